"""Automatic video <-> sensor time offset (`geofuse sync`): the camera's rotation rate seen in the
video against the gyroscope's (or, without one, a recorded attitude's, or a drone's course).

1. Video: sparse optical flow (OpenCV's pyramidal Lucas-Kanade on corners) between consecutive
   frames of a reduced grey copy; each pair's feature bearings (through the session's lens or
   pinhole) give the frame-to-frame rotation by a least-squares fit (Kabsch) with outlier
   rejection; rotation / time step = the rate (rad/s, camera frame) at the pair's mid time.
2. Reference: the gyroscope's rates turned from the device frame into the camera frame by the
   mount; else a recorded attitude (a DJI gimbal's, a camera's, a phone's own) differentiated;
   else, for a drone whose subtitle has no gimbal angles, the turn rate of its heading (its
   recorded yaw, or its direction of travel from the GNSS track) about the world's up axis, which
   the video's rates are projected on: the offset found is then the lag of the GNSS track (or
   the yaw) behind the video. A course that hardly turns is refused with the reason.
3. Coarse: the lag that maximises the cross-correlation of the two rate magnitudes over the
   whole clip (+-MAX_LAG_S); fine: the lag, in 1 ms steps within +-FINE_RANGE_S of it and refined
   by a parabola, that best fits the rate components on the windows that say most about time:
   those where the reference's rates change fastest (a time error dt moves a rate w by
   dt * dw/dt; the steady middle of a turn says little). The result is the offset to add to the
   video's times (seconds; video.time_offset_s).
4. Drift, on long clips: each strong window's own lag, regressed on time; kept when it moves the
   clip's ends by DRIFT_MIN_EFFECT_S or more.

Times: media seconds (the video's presentation times) and session seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import rotations
from app.attitude.heading import COURSE_HOLD_SPEED_MPS, smoothed_velocity
from app.constants import COURSE
from app.errors import GeofuseError

FLOW_WIDTH_PX = 320  # the video is reduced to this width for the flow
MAX_FEATURES = 200
MIN_TRACKS = 12  # pairs with fewer tracked features give no rate
MAX_LAG_S = 2.0
FINE_RANGE_S = 0.25  # the fine fit searches this far either side of the coarse lag
GRID_HZ = 500.0  # both rate curves are resampled on this grid
WINDOW_S = 1.0
DRIFT_MIN_SPAN_S = 40.0  # a clock drift is fitted only over clips whose strong windows span this
DRIFT_LOCAL_S = 0.05  # each window's own offset is searched this far around the clip's
DRIFT_MIN_EFFECT_S = (
    0.005  # a fitted drift that moves the clip's ends by less than this is noise: 0
)
TIMING_SMOOTH_S = 0.1  # the reference's rates are smoothed over this before their change is taken
STRONG_FRACTION = 0.3  # the fine fit uses the 30 % of windows that say most about time


@dataclass(frozen=True)
class RateCurve:
    """Rotation rates: t (N,) seconds; omega (N, 3) rad/s in the camera frame (OpenGL axes), or,
    with an axis ((3,) unit vector in that frame), omega (N, 1): the rate about that axis only
    (a course knows only how the heading turns)."""

    t: np.ndarray
    omega: np.ndarray
    axis: np.ndarray | None = None

    def along(self, reference: "RateCurve") -> "RateCurve":
        """This three-axis curve made comparable with `reference`: its rate about the
        reference's axis where the reference has one, else itself."""
        if reference.axis is None:
            return self
        return RateCurve(self.t, (self.omega @ reference.axis)[:, None], reference.axis)


