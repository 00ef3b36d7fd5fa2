"""GNSS fixes tested against the scene (issue 52): a fix that disagrees with the registered
keyframes beyond its stated accuracy is a lie (spoofing, a jump, a drag-off, a frozen or replayed
track, a height that disagrees, multipath) and is not used; the track there stands on the scene.

Each fix is compared with the registered camera position at its time (linear between the two
registered keyframes around it, when both lie within reach_s): the residual (fix - scene, ENU m)
is median-filtered over `window` tested fixes (a keyframe registered wrongly moves one residual;
a median keeps a jump's edge where it is), and a fix whose horizontal residual exceeds
max(floor_m, n_sigma x its stated accuracy), or whose vertical one exceeds max(v_floor_m,
n_sigma x v_ratio x that accuracy), raises the alarm; so does one that ends a steady drift
(`drifting`: over the drift_s before it the residual walked away from the GNSS's own offset,
both halves of that span the same way, by more than max(drift_floor_m, drift_sigma x the
accuracy) while the accuracy stated held: a 2 m/s drag-off is caught 3 s after it begins, not
5.6 s when it passes 4.5 x 2.5 m). The lie began where the residual left the GNSS's own offset
before it (its median 30 to 10 s before the alarm): at a jump, or as far back from the moment it
had gone half as far as at the alarm as that moment is from the alarm (a drag-off grows
steadily; in a file, how far it had gone is taken along the way its fixes walk after the
alarm, so that the GNSS's own wander across it does not count); it lasts until a tested fix
agrees with the scene again: within release_sigma (3) times its accuracy of the GNSS's own
offset before it, not merely under the alarm's threshold.
What the fixes did there names it (`kind`): `frozen` where the fix at the alarm and those around
it have not moved (within still_m, for min_still_s or more: the receiver stopped while the
camera flew on; it began at the first of them), `replayed` where the lie's fixes repeat, within repeat_m, earlier
fixes at one steady lag (a recorded stretch played again; it began at the first repeated fix),
`height` where only the vertical residual left its bounds, `disagrees` otherwise (a jump, a
drag-off). The same forming and naming serves the test against the IMU's motion
(app.register.inertial: its innovations as the residual, witness `imu`), and `merged` makes the
two tests' lies one. Times are session seconds; positions local ENU metres
(app.geodesy.enu.LocalFrame).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from app.camera.fixes import FixStatus

FloatArray = npt.NDArray[np.float64]
DISAGREES, FROZEN, REPLAYED, HEIGHT = "disagrees", "frozen", "replayed", "height"
LIE_KINDS = (DISAGREES, FROZEN, REPLAYED, HEIGHT)
SCENE, IMU, BOTH = "scene", "imu", "scene and imu"  # what a lie was caught against
WITNESSES = (SCENE, IMU, BOTH)
WITNESS_WORDS = {
    SCENE: "the scene",
    IMU: "the IMU's motion",
    BOTH: "the scene and the IMU's motion",
}
JUMP_SHARE = 0.6  # a residual that steps by this share of its size at the alarm in one fix jumped
# between tested fixes farther apart than STEP_GAP_S (s: keyframes lost over a turn, fog) a
# rise is a step only if faster than a drag-off walks (DRAG_MAX_MPS, m/s); else it crossed
# half-way somewhere inside the gap, where a straight line between them says
STEP_GAP_S = 1.5
DRAG_MAX_MPS = 10.0
# a lie whose fixes walk within acos(WALK_ALONG) of the way it had gone from the GNSS's own
# offset at its alarm is a drag-off walking: a file's is dated along that walk (lies_of)
WALK_ALONG = 0.5


@dataclass(frozen=True)
class CheckSettings:
    """window: fixes in the running median of the residuals (odd); n_sigma, floor_m: the alarm
    threshold, max(floor_m, n_sigma x the stated horizontal accuracy) m; accuracy_m: the
    accuracy assumed (m, 1 sigma per axis) where the fixes state none; reach_s: a fix is tested
    where registered keyframes lie within this many seconds before and after it; baseline_s:
    the GNSS's own offset before an alarm is the median residual over the (start, end) seconds
    before the alarm; merge_s: alarms closer than this are one lie; v_ratio, v_floor_m: the
    vertical threshold, max(v_floor_m, n_sigma x v_ratio x the horizontal accuracy) m (GNSS
    heights are about twice as uncertain as positions); still_m: a fix within this (m, 3D) of
    the one before it has not moved (a frozen track repeats its fix to the millimetre; a
    receiver at rest wanders by decimetres a second); min_still_s: a frozen track has not moved
    for this long (s), at least (a receiver repeating a fix it did not update: shorter);
    repeat_m: a fix within this (m, 3D) of an earlier one repeats it (a replayed track);
    replay_max_s: the farthest back (s) a replay is looked for; drift_s, drift_sigma,
    drift_floor_m, drift_steady, drift_held: the drift test (`drifting`): over drift_s (s; 0:
    none) the residual went farther from the GNSS's own offset than max(drift_floor_m,
    drift_sigma x the largest accuracy stated there) m, each half of the span by drift_steady
    of it or more, where the stated accuracy held within drift_held x its least (a receiver
    that says it is less sure, under multipath, is left to the threshold); walk_s, walk_floor_m,
    walk_pieces, walk_steady: the longer walk test (`drifting`; walk_s 0: none), over walk_s
    (s) in walk_pieces pieces each moving it by walk_steady of the whole or more, beyond
    max(walk_floor_m, drift_sigma x the accuracy) m: a slow drag-off, 2 m/s against the 12 m
    that fixes stating no accuracy are held to, which the halves' 4 s never see walk that far
    (a 24 s DJI clip's: caught 4.8-5.2 s after it passed 5 m, not 7.7-9.5 s: docs/ACCURACY.md);
    release_sigma: a lie goes on while its fixes stand farther from the GNSS's own offset
    before it than the threshold taken at this many sigma instead of n_sigma (trust comes
    back more slowly than it went: a drag-off's median residual lags, and its fixes wander
    back under the alarm's threshold for a fix or two); onset_fit_s, onset_min_mps: where the
    fixes after an alarm are known (a file), a drag-off is dated by how far it had gone along
    its walk (`_walk`: its line fitted over up to onset_fit_s (s) of tested fixes from the
    alarm on, walking at onset_min_mps (m/s) or more), not by its distance from the GNSS's
    own offset, which the GNSS's wander across the walk moves as well."""

    window: int = 5
    n_sigma: float = 4.5
    floor_m: float = 5.0
    accuracy_m: float = 5.0
    reach_s: float = 1.0
    baseline_s: tuple[float, float] = (30.0, 10.0)
    merge_s: float = 10.0
    v_ratio: float = 2.0
    v_floor_m: float = 10.0
    still_m: float = 0.02
    min_still_s: float = 2.0
    repeat_m: float = 0.05
    replay_max_s: float = 600.0
    drift_s: float = 4.0
    drift_sigma: float = 2.4
    drift_floor_m: float = 6.0
    drift_steady: float = 0.25
    drift_held: float = 1.2
    walk_s: float = 8.0
    walk_floor_m: float = 8.0
    walk_pieces: int = 4
    walk_steady: float = 0.15
    release_sigma: float = 3.0
    onset_fit_s: float = 10.0
    onset_min_mps: float = 0.3

    def thresholds(self, accuracy_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(horizontal, vertical) m beyond which a fix stating accuracy_m (m, each fix's or
        one) disagrees: max(floor_m, n_sigma x it), max(v_floor_m, n_sigma x v_ratio x it)."""
        acc = np.asarray(accuracy_m, np.float64)
        return (
            np.maximum(self.floor_m, self.n_sigma * acc),
            np.maximum(self.v_floor_m, self.n_sigma * self.v_ratio * acc),
        )


def clip_time(
    t_s: float, t0_s: float = 0.0, utc_of: Callable[[float], float | None] | None = None
) -> str:
    """'09:47:40 (t = 40.0 s)', or 't = 40.0 s' where UTC is unknown: time t_s (s) as the lies'
    messages say it, clip time from t0_s (s), UTC where utc_of(t_s) knows it."""
    clip = f"t = {t_s - t0_s:.1f} s"
    utc = None if utc_of is None else utc_of(t_s)
    return clip if utc is None else f"{time.strftime('%H:%M:%S', time.gmtime(utc))} ({clip})"


@dataclass(frozen=True)
class GnssLie:
    """One lie: began_s when the fixes first left their own offset by more than their accuracy,
    caught_s the first fix beyond the threshold, worst_s and worst_m where and how far (m,
    horizontal; vertical for a `height` lie) they disagreed most with the scene, ended_s the last
    rejected fix (session s); offset (3,): the GNSS's own offset before it (fix - scene, ENU m);
    kind: LIE_KINDS (module docstring); replay_of_s: for a `replayed` lie, the session time of
    the earlier fix its first fix repeats (else None); witness (WITNESSES): what it was caught
    against, the registered keyframes (`scene`), the motion the IMU integrates
    (`imu`, app.register.inertial) or both; shift (3,) ENU m and shifted_s (first, last
    session s): a jump whose offset held, its fixes moved back by it and used over that span
    (app.register.inertial.shifted_back), else None; unseen_from_s: a lie caught live after a
    stretch where no keyframe tested the fixes (app.live.gnss_watch) began after this (session
    s) and by began_s, unseen between (else None); dragged: a drag-off whose fixes, less its
    line, carry the track where no keyframe registered (app.register.inertial.carried_track)."""

    began_s: float
    caught_s: float
    worst_s: float
    worst_m: float
    ended_s: float
    offset: FloatArray
    kind: str = DISAGREES
    replay_of_s: float | None = None
    witness: str = SCENE
    shift: FloatArray | None = None
    shifted_s: tuple[float, float] | None = None
    unseen_from_s: float | None = None
    dragged: bool = False

    def said(self, t0_s: float, utc_of: Callable[[float], float | None] | None = None) -> str:
        """One line for people, clip times from the first frame's session time t0_s (s) and
        UTC where utc_of(session s) knows it (app.session.model.Session.utc_of), by kind:
        "GNSS disagrees with the scene from 09:47:10 (t = 30.0 s), 38 m by 09:47:30 (t = 50.0 s):
        not used ...", "GNSS frozen from ..., 38 m behind the scene by ...", "GNSS replays its
        fixes of 09:46:50 (t = 10.0 s) from ..., 38 m off the scene by ...", "GNSS height
        disagrees with the scene by 40 m from ... (the most by ...)"; "the IMU's motion" or "the
        scene and the IMU's motion" where the IMU caught it."""

        def when(t: float) -> str:
            return clip_time(t, t0_s, utc_of)

        since = when(self.began_s)
        if self.unseen_from_s is not None:
            since = (
                f"some time between {when(self.unseen_from_s)} and {since} (no keyframe "
                "registered between)"
            )
        stands = "the scene's registered keyframes"
        if self.witness != SCENE:
            stands += " and the IMU's motion"
        caught = f"caught at t = {self.caught_s - t0_s:.1f} s"
        tail = f": not used ({caught}; the track stands on {stands} there)"
        if self.dragged:
            tail = (
                f": not used as given ({caught}; the track stands on {stands} there, and where"
                " none registered on the fixes' motion less the drag's line)"
            )
        far, by, what = f"{self.worst_m:.0f} m", when(self.worst_s), WITNESS_WORDS[self.witness]
        if self.shift is not None and self.shifted_s is not None:
            e, n, u = self.shift
            tail = (
                f": not used as given ({caught}); moved back by {np.linalg.norm(self.shift):.0f} m"
                f" (E {e:+.1f}, N {n:+.1f}, U {u:+.1f}) they agree with {what} again and carry"
                f" the track from t = {self.shifted_s[0] - t0_s:.1f} to "
                f"{self.shifted_s[1] - t0_s:.1f} s"
            )
        if self.kind == FROZEN:
            return f"GNSS frozen from {since}, {far} behind {what} by {by}{tail}"
        if self.kind == REPLAYED and self.replay_of_s is not None:
            return (
                f"GNSS replays its fixes of {when(self.replay_of_s)} from {since}, "
                f"{far} off {what} by {by}{tail}"
            )
        if self.kind == HEIGHT:
            return (
                f"GNSS height disagrees with {what} by {far} from {since} (the most by {by}){tail}"
            )
        return f"GNSS disagrees with {what} from {since}, {far} by {by}{tail}"


@dataclass(frozen=True)
class GnssCheck:
    """The outcome: status (which fixes were rejected), the lies found, and per fix the
    median-filtered residual (N, 3) fix - scene (ENU m; NaN where untested)."""

    status: FixStatus
    lies: tuple[GnssLie, ...]
    residual: FloatArray

    def lie_at(self, t_s: float) -> GnssLie | None:
        """The lie a rejected moment at session time t_s (s) belongs to: the one whose span
        [began_s, ended_s] lies nearest (its untested edge fixes are rejected too); None where
        there is none."""
        if not self.lies:
            return None
        gap = [max(lie.began_s - t_s, t_s - lie.ended_s, 0.0) for lie in self.lies]
        return self.lies[int(np.argmin(gap))]


def scene_positions(
    t_fix: FloatArray, key_t: FloatArray, key_enu: FloatArray, reach_s: float
) -> FloatArray:
    """(N, 3) the registered position (ENU m) at each fix time t_fix (s): linear between the
    registered keyframes (times key_t, increasing; positions key_enu (K, 3)) around it; NaN
    where either lies farther than reach_s or there is none."""
    out = np.full((len(t_fix), 3), np.nan)
    if len(key_t) < 2:
        return out
    j = np.clip(np.searchsorted(key_t, t_fix), 1, len(key_t) - 1)
    ok = (
        (key_t[j - 1] <= t_fix)
        & (key_t[j] >= t_fix)
        & (t_fix - key_t[j - 1] <= reach_s)
        & (key_t[j] - t_fix <= reach_s)
    )
    s = ((t_fix - key_t[j - 1]) / np.maximum(key_t[j] - key_t[j - 1], 1e-9))[:, None]
    out[ok] = ((1 - s) * key_enu[j - 1] + s * key_enu[j])[ok]
    return out


def running_median(x: FloatArray, window: int) -> FloatArray:
    """(N, D) the median of each row's centred window of `window` rows (shrunk at the ends)."""
    h = window // 2
    return np.array([np.median(x[max(0, i - h) : i + h + 1], axis=0) for i in range(len(x))])


def running_max(x: FloatArray, window: int) -> FloatArray:
    """(N,) the largest of each value's centred window of `window` values (shrunk at the ends)."""
    h = window // 2
    return np.array([x[max(0, i - h) : i + h + 1].max() for i in range(len(x))])


def own_offset(
    t: FloatArray, residual: FloatArray, t_s: float, settings: CheckSettings
) -> FloatArray | None:
    """The GNSS's own offset before session time t_s (s): the median of the residuals
    (N, D) m of the fixes at times t (N,) s, increasing, over settings.baseline_s (from, to s)
    before it; None where no fix lies there."""
    b0, b1 = settings.baseline_s
    lo, hi = np.searchsorted(t, t_s - b0), np.searchsorted(t, t_s - b1, side="right")
    return np.median(residual[lo:hi], axis=0) if hi > lo else None


def check_fixes(
    t_fix: npt.ArrayLike,
    enu_fix: npt.ArrayLike,
    accuracy_m: npt.ArrayLike | None,
    key_t: npt.ArrayLike,
    key_enu: npt.ArrayLike,
    settings: CheckSettings = CheckSettings(),
) -> GnssCheck:
    """The fixes (times t_fix (N,) s, positions enu_fix (N, 3) m, stated horizontal accuracy
    (N,) m or None) tested against the registered keyframes (times key_t (K,) s, positions
    key_enu (K, 3) m): which are rejected, and the lies (module docstring)."""
    t = np.asarray(t_fix, np.float64)
    enu = np.asarray(enu_fix, np.float64).reshape(-1, 3)
    acc = (
        np.full(len(t), settings.accuracy_m)
        if accuracy_m is None
        else np.where(np.isfinite(accuracy_m), accuracy_m, settings.accuracy_m)
    )
    order = np.argsort(np.asarray(key_t, np.float64))
    kt = np.asarray(key_t, np.float64)[order]
    kp = np.asarray(key_enu, np.float64).reshape(-1, 3)[order]
    raw = enu - scene_positions(t, kt, kp, settings.reach_s)
    tested = np.flatnonzero(np.isfinite(raw).all(axis=1))
    residual = np.full_like(raw, np.nan)
    rejected = np.zeros(len(t), bool)
    if len(tested) == 0:
        return GnssCheck(FixStatus(t, rejected), (), residual)
    residual[tested] = running_median(raw[tested], settings.window)
    off_h = np.linalg.norm(residual[tested, :2], axis=1)
    off_v = np.abs(residual[tested, 2])
    # a median carries the errors of the fixes it was taken over: held to the least sure of them
    # (as a burst of multipath ends, the newest fix states its clean accuracy again)
    held = running_max(acc[tested], settings.window)
    h, v = settings.thresholds(held)
    bad_h = (off_h > h) | drifting(t[tested], residual[tested], acc[tested], settings)
    bad_v = off_v > v
    # a lie goes on while its fixes stand farther than release_sigma off the GNSS's own offset
    limits = replace(settings, n_sigma=settings.release_sigma).thresholds(held)
    rejected, lies = lies_of(
        t, enu, residual, tested, bad_h, bad_v, settings, limits=limits, along_walk=True
    )
    return GnssCheck(FixStatus(t, rejected), tuple(lies), residual)


def drifting(
    t: FloatArray, residual: FloatArray, accuracy_m: FloatArray, settings: CheckSettings
) -> npt.NDArray[np.bool_]:
    """(T,) which tested fixes (times t (T,) s, increasing; median-filtered residuals (T, 3) ENU
    m; stated accuracy (T,) m) end a steady drift away from the GNSS's own offset (the median
    residual over baseline_s before them): over the drift_s before them the horizontal residual
    went farther from it by more than max(drift_floor_m, drift_sigma x the largest accuracy
    stated there), each half of that span moving it by drift_steady of the whole or more the
    same way (a drag-off walks on; the GNSS's own wander, multipath swinging it from one side
    to the other and a registration astray do not); or over the walk_s before them by more
    than max(walk_floor_m, drift_sigma x that accuracy), in walk_pieces pieces each moving it by
    walk_steady of the whole or more (a slow drag-off walks on for longer: multipath comes in
    within a piece or two, then holds). Either only where the stated accuracy held within
    drift_held x its least over the span. Where no tested fix lies within 1 s of a piece's
    edge, or none in the baseline's span, none is judged."""
    out = np.zeros(len(t), bool)
    for span_s, pieces, steady, floor_m in (
        (settings.drift_s, 2, settings.drift_steady, settings.drift_floor_m),
        (settings.walk_s, settings.walk_pieces, settings.walk_steady, settings.walk_floor_m),
    ):
        if span_s > 0 and len(t) > pieces:
            r = residual[:, :2]
            out |= _walked(t, r, accuracy_m, settings, span_s, pieces, steady, floor_m)
    return out


def _walked(
    t: FloatArray,
    r: FloatArray,
    accuracy_m: FloatArray,
    settings: CheckSettings,
    span_s: float,
    pieces: int,
    steady: float,
    floor_m: float,
) -> npt.NDArray[np.bool_]:
    """(T,) which fixes end a walk (`drifting`) over span_s (s) in `pieces` pieces, each
    moving the horizontal residual r (T, 2) m by `steady` of the whole or more the same way,
    by more than max(floor_m, drift_sigma x the largest accuracy stated over it)."""
    out = np.zeros(len(t), bool)

    def at(when: FloatArray) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        j = np.clip(np.searchsorted(t, when), 1, len(t) - 1)
        j = np.where(np.abs(t[j - 1] - when) < np.abs(t[j] - when), j - 1, j)
        return j, np.abs(t[j] - when) <= 1.0

    # the pieces' edges, from the span's start to the fix judged: (pieces, T) indices
    edges = [at(t - span_s * (1.0 - k / pieces)) for k in range(pieces)]
    idx = np.array([e[0] for e in edges] + [np.arange(len(t))])
    ok = np.logical_and.reduce([e[1] for e in edges]) & (idx[0] < np.arange(len(t)))
    for i in np.flatnonzero(ok):
        base = own_offset(t, r, t[i], settings)
        if base is None:
            continue
        j = idx[0, i]
        grew = np.linalg.norm(r[i] - base) - np.linalg.norm(r[j] - base)
        stated = accuracy_m[j : i + 1]
        limit = max(floor_m, settings.drift_sigma * stated.max())
        if grew <= limit or stated.max() > settings.drift_held * stated.min():
            continue
        d = r[i] - r[j]
        u = d / np.linalg.norm(d)
        moved = np.diff(r[idx[:, i]], axis=0) @ u
        out[i] = moved.min() >= steady * np.linalg.norm(d)
    return out


def lies_of(
    t: FloatArray,
    enu: FloatArray,
    residual: FloatArray,
    tested: npt.NDArray[np.int64],
    bad_h: npt.NDArray[np.bool_],
    bad_v: npt.NDArray[np.bool_],
    settings: CheckSettings,
    witness: str = SCENE,
    back_s: float | None = None,
    limits: tuple[FloatArray, FloatArray] | None = None,
    along_walk: bool = False,
) -> tuple[npt.NDArray[np.bool_], list[GnssLie]]:
    """(which fixes are rejected (N,), the lies) from the fixes' times t (N,) s and positions
    enu (N, 3) m, their residual (N, 3) m against a witness (NaN where untested), the tested
    fixes' indices (T,) and which of those passed the horizontal (bad_h (T,)) or vertical
    (bad_v) threshold: alarms within merge_s are one lie; it began where the residual left
    the GNSS's own offset before it (the module docstring) and is named by what the fixes did;
    witness (WITNESSES): what the residual was taken against; back_s: a lie began no farther
    than this (s) before its alarm (None: anywhere after the last lie); limits: the tested
    fixes' (horizontal, vertical) thresholds (T,) m each, where given a lie goes on while its
    fixes stand farther than these from the GNSS's own offset before it (a drag-off whose
    median residual lags or whose fix happens to wander back under the threshold for a fix or
    two, and which no keyframe tests after, is not ended there), until one comes back;
    along_walk: a lie that walks (a drag-off) is dated by how far it had gone along its walk,
    taken from the fixes after its alarm (`_walk`: a file's), not by its distance from the
    GNSS's own offset, which the GNSS's own wander across the walk moves as well (the
    scene's test of a file: 6 m across a 1 m/s drag said it from 10 s before it began)."""
    bad = bad_h | bad_v
    off_h = np.linalg.norm(residual[tested, :2], axis=1)
    off_v = np.abs(residual[tested, 2])
    rejected = np.zeros(len(t), bool)
    lies: list[GnssLie] = []
    n = 0  # tested fixes looked at so far
    while n < len(tested):
        hits = np.flatnonzero(bad[n:])
        if len(hits) == 0:
            break
        a = n + int(hits[0])  # the alarm: index into tested
        base = own_offset(t[tested], residual[tested], t[tested[a]], settings)
        if base is None:  # no clean stretch before it to learn the offset from
            base = np.zeros(3)
        off = bad.copy()  # the fixes that keep the lie going
        if limits is not None:
            off[a:] |= np.linalg.norm(residual[tested[a:], :2] - base[:2], axis=1) > limits[0][a:]
            off[a:] |= np.abs(residual[tested[a:], 2] - base[2]) > limits[1][a:]
        last = a  # the last bad fix, the lie going on while alarms follow within merge_s
        for k in range(a + 1, len(tested)):
            if off[k]:
                last = k
            elif t[tested[k]] - t[tested[last]] > settings.merge_s:
                break
        good_after = np.flatnonzero(~off[last + 1 :])
        end = len(t) if len(good_after) == 0 else tested[last + 1 + int(good_after[0])]
        upright = not bad_h[a : last + 1].any()  # only the height disagrees
        away = (
            np.abs(residual[tested, 2] - base[2])
            if upright
            else np.linalg.norm(residual[tested, :2] - base[:2], axis=1)
        )
        earliest = n
        if back_s is not None:
            earliest = max(n, int(np.searchsorted(t[tested], t[tested[a]] - back_s)))
        first, stepped = _onset(t[tested], away, earliest, a)
        kind, began, replay_of = DISAGREES, None, None
        still = _frozen_span(t, enu, int(tested[a]), settings)
        if still is not None:
            kind, began = FROZEN, still[0]
            # every fix of the frozen run is a lie, those a witness's growing spread lets pass too
            end = max(end, still[1] + 1)
            last = max(last, int(np.searchsorted(tested, still[1], side="right")) - 1)
        else:
            replay = _replayed(t, enu, int(tested[first]), end, settings)
            if replay is not None:
                kind = REPLAYED
                began, replay_of = _replay_start(t, enu, *replay, settings)
            elif upright:
                kind = HEIGHT
        if along_walk and kind == DISAGREES and not stepped:
            along = _walk(t[tested], residual[tested], a, last, settings)
            gone = residual[tested[a], :2] - base[:2]
            if along is not None and gone @ along >= WALK_ALONG * np.linalg.norm(gone):
                # a drag-off walking the way it had gone: dated along its walk, not across it
                along_away = (residual[tested, :2] - base[:2]) @ along
                first = _onset(t[tested], along_away, earliest, a)[0]
        if began is not None:  # the fixes themselves say where it began
            first = int(np.clip(np.searchsorted(t[tested], t[began]), n, a))
        # untested fixes inside it too, and those between it and the last tested fix before it
        # that agreed (the keyframes at a jump's edge are the ones the gate drops), within merge_s
        start = tested[first] if first == 0 else tested[first - 1] + 1
        start = max(start, int(np.searchsorted(t, t[tested[first]] - settings.merge_s)))
        if began is not None:
            start = min(start, began)
        rejected[start:end] = True
        off = off_v if upright else off_h
        worst = first + int(np.argmax(off[first : last + 1]))
        lies.append(
            GnssLie(
                float(t[tested[first]] if began is None else t[began]),
                float(t[tested[a]]),
                float(t[tested[worst]]),
                float(off[worst]),
                float(t[end - 1]),
                base,
                kind,
                replay_of,
                witness,
            )
        )
        n = last + 1
    return rejected, lies


def _onset(t: FloatArray, away: FloatArray, n: int, a: int) -> tuple[int, bool]:
    """Where a lie caught at index a (of times t (s) and distances `away` (m) of the residual from
    the GNSS's own offset) began, not before index n: a jump's first fix (where the residual
    stepped in one fix by more than JUMP_SHARE of its size at the alarm, caught there or a few
    fixes on, where the GNSS's own offset kept it under the threshold at first; across a gap
    in the tested fixes, faster than DRAG_MAX_MPS); a drag-off's, back from where it was half
    as far as at the alarm by as long again (a ramp: half-way in time), that moment where a
    straight line between the fixes either side of it crossed half-way (inside a gap too; the
    first fix past it would date a drag-off a fix late, twice over), so that the GNSS's own
    wander does not take it back farther. (That index, whether it stepped there.)"""
    half = a
    while half > n and away[half - 1] > 0.5 * away[a]:
        half -= 1
    crossed = float(t[half])
    if half > n:
        rise, gap = away[half] - away[half - 1], t[half] - t[half - 1]
        if rise > JUMP_SHARE * away[a] and (gap <= STEP_GAP_S or rise > DRAG_MAX_MPS * gap):
            return half, True
        if rise > 0.0:  # between the fixes either side, not at the first past it
            crossed = float(t[half - 1] + gap * (0.5 * away[a] - away[half - 1]) / rise)
    began = 2.0 * crossed - t[a]
    return max(n, int(np.searchsorted(t, began - 1e-6))), False


def _walk(
    t: FloatArray, residual: FloatArray, a: int, last: int, settings: CheckSettings
) -> FloatArray | None:
    """The direction (2,) (east, north unit vector) in which a lie caught at index a (of the
    tested fixes' times t (s) and residuals (T, 3) m) walks: its horizontal residual's line
    fitted over the fixes from the alarm to onset_fit_s after it, not past its last bad fix
    (index `last`); None where those span under 2 s or walk slower than onset_min_mps (m/s)."""
    after = np.arange(a, last + 1)
    after = after[t[after] <= t[a] + settings.onset_fit_s]
    if len(after) < 3 or t[after[-1]] - t[after[0]] < 2.0:
        return None
    dt = t[after] - t[a]
    fit = np.linalg.lstsq(np.column_stack([np.ones(len(dt)), dt]), residual[after, :2], rcond=None)  # fmt: skip
    speed = float(np.linalg.norm(fit[0][1]))
    return None if speed < settings.onset_min_mps else fit[0][1] / speed


def _frozen_span(
    t: FloatArray, enu: FloatArray, i: int, settings: CheckSettings
) -> tuple[int, int] | None:
    """(the first fix, the last) of a frozen run through fix i (times t (N,) s, positions enu
    (N, 3) m): consecutive fixes within settings.still_m of each other spanning
    settings.min_still_s or more (a receiver repeating an output it did not update is
    shorter); None where fix i moves."""
    step = np.r_[np.inf, np.linalg.norm(np.diff(enu, axis=0), axis=1), np.inf]  # into fix k
    lo, hi = i, i
    while step[lo] <= settings.still_m:
        lo -= 1
    while step[hi + 1] <= settings.still_m:
        hi += 1
    return (int(lo), int(hi)) if t[hi] - t[lo] >= settings.min_still_s else None


def _replayed(
    t: FloatArray, enu: FloatArray, start: int, end: int, settings: CheckSettings
) -> tuple[int, float] | None:
    """Whether the fixes start..end-1 (times t (N,) s, positions enu (N, 3) m) begin by
    repeating earlier ones, each within settings.repeat_m of a fix of the replay_max_s before
    `start`, at one lag (give or take a second and two fix intervals), for min_still_s or more
    from within merge_s of `start` (a recorded stretch played again: only its first `lag`
    seconds repeat fixes said before, what follows was never said): (the first repeating fix,
    the lag s); None where they do not."""
    earlier = np.flatnonzero((t < t[start]) & (t >= t[start] - settings.replay_max_s))
    if len(earlier) < 2 or end - start < 2:
        return None
    lie = np.arange(start, end)
    d, j = cKDTree(enu[earlier]).query(enu[lie])
    hit = lie[d <= settings.repeat_m]
    if len(hit) < 2 or t[hit[0]] - t[start] > settings.merge_s:
        return None
    lag = t[hit] - t[earlier[j[d <= settings.repeat_m]]]
    step = float(np.median(np.diff(t)))
    steady = np.abs(lag - lag[0]) <= 1.0 + 2 * step
    run = hit[steady]
    # the repeating fixes follow one another from the first (a gap of a fix or two allowed)
    gaps = np.diff(t[run]) > 3 * step
    run = run[: int(np.argmax(gaps)) + 1] if gaps.any() else run
    if t[run[-1]] - t[run[0]] < settings.min_still_s:
        return None
    return int(run[0]), float(np.median(t[run] - t[earlier[j[np.isin(lie, run)]]]))


def _replay_start(
    t: FloatArray, enu: FloatArray, i: int, lag_s: float, settings: CheckSettings
) -> tuple[int, float]:
    """(the first fix, back from fix i (one that repeats an earlier fix), that repeats the fix
    nearest lag_s (s) before it within settings.repeat_m; the session time (s) of the fix it
    repeats)."""

    def repeats(k: int) -> int | None:
        j = int(np.clip(np.searchsorted(t, t[k] - lag_s), 0, len(t) - 1))
        near = [m for m in (j - 1, j, j + 1) if 0 <= m < k]
        if not near:
            return None
        m = min(near, key=lambda m: abs(t[m] - (t[k] - lag_s)))
        return m if np.linalg.norm(enu[k] - enu[m]) <= settings.repeat_m else None

    first, of = i, repeats(i)
    while first > 0 and (m := repeats(first - 1)) is not None:
        first, of = first - 1, m
    return first, float(t[of] if of is not None else t[first] - lag_s)


def merged(scene: GnssCheck, imu: GnssCheck, merge_s: float = CheckSettings().merge_s) -> GnssCheck:
    """Two tests of the same fixes as one: a fix either rejected is rejected; lies within
    merge_s of each other are one (from the earlier alarm to the later end, the larger
    disagreement, a named kind over `disagrees`, the GNSS's own offset the scene's, both
    witnesses where both caught it). It began where a named kind's fixes say (the earlier),
    else where the IMU caught a step at the fix it stepped at (a jump), else where the scene's
    residual left the GNSS's own offset (no later than the alarm: the IMU's residual is no
    distance from where the platform is, and a drag-off's ramp cannot be read back from it),
    else at the earlier start; the fixes before that which only the IMU's lie took in (before
    a step, every one) are not rejected. The residual the scene's."""
    t = scene.status.t
    rejected = scene.status.rejected | imu.status.rejected
    groups: list[list[GnssLie]] = []
    for lie in sorted(scene.lies + imu.lies, key=lambda lie: lie.began_s):
        if groups and lie.began_s <= max(g.ended_s for g in groups[-1]) + merge_s:
            groups[-1].append(lie)
        else:
            groups.append([lie])
    lies = []
    for group in groups:
        worst = max(group, key=lambda lie: lie.worst_m)
        named = [lie for lie in group if lie.kind != DISAGREES]
        first = named[0] if named else group[0]
        seen = {lie.witness for lie in group}
        witness = seen.pop() if len(seen) == 1 else BOTH
        from_scene = [lie for lie in group if lie.witness == SCENE]
        # a step the IMU caught at the fix it stepped at (a jump): its start is exact, where
        # the scene may have tested no fix (fog: a jump inside it dated by the line across)
        stepped = [lie for lie in group if lie.witness == IMU and lie.caught_s <= lie.began_s]
        caught = min(lie.caught_s for lie in group)
        began = earliest = min(lie.began_s for lie in group)
        if named:
            began = min(lie.began_s for lie in named)
        elif stepped:
            began = min(lie.began_s for lie in stepped)
        elif from_scene:
            began = min(min(lie.began_s for lie in from_scene), caught)
        if earliest < began:  # an earlier start: the fixes before this one are kept that
            # only it took in (the IMU's), or all (before a step the IMU saw at its fix)
            kept = ~scene.status.rejected | bool(stepped and not named)
            rejected &= ~((t >= earliest) & (t < began) & kept)
        lies.append(
            GnssLie(
                began,
                caught,
                worst.worst_s,
                worst.worst_m,
                max(lie.ended_s for lie in group),
                from_scene[0].offset if from_scene else first.offset,
                first.kind,
                first.replay_of_s,
                witness,
            )
        )
    return GnssCheck(FixStatus(t, rejected), tuple(lies), scene.residual)
