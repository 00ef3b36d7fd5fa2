"""The camera's own motion seen in the video (issue 52): where a clip has no IMU and neither a
GNSS fix nor a registered keyframe measures the track (an outage over a stretch the scene does
not register: a model with a hole, keyframes lost to glare), the video still shows the ground go
by, and that carries the track instead of a smooth curve between the measurements around.

Between frames STRIDE apart, corners tracked by sparse optical flow (app.sync.flow.tracked) are
turned into the world by each frame's camera attitude and met with a level ground one metre
below the camera: a corner seen at ground point g1 (east, north, relative to the camera, metres
per metre of height) from the first frame and at g2 from the second says the camera moved by
g1 - g2 (`ground_step`: the median over the corners that look down by MIN_DEPRESSION_DEG or
more; a roof's corners disagree, the ground's majority holds). That is a step per metre of
height above the ground: the height is fitted (`height`) on each side of the stretch, over the
MARGIN_S where fixes or keyframes measured the track (how far it moved against the steps' sum),
and runs linearly from one to the other across it, so that neither the ground's height nor the
scene is needed inside it; a stretch with no measurement after it (the clip's end) or before, or
whose two heights disagree, is left to the carry (no scale checks the video's motion there).
A stretch is sought where frames lie more than LOST_S from every measurement, and then runs
from the measurement before them to the one after: the platform turns as much in the second
after the last fix as later. One velocity per BIN_S (ENU m/s, horizontal; the scale errs for
seconds at a time, so its steps are not independent) joins the carry
(app.register.inertial.carry) as a measurement with a spread of SPEED_SHARE of the speed plus
SPEED_FLOOR_MPS. On the simulated DJI weave with its keyframes lost over a 6 s outage the
track's median error there fell from 4.1 to 0.9 m (tests/test_dji_registered.py). Times are
session seconds; positions local ENU metres; camera attitudes camera -> ENU quaternions in the
OpenGL camera axes (app.geodesy.rotations).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from app.camera.fixes import USED, FixStatus
from app.core.errors import GeofuseError
from app.geodesy import rotations
from app.io.video import VideoInfo, frames_at
from app.register.fuse import Correction
from app.session.camera_track import CameraTrack
from app.session.model import Session
from app.sync.flow import FLOW_WIDTH_PX, MIN_TRACKS, tracked
from app.sync.rates import bearings_of

FloatArray = npt.NDArray[np.float64]
MIN_DEPRESSION_DEG = 20.0  # rays nearer the horizon meet a level ground too far off to trust
STRIDE = 3  # frames between the two of a step (0.1 s at 30 fps: a few pixels of flow)
MIN_FITTED = 5  # steps where the track is measured, at least, to fit the height by
MAX_MISFIT = 0.3  # the fit's miss against how far the track moved, at most this share of it
SPEED_SHARE = 0.06  # a velocity's spread (m/s, each axis): this share of the speed ...
SPEED_FLOOR_MPS = 0.2  # ... plus this
BIN_S = 0.5  # one velocity per this much video (s)
LOST_S = 1.0  # a frame farther than this (s) from every fix used and keyframe kept is not
# measured: the video's own motion is sought there ...
MEASURED_S = 0.25  # ... and its height fitted where measurements lie 2 x this apart or closer,
MARGIN_S = 3.0  # within this (s) either side
HEIGHTS_AGREE = 1.5  # the heights fitted either side agree within this ratio
_OPENGL = np.array([1.0, -1.0, -1.0])  # OpenCV camera axes (x right, y down, z ahead) -> OpenGL's


def ground_step(
    b1: FloatArray, b2: FloatArray, q1: FloatArray, q2: FloatArray
) -> FloatArray | None:
    """(2,) east, north: how far the camera moved between two frames, per metre of its height
    above a level ground, from corners seen along bearings b1 (N, 3) in the first frame and b2
    (N, 3) in the second (unit, OpenCV camera axes) with the cameras' attitudes q1, q2 (camera
    -> ENU, OpenGL camera axes): the median of g1 - g2 over the corners that look down by
    MIN_DEPRESSION_DEG or more in both (module docstring); None where fewer than MIN_TRACKS do."""
    w1 = rotations.rotate(q1, np.asarray(b1, np.float64) * _OPENGL)
    w2 = rotations.rotate(q2, np.asarray(b2, np.float64) * _OPENGL)
    low = -np.sin(np.radians(MIN_DEPRESSION_DEG))
    down = (w1[:, 2] < low) & (w2[:, 2] < low)
    if down.sum() < MIN_TRACKS:
        return None
    g1 = w1[down, :2] / -w1[down, 2:3]
    g2 = w2[down, :2] / -w2[down, 2:3]
    return np.median(g1 - g2, axis=0)


@dataclass(frozen=True)
class FlowSteps:
    """Steps between frames: t (P,) their mid times (session s), dt (P,) s between them, step
    (P, 2) east, north per metre of height (ground_step)."""

    t: FloatArray
    dt: FloatArray
    step: FloatArray


@dataclass
class Seen:
    """Corners tracked between a solve's frames, kept across its carries (each asks for its
    stretches again under another attitude correction, and decoding costs seconds a minute):
    per (frame, next frame) index pair their bearings (b1, b2 (N, 3) unit, OpenCV camera axes),
    None where they did not track (or a frame did not decode, or the times do not increase)."""

    pairs: dict[tuple[int, int], tuple[FloatArray, FloatArray] | None] = field(default_factory=dict)

    def track(
        self,
        video: VideoInfo,
        frame_times: FloatArray,
        wanted: list[tuple[int, int]],
        bearings: Callable[[np.ndarray], np.ndarray],
        display_width: int,
    ) -> None:
        """The pairs `wanted` (increasing) not yet tracked: their frames decoded in one pass,
        reduced to FLOW_WIDTH_PX, and the corners tracked from each pair's first to its second
        (app.sync.flow.tracked)."""
        need = [p for p in wanted if p not in self.pairs]
        if not need:
            return
        frames = sorted({i for p in need for i in p})
        starts = {a: b for a, b in need}
        open_: dict[int, np.ndarray] = {}  # the first frames of pairs whose second is to come
        for i, rgb in frames_at(video, frames, long_side=2 * FLOW_WIDTH_PX):
            scale = FLOW_WIDTH_PX / rgb.shape[1]
            size = (FLOW_WIDTH_PX, max(2, round(rgb.shape[0] * scale)))
            small = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
            grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
            for a in [a for a in open_ if starts[a] == i]:
                corners = None
                if frame_times[i] > frame_times[a]:
                    corners = tracked(open_.pop(a), grey, FLOW_WIDTH_PX / display_width)
                else:
                    open_.pop(a)
                self.pairs[(a, i)] = (
                    None if corners is None else (bearings(corners[0]), bearings(corners[1]))
                )
            if i in starts:
                open_[i] = grey
        for p in need:  # a frame that did not decode: no step
            self.pairs.setdefault(p, None)


def flow_steps(
    video: VideoInfo,
    frame_times: FloatArray,
    indices: npt.ArrayLike,
    attitude: Callable[[FloatArray], FloatArray],
    bearings: Callable[[np.ndarray], np.ndarray],
    display_width: int,
    seen: Seen | None = None,
) -> FlowSteps:
    """The steps between consecutive frames of `indices` (increasing) of `video` (VideoInfo;
    decoded in one pass, reduced to FLOW_WIDTH_PX), at session times frame_times (F,) s, under
    attitude(t (M,) s) -> (M, 4) camera -> ENU; bearings: display pixels (N, 2) -> unit
    bearings (N, 3) in OpenCV camera axes; display_width: the display's width (px); seen: the
    corners earlier calls tracked (only the pairs not among them are decoded). A pair whose
    corners do not track, or look too little down, gives no step."""
    seen = Seen() if seen is None else seen
    wanted = [int(i) for i in indices]
    pairs = list(zip(wanted, wanted[1:], strict=False))
    seen.track(video, frame_times, pairs, bearings, display_width)
    pairs = [p for p in pairs if seen.pairs[p] is not None]
    ends = sorted({i for p in pairs for i in p})
    q_of = dict(zip(ends, attitude(np.asarray(frame_times, np.float64)[ends]), strict=True))
    ts, dts, steps = [], [], []
    for a, b in pairs:
        step = ground_step(*seen.pairs[(a, b)], q_of[a], q_of[b])
        if step is not None:
            ts.append(0.5 * (frame_times[a] + frame_times[b]))
            dts.append(frame_times[b] - frame_times[a])
            steps.append(step)
    return FlowSteps(np.array(ts), np.array(dts), np.array(steps).reshape(-1, 2))


def height(steps: FlowSteps, moved: FloatArray, known: npt.NDArray[np.bool_]) -> float | None:
    """The camera's height above the ground (m) that scales the steps to how far the track moved
    over each (moved (P, 2) east, north m), over those where the track is measured (known
    (P,)): the height h fitting their sums, sum moved = h sum step (least squares), so that a
    velocity errs less than its distance over the whole; None where fewer than MIN_FITTED are,
    or the fit misses that distance by more than MAX_MISFIT of it (the ground is not level, or
    not seen)."""
    if known.sum() < MIN_FITTED:
        return None
    d, s = np.asarray(moved, np.float64)[known].sum(axis=0), steps.step[known].sum(axis=0)
    if not s @ s > 0:
        return None
    h = float(s @ d / (s @ s))
    if h <= 0 or np.linalg.norm(d - h * s) > MAX_MISFIT * np.linalg.norm(d):
        return None
    return h


@dataclass(frozen=True)
class Flow:
    """Velocities the video's own motion measured: t (P,) session s, increasing; v (P, 3) ENU
    m/s (the height's not measured: 0); sigma (P,) m/s, each axis."""

    t: FloatArray
    v: FloatArray
    sigma: FloatArray

    def within(self, t0: float, t1: float) -> Flow:
        """Those at times within [t0, t1] s."""
        inside = (self.t >= t0) & (self.t <= t1)
        return Flow(self.t[inside], self.v[inside], self.sigma[inside])


def video_flow(
    session: Session,
    track: CameraTrack,
    correction: Correction,
    fixes: tuple[FloatArray, FloatArray],
    keys: tuple[FloatArray, FloatArray],
    filled: tuple[float, float],
    status: FixStatus,
    seen: Seen | None = None,
) -> tuple[Flow | None, str]:
    """(the velocities the video's own motion measures (module docstring), what to say of them)
    over the stretches of `filled` (session s) whose frames are not posed by a fix (`status`
    not used at their time: the carry fills them) and lie farther than LOST_S from every
    measurement, each from the measurement before them to the one after: the fixes used and
    the keyframes kept, each (times (M,) s, positions (M, 3) ENU m). The camera's attitude is
    the track's under the registration's correction; seen: the corners a solve's earlier
    carries tracked (flow_steps). (None, "") where there is no such stretch; (None, what was
    said) where none could be scaled."""
    t_m = np.concatenate([fixes[0], keys[0]])
    if len(t_m) < 2:
        return None, ""
    times = np.asarray(session.frame_times, np.float64)
    lost = (
        (_farther(times, np.sort(t_m)) > LOST_S)
        & (times >= filled[0])
        & (times <= filled[1])
        & (status.at(times) != USED)
    )
    if not lost.any():
        return None, ""
    # each stretch runs from the measurement before its lost frames to the one after: the
    # track swings between them, near one as far from it
    t_m = np.sort(t_m)
    runs = [_around(t_m, a, b) for a, b in _runs(times, lost)]
    near = np.zeros(len(times), bool)
    for a, b in runs:
        near |= (times >= a - MARGIN_S) & (times <= b + MARGIN_S)
    # every STRIDE-th frame of the video (not of the stretch: a solve's carries, whose
    # stretches move by a frame or two, ask for the same pairs, tracked once: Seen)
    indices = np.flatnonzero(near & (np.arange(len(times)) % STRIDE == 0))

    def attitude(t: FloatArray) -> FloatArray:
        _, _, q = track.poses.at(t)
        _, dr = correction(t)
        return rotations.multiply(rotations.from_rotvec(dr), q)

    t0 = float(times[0])
    named = [f"t = {a - t0:.1f} to {b - t0:.1f} s" for a, b in runs]
    spans = ", ".join(named)
    try:
        steps = flow_steps(
            session.video,
            times,
            indices,
            attitude,
            bearings_of(session),
            session.intrinsics.width,
            seen,
        )
    except (GeofuseError, OSError, cv2.error) as exc:
        return None, f"the video's own motion over {spans} could not be read ({exc})"
    # how far the track moved over each step, where it was measured: by the keyframes (the
    # fixes carry the GNSS's own error, which a line through both would zig-zag by), else by
    # the fixes
    measured = [_moved(steps, *keys), _moved(steps, *fixes)]
    flows, said = [], []
    for (a, b), span in zip(runs, named, strict=True):
        fitted = stretch_velocities(steps, measured, a, b)
        if fitted is None:
            said.append(f"{span} (its motion could not be scaled to the track around)")
        else:
            flows.append(fitted[0])
            said.append(f"{span} (the camera {fitted[1]:.0f} to {fitted[2]:.0f} m above ground)")
    carries = (
        ": the video's own motion carries the track there, scaled where the track was measured"
        if flows
        else ": the track there stands on the measurements around alone"
    )
    text = "no fix and no registered keyframe over " + ", ".join(said) + carries
    if not flows:
        return None, text
    keys_ = ("t", "v", "sigma")
    return Flow(*(np.concatenate([getattr(f, k) for f in flows]) for k in keys_)), text


def _moved(
    steps: FlowSteps, t_m: FloatArray, p_m: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """(how far the measurements at times t_m (M,) s, positions p_m (M, 3) ENU m moved over
    each step (P, 2) east, north m, linear between them; where both its ends lie between two
    of them 2 MEASURED_S apart or closer (P,))."""
    known = np.zeros(len(steps.t), bool)
    if len(t_m) < 2:
        return np.zeros((len(steps.t), 2)), known
    order = np.argsort(t_m)
    t_m, p_m = np.asarray(t_m, np.float64)[order], np.asarray(p_m, np.float64)[order]
    ends = (steps.t - steps.dt / 2, steps.t + steps.dt / 2)
    at = [np.column_stack([np.interp(e, t_m, p_m[:, k]) for k in (0, 1)]) for e in ends]
    return at[1] - at[0], _between(ends[0], t_m) & _between(ends[1], t_m)


def stretch_velocities(
    steps: FlowSteps,
    measured: list[tuple[FloatArray, npt.NDArray[np.bool_]]],
    a: float,
    b: float,
) -> tuple[Flow, float, float] | None:
    """(the velocities over the stretch a..b s (session), one per BIN_S, and the heights (m)
    fitted before and after it: linear between them across it) from the steps and how far the
    track moved over each where it was measured (`measured`: (moved (P, 2) m, known (P,)) by
    one kind of measurement, the first that fits on a side). None where either side
    could not be fitted, or the two disagree by more than HEIGHTS_AGREE times (a stretch
    measured on one side only is dead reckoning from a scale nothing checks)."""

    def fitted(side: npt.NDArray[np.bool_]) -> float | None:
        for moved, known in measured:
            h = height(steps, moved, known & side)
            if h is not None:
                return h
        return None

    h_a = fitted((steps.t < a) & (steps.t >= a - MARGIN_S))
    h_b = fitted((steps.t > b) & (steps.t <= b + MARGIN_S))
    if h_a is None or h_b is None or max(h_a, h_b) > HEIGHTS_AGREE * min(h_a, h_b):
        return None
    inside = (steps.t >= a) & (steps.t <= b)
    if not inside.any():
        return None
    t, rate = steps.t[inside], steps.step[inside] / steps.dt[inside, None]
    share = np.clip((t - a) / max(b - a, 1e-9), 0.0, 1.0)
    v = ((1 - share) * h_a + share * h_b)[:, None] * rate
    # one per BIN_S: the steps' errors are not independent (the scale errs for seconds)
    bins = np.floor((t - a) / BIN_S).astype(int)
    ts = np.array([t[bins == k].mean() for k in np.unique(bins)])
    vs = np.array([v[bins == k].mean(axis=0) for k in np.unique(bins)])
    spread = SPEED_SHARE * np.linalg.norm(vs, axis=1) + SPEED_FLOOR_MPS
    return Flow(ts, np.column_stack([vs, np.zeros(len(vs))]), spread), h_a, h_b


def _between(t: FloatArray, measured: FloatArray) -> npt.NDArray[np.bool_]:
    """(T,) whether each time t lies between two of `measured` (sorted) at most 2 MEASURED_S
    apart (where a line between them is where the track was)."""
    j = np.searchsorted(measured, t)
    inside = (j > 0) & (j < len(measured))
    j = np.clip(j, 1, len(measured) - 1)
    return inside & (measured[j] - measured[j - 1] <= 2 * MEASURED_S)


def _around(measured: FloatArray, a: float, b: float) -> tuple[float, float]:
    """(the last of `measured` (sorted) at or before a, the first at or after b): the span
    between the measurements around the times a..b s (a, b themselves where none is)."""
    before, after = measured[measured <= a], measured[measured >= b]
    return (float(before[-1]) if len(before) else a, float(after[0]) if len(after) else b)


def _farther(t: FloatArray, measured: FloatArray) -> FloatArray:
    """(T,) how far (s) each time t lies from the nearest of `measured` (sorted, 2 or more)."""
    j = np.clip(np.searchsorted(measured, t), 1, len(measured) - 1)
    return np.minimum(np.abs(t - measured[j - 1]), np.abs(measured[j] - t))


def _runs(t: FloatArray, flag: npt.NDArray[np.bool_]) -> list[tuple[float, float]]:
    """The (first, last) times t of each run of consecutive True flags."""
    edges = np.flatnonzero(np.diff(np.r_[0, flag.astype(int), 0]))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]