@dataclass(frozen=True)
class SyncResult:
    """offset_s: add to the video's times; confidence: the mean correlation coefficient (0..1) of
    the rate components (three, or the one about a course's axis) at that offset, on the fitted windows; windows: (start, end) session seconds of the windows fitted;
    coarse_s: the magnitude correlation's lag."""

    offset_s: float
    confidence: float
    windows: tuple[tuple[float, float], ...]
    coarse_s: float
    drift_ppm: float = 0.0  # the video clock's rate error against the sensors' (parts per million)
    reference_s: float = 0.0  # session time at which offset_s holds exactly (the drift's pivot)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R (3x3) minimising sum |b - R a|^2 over unit vectors (N, 3)."""
    h = a.T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def frame_rotation(b1: np.ndarray, b2: np.ndarray) -> np.ndarray | None:
    """R with b2 ~ R b1 (bearings (N, 3)), refitted without the worst third of residuals."""
    if len(b1) < MIN_TRACKS:
        return None
    r = _kabsch(b1, b2)
    res = np.linalg.norm(b2 - b1 @ r.T, axis=1)
    keep = res <= np.percentile(res, 67)
    return _kabsch(b1[keep], b2[keep]) if keep.sum() >= MIN_TRACKS else r


def video_rates(
    video,
    bearings: Callable[[np.ndarray], np.ndarray],
    rotation_cw: int,
    progress: Callable[[float], None] | None = None,
) -> RateCurve:
    """The camera's rotation rate between consecutive frames (see the module docstring).
    bearings: display pixels (N, 2) -> unit vectors (N, 3) in OpenCV's camera frame."""
    import av
    import cv2

    from app.io.video import media_seconds

    w, h = video.width, video.height
    scale = FLOW_WIDTH_PX / w
    size = (FLOW_WIDTH_PX, max(2, round(h * scale)))
    k = (rotation_cw // 90) % 4
    t_out, w_out = [], []
    prev = prev_t = None
    n = len(video.pts_s)
    with av.open(str(video.path)) as c:
        stream = c.streams.video[0]
        stream.thread_type = "AUTO"
        for i, frame in enumerate(c.decode(stream)):
            if frame.pts is None:
                continue
            t = media_seconds(frame.pts, stream.time_base, video.origin_s)
            grey = np.ascontiguousarray(
                np.rot90(
                    frame.reformat(width=size[0], height=size[1], format="gray").to_ndarray(), k=-k
                )
            )
            if prev is not None and t > prev_t:
                pts = cv2.goodFeaturesToTrack(prev, MAX_FEATURES, 0.01, 6)
                if pts is not None and len(pts) >= MIN_TRACKS:
                    nxt, ok, _ = cv2.calcOpticalFlowPyrLK(
                        prev, grey, pts, None, winSize=(15, 15), maxLevel=3
                    )
                    ok = ok.ravel() == 1
                    if ok.sum() >= MIN_TRACKS:
                        p1 = (pts[ok, 0, :] + 0.5) / scale  # display pixels of the full video
                        p2 = (nxt[ok, 0, :] + 0.5) / scale
                        rot = frame_rotation(bearings(p1), bearings(p2))
                        if rot is not None:
                            # b2 = D^T b1 for a body turn D: the camera's rate is -rotvec(R) / dt.
                            rv = -rotations.to_scipy(rotations.from_matrix(rot)).as_rotvec() / (
                                t - prev_t
                            )
                            t_out.append((t + prev_t) / 2)
                            w_out.append([rv[0], -rv[1], -rv[2]])  # OpenCV camera axes -> OpenGL's
            prev, prev_t = grey, t
            if progress is not None and i % 50 == 0:
                progress(min(1.0, i / max(n, 1)))
    if progress is not None:
        progress(1.0)
    if len(t_out) < 10:
        raise GeofuseError(
            f"{video.path}: too few frames with trackable features to see the camera turn ({len(t_out)})"
        )
    return RateCurve(np.asarray(t_out), np.asarray(w_out))


def _on_grid(curve: RateCurve, t: np.ndarray) -> np.ndarray:
    return np.column_stack(
        [
            np.interp(t, curve.t, curve.omega[:, j], left=np.nan, right=np.nan)
            for j in range(curve.omega.shape[1])
        ]
    )


def _score(
    video: RateCurve, gyro: RateCurve, lag: float, t: np.ndarray, mask: np.ndarray | None = None
) -> float:
    """Mean squared difference of the components, video at t against gyro at t + lag."""
    a, b = _on_grid(video, t), _on_grid(gyro, t + lag)
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    if mask is not None:
        ok &= mask
    return float(np.mean(np.sum((a[ok] - b[ok]) ** 2, axis=1))) if ok.sum() > 10 else np.inf


def estimate_offset(video: RateCurve, gyro: RateCurve, clip_start_s: float) -> SyncResult:
    """The offset (s) that aligns the video's rates (media time + clip_start_s) with the
    gyroscope's (session time); see the module docstring. A reference with an axis (the
    course) is compared with the video's rate about that axis."""
    video = video.along(gyro)
    v = RateCurve(video.t + clip_start_s, video.omega)
    t = np.arange(v.t[0], v.t[-1], 1.0 / GRID_HZ)
    mag_v = np.nan_to_num(np.linalg.norm(_on_grid(v, t), axis=1))
    lags = np.arange(-MAX_LAG_S, MAX_LAG_S + 1e-9, 1.0 / GRID_HZ)
    mag_g_full = np.linalg.norm(
        _on_grid(gyro, np.arange(t[0] - MAX_LAG_S, t[-1] + MAX_LAG_S + 1e-9, 1.0 / GRID_HZ)), axis=1
    )
    mag_g_full = np.nan_to_num(mag_g_full)
    mv = mag_v - mag_v.mean()
    corr = np.array(
        [
            np.dot(mv, mag_g_full[i : i + len(mv)] - mag_g_full[i : i + len(mv)].mean())
            for i in range(len(lags))
        ]
    )
    coarse = float(lags[int(np.argmax(corr))])
    # The windows that say most about time (see _timing_energy).
    edges = np.arange(t[0], t[-1], WINDOW_S)
    energy = _timing_energy(gyro, t + coarse, edges, t)
    strong_edges = edges[energy >= np.quantile(energy, 1.0 - STRONG_FRACTION)]
    mask = np.zeros(len(t), bool)
    for e in strong_edges:
        mask |= (t >= e) & (t < e + WINDOW_S)
    fine_lags = np.arange(coarse - FINE_RANGE_S, coarse + FINE_RANGE_S + 1e-9, 0.001)
    tm = t[mask]  # the strong windows' grid only
    scores = np.array([_score(v, gyro, lag, tm) for lag in fine_lags])
    best = _parabolic_min(fine_lags, scores)
    a, b = _on_grid(v, t), _on_grid(gyro, t + best)
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & mask
    confidence = (
        float(np.mean([np.corrcoef(a[ok, j], b[ok, j])[0, 1] for j in range(a.shape[1])]))
        if ok.sum() > 10
        else 0.0
    )
    drift, pivot = _drift(v, gyro, best, strong_edges, t)
    return SyncResult(
        best,
        max(0.0, confidence),
        tuple((float(e), float(e + WINDOW_S)) for e in strong_edges),
        coarse,
        drift,
        pivot,
    )


def _timing_energy(
    reference: RateCurve, t_ref: np.ndarray, edges: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """How much each window (start edges, WINDOW_S long, on grid t) says about time: the mean
    squared rate of change of the reference's rates (read at t_ref, smoothed over
    TIMING_SMOOTH_S), since a time error dt changes a rate w by dt * dw/dt. (Peaks of a smooth
    turn, however strong, say little; its onsets and reversals say most.)"""
    from scipy.ndimage import uniform_filter1d

    ref = _on_grid(reference, t_ref)  # NaN where the reference has no rate (before, after, gaps)
    valid = np.isfinite(ref).all(axis=1)
    n = max(1, int(round(TIMING_SMOOTH_S * GRID_HZ)))
    smooth = uniform_filter1d(np.where(valid[:, None], ref, 0.0), n, axis=0, mode="nearest")
    change = np.sum(np.gradient(smooth, axis=0) ** 2, axis=1) * GRID_HZ**2
    change[uniform_filter1d(valid.astype(np.float64), n + 2, mode="constant") < 1.0 - 1e-9] = (
        np.nan
    )  # near a gap
    out = np.zeros(len(edges))
    for i, e in enumerate(edges):
        window = change[(t >= e) & (t < e + WINDOW_S)]
        out[i] = (
            np.mean(window) if len(window) and np.isfinite(window).all() else 0.0
        )  # a window the reference does not cover says nothing
    return out


def _parabolic_min(lags: np.ndarray, scores: np.ndarray) -> float:
    """The lag of the lowest score, refined by the parabola through it and its neighbours."""
    k = int(np.argmin(scores))
    best = float(lags[k])
    if 0 < k < len(scores) - 1 and np.isfinite(scores[k - 1 : k + 2]).all():
        s0, s1, s2 = scores[k - 1 : k + 2]
        denom = s0 - 2 * s1 + s2
        if denom > 0:
            best += float(lags[1] - lags[0]) * 0.5 * (s0 - s2) / denom
    return best


def _drift(
    v: RateCurve, gyro: RateCurve, offset: float, edges: np.ndarray, t: np.ndarray
) -> tuple[float, float]:
    """(drift ppm, pivot time): each strong window's own best lag near the clip's, regressed on
    time; 0 when the windows span less than DRIFT_MIN_SPAN_S (too short a clip to see it)."""
    pivot = float(np.mean(edges + WINDOW_S / 2)) if len(edges) else float(t[0])
    if len(edges) < 6 or np.ptp(edges) < DRIFT_MIN_SPAN_S:
        return 0.0, pivot
    lags = np.arange(offset - DRIFT_LOCAL_S, offset + DRIFT_LOCAL_S + 1e-9, 0.001)
    local = []
    for e in edges:
        tw = t[(t >= e) & (t < e + WINDOW_S)]  # this window's grid only
        local.append(_parabolic_min(lags, np.array([_score(v, gyro, lag, tw) for lag in lags])))
    slope, _ = np.polyfit(edges + WINDOW_S / 2 - pivot, np.asarray(local), 1)
    if abs(slope) * np.ptp(edges) < DRIFT_MIN_EFFECT_S:
        return 0.0, pivot
    return float(slope * 1e6), pivot


ATTITUDE_SMOOTH_S = 0.15  # moving average of rates differentiated from recorded attitudes
RECORDED_FOR_RATES = (
    "telemetry",
    "camera",
    "phone",
)  # recorded attitudes, best first, when no gyroscope
MIN_COURSE_TURN_DEG_S = 3.0  # a course turning slower than this carries no usable timing
MIN_COURSE_TURNING_S = 4.0  # ... and it must turn that fast for this long over the clip
SYNC_COURSE_SMOOTH_S = 1.0  # s: velocities are averaged, and the course's turn taken, over this


def attitude_rates(t: np.ndarray, q: np.ndarray) -> RateCurve:
    """Body rates (rad/s, the device frame) between successive attitudes q (N, 4) device -> world
    at times t (N,) s, at the midpoints: the rotation vector of q_i* q_(i+1) over the interval.
    (`omega` is then in the device frame; gyro_rates turns it into the camera frame.)"""
    t = np.asarray(t, np.float64)
    dt = np.diff(t)
    keep = dt > 1e-6
    step = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])[keep]
    rates = rotations.to_scipy(step).as_rotvec() / dt[keep, None]
    mid = (t[:-1] + t[1:])[keep] / 2.0
    # attitudes carry sample-to-sample noise that differentiation amplifies: a centred moving
    # average over ATTITUDE_SMOOTH_S (symmetric, so it moves no time) keeps the turns
    n = max(1, int(round(ATTITUDE_SMOOTH_S / max(float(np.median(dt[keep])), 1e-6))) | 1)
    if n > 1 and len(rates) > n:
        from scipy.ndimage import uniform_filter1d

        rates = uniform_filter1d(rates, n, axis=0, mode="nearest")
    return RateCurve(mid, rates)


def rate_source(session) -> str | None:
    """What times the video: 'gyroscope', a recorded attitude's name, 'course' (a drone without
    gimbal angles: the heading it flies, from its yaw or its GNSS track), or None."""
    if session.gyr is not None:
        return "gyroscope"
    recorded = next((n for n in RECORDED_FOR_RATES if n in session.recorded), None)
    return recorded or (COURSE if session.course_pitch_deg is not None else None)


RATE_SOURCE_WORDS = {
    "gyroscope": "the gyroscope",
    "telemetry": "the recorded gimbal attitude",
    "camera": "the camera's recorded attitude",
    "phone": "the phone's recorded attitude",
    COURSE: "the aircraft's course (the GNSS track's lag behind the video)",
}


def timed_by(session) -> str:
    """What the session's video is timed against, in words, for messages."""
    name = rate_source(session)
    return RATE_SOURCE_WORDS.get(name, str(name))


def gyro_rates(session) -> RateCurve:
    """The session's rotation rates in the camera frame of the displayed video: its gyroscope's,
    or, without one, those of a recorded attitude (a DJI gimbal's, a camera's or a phone's own),
    differentiated, or those of the course attitude (a drone whose camera looks where it flies:
    the offset found is then the lag of its GNSS track, or its yaw, behind the video); raises
    when it has none, or when the course turns too little to time anything by."""
    mount = rotations.conjugate(session.camera_mount())
    name = rate_source(session)
    if name == "gyroscope":
        t, body = session.gyr.t, session.gyr.values
    elif name is None:
        raise GeofuseError(
            f"{session.path}: no gyroscope, no recorded attitude and no course: the offset cannot be found from rotation (set video.time_offset_s by hand)"
        )
    elif name == COURSE:
        return course_rates(session)
    else:
        stream = session.recorded[name]
        curve = attitude_rates(stream.t, stream.q)
        t, body = curve.t, curve.omega
    return RateCurve(t, rotations.rotate(np.tile(mount, (len(t), 1)), body))


def course_rates(session) -> RateCurve:
    """How fast a drone's heading turns (rad/s about the world's up axis, seen in the camera frame
    of the displayed video): from the aircraft's recorded yaw where the subtitle has one, else from
    its direction of travel (velocities averaged over SYNC_COURSE_SMOOTH_S; NaN while slower than
    COURSE_HOLD_SPEED_MPS); the turn is taken over SYNC_COURSE_SMOOTH_S too, centred, so that no
    time moves. Refused when it turns too little."""
    if session.aircraft_yaw is not None:
        t, heading = (np.asarray(x, np.float64) for x in session.aircraft_yaw)
        moving = np.ones(len(t), bool)
    else:
        pos = session.positions()
        t = pos.t
        vel = smoothed_velocity(t, pos.vel_enu, SYNC_COURSE_SMOOTH_S)
        heading = np.degrees(np.arctan2(vel[:, 0], vel[:, 1]))
        moving = np.hypot(vel[:, 0], vel[:, 1]) > COURSE_HOLD_SPEED_MPS
    keep = np.concatenate([[True], np.diff(t) > 1e-6])
    t, heading, moving = t[keep], np.unwrap(np.radians(heading[keep])), moving[keep]
    # the turn over SYNC_COURSE_SMOOTH_S centred on each fix (a derivative from neighbouring
    # fixes would amplify the positions' rounding); a heading turning clockwise (seen from
    # above) is a negative turn about the up axis
    half = SYNC_COURSE_SMOOTH_S / 2
    rate = -(np.interp(t + half, t, heading) - np.interp(t - half, t, heading)) / (2 * half)
    rate[~moving | (t - half < t[0]) | (t + half > t[-1])] = np.nan
    _check_course_turns(t, rate, session)
    pitch = float(session.course_pitch_deg)
    q = rotations.camera_quat_from_hpr(
        0.0, pitch, 0.0
    )  # the heading does not change where "up" is seen
    up = rotations.rotate(
        rotations.conjugate(q), np.array([0.0, 0.0, 1.0])
    )  # world up in the camera frame
    up = rotations.rotate(rotations.conjugate(session.camera_mount()), up)
    return RateCurve(t, rate[:, None], up / np.linalg.norm(up))


def _check_course_turns(t: np.ndarray, rate: np.ndarray, session) -> None:
    """Refuse a course that turns faster than MIN_COURSE_TURN_DEG_S for less than
    MIN_COURSE_TURNING_S in all: a straight flight or a hover carries no time."""
    deg = np.degrees(np.abs(np.nan_to_num(rate)))
    dt = np.diff(t, append=t[-1])
    turning = float(np.sum(dt[deg >= MIN_COURSE_TURN_DEG_S]))
    if turning < MIN_COURSE_TURNING_S:
        source = "yaw" if session.aircraft_yaw is not None else "course over the ground"
        raise GeofuseError(
            f"{session.path}: the aircraft's {source} turns faster than {MIN_COURSE_TURN_DEG_S:g} deg/s for only {turning:.1f} s "
            f"(at most {float(np.max(deg, initial=0.0)):.1f} deg/s; {MIN_COURSE_TURNING_S:g} s needed): a straight flight or a hover "
            "does not show when its GNSS track lags the video, so the offset cannot be estimated (set video.time_offset_s by hand)"
        )


def bearings_of(session) -> Callable[[np.ndarray], np.ndarray]:
    """Display pixels -> unit bearings (OpenCV camera frame) through the session's lens or pinhole."""
    lens, intr = session.lens, session.intrinsics

    def bearings(uv: np.ndarray) -> np.ndarray:
        if lens is not None:
            ab = lens.undistort(uv)
        else:
            ab = np.column_stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy])
        b = np.column_stack([ab, np.ones(len(ab))])
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    return bearings


def settings_path(source: Path) -> Path:
    """The session's own file of settings beside its manifest or clip (never an input):
    `NAME.geofuse.toml`, holding what `geofuse sync --write` found."""
    return source.with_name(source.stem + ".geofuse.toml")


def read_settings(source: Path) -> dict:
    """The settings file's tables ({} when there is none); a broken one is an error naming it."""
    import tomllib

    path = settings_path(source)
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeofuseError(
            f"{path}: not valid TOML ({exc}); delete it or run geofuse sync --write again"
        ) from exc


def synced_offset(source: Path) -> float | None:
    """The offset stored by `geofuse sync --write` for this manifest or clip, or None."""
    value = read_settings(source).get("sync", {}).get("time_offset_s")
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None


def synced_drift(source: Path) -> tuple[float, float]:
    """(drift ppm, pivot session time) stored beside the offset, or (0, 0)."""
    sync = read_settings(source).get("sync", {})
    drift, pivot = sync.get("drift_ppm", 0.0), sync.get("drift_pivot_s", 0.0)
    ok = all(isinstance(x, (int, float)) and np.isfinite(x) for x in (drift, pivot))
    return (float(drift), float(pivot)) if ok else (0.0, 0.0)


def settings_text(result: SyncResult, total_offset_s: float) -> str:
    return (
        "# written by `geofuse sync --write`: the session's own settings (its inputs are never written)\n"
        f"[sync]\ntime_offset_s = {total_offset_s:.6f}   # seconds added to the video's times\n"
        f"drift_ppm = {result.drift_ppm:.2f}   # the video clock's rate error (fitted on long clips; 0 otherwise)\n"
        f"drift_pivot_s = {result.reference_s:.6f}   # session time at which the offset holds exactly\n"
        f"confidence = {result.confidence:.4f}\nwindows = {len(result.windows)}\n"
    )


def sync_session(session, progress: Callable[[float], None] | None = None) -> SyncResult:
    """The offset to add to the session's video times so that they agree with its gyroscope (or,
    without one, with a recorded attitude's rates)."""
    gyro = gyro_rates(session)
    rates = video_rates(session.video, bearings_of(session), session.rotation_cw, progress)
    clip_start = float(session.frame_times[0] - session.video.pts_s[0])
    return estimate_offset(rates, gyro, clip_start)
