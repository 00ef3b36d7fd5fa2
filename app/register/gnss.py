"""GNSS fixes tested against the scene (issue 52): a fix that disagrees with the registered
keyframes beyond its stated accuracy is a lie (spoofing, a jump, a drag-off, multipath) and is
not used; the track there stands on the scene.

Each fix is compared with the registered camera position at its time (linear between the two
registered keyframes around it, when both lie within reach_s): the residual (fix - scene, ENU m)
is median-filtered over `window` tested fixes (a keyframe registered wrongly moves one residual;
a median keeps a jump's edge where it is), and a fix whose horizontal residual exceeds
max(floor_m, n_sigma x its stated accuracy) raises the alarm. The lie began where the residual
left the GNSS's own offset before it (its median 30 to 10 s before the alarm): at a jump, or as
far back from the moment it had gone half as far as at the alarm as that moment is from the
alarm (a drag-off grows steadily); it lasts until a tested fix agrees with the scene again. Times are session seconds;
positions local ENU metres (app.geodesy.enu.LocalFrame).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.camera.fixes import FixStatus

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CheckSettings:
    """window: fixes in the running median of the residuals (odd); n_sigma, floor_m: the alarm
    threshold, max(floor_m, n_sigma x the stated horizontal accuracy) m; accuracy_m: the
    accuracy assumed (m, 1 sigma per axis) where the fixes state none; reach_s: a fix is tested
    where registered keyframes lie within this many seconds before and after it; baseline_s:
    the GNSS's own offset before an alarm is the median residual over the (start, end) seconds
    before the alarm; merge_s: alarms closer than this are one lie."""

    window: int = 5
    n_sigma: float = 4.5
    floor_m: float = 5.0
    accuracy_m: float = 5.0
    reach_s: float = 1.0
    baseline_s: tuple[float, float] = (30.0, 10.0)
    merge_s: float = 10.0


@dataclass(frozen=True)
class GnssLie:
    """One lie: began_s when the fixes first left their own offset by more than their accuracy,
    caught_s the first fix beyond the threshold, worst_s and worst_m where and how far (m,
    horizontal) they disagreed most with the scene, ended_s the last rejected fix (session s);
    offset (3,): the GNSS's own offset before it (fix - scene, ENU m)."""

    began_s: float
    caught_s: float
    worst_s: float
    worst_m: float
    ended_s: float
    offset: FloatArray

    def said(self, t0_s: float, utc_of: Callable[[float], float | None] | None = None) -> str:
        """One line for people, clip times from the first frame's session time t0_s (s) and
        UTC where utc_of(session s) knows it (app.session.model.Session.utc_of): "GNSS
        disagrees with the scene from 09:47:10 (t = 30.0 s), 38 m by 09:47:30 (t = 50.0 s):
        not used"."""

        def when(t: float) -> str:
            clip = f"t = {t - t0_s:.1f} s"
            utc = None if utc_of is None else utc_of(t)
            if utc is None:
                return clip
            return f"{time.strftime('%H:%M:%S', time.gmtime(utc))} ({clip})"

        return (
            f"GNSS disagrees with the scene from {when(self.began_s)}, {self.worst_m:.0f} m by "
            f"{when(self.worst_s)}: not used (caught at t = {self.caught_s - t0_s:.1f} s; the "
            "track stands on the scene's registered keyframes there)"
        )


@dataclass(frozen=True)
class GnssCheck:
    """The outcome: status (which fixes were rejected), the lies found, and per fix the
    median-filtered residual (N, 3) fix - scene (ENU m; NaN where untested)."""

    status: FixStatus
    lies: tuple[GnssLie, ...]
    residual: FloatArray


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
    off = np.linalg.norm(residual[tested, :2], axis=1)
    bad = off > np.maximum(settings.floor_m, settings.n_sigma * acc[tested])
    lies: list[GnssLie] = []
    n = 0  # tested fixes looked at so far
    while n < len(tested):
        hits = np.flatnonzero(bad[n:])
        if len(hits) == 0:
            break
        a = n + int(hits[0])  # the alarm: index into tested
        b0, b1 = settings.baseline_s
        before = (t[tested] >= t[tested[a]] - b0) & (t[tested] <= t[tested[a]] - b1)
        base = (
            np.median(residual[tested[before]], axis=0)
            if before.any()
            else np.zeros(3)  # no clean stretch before it to learn the offset from
        )
        away = np.linalg.norm(residual[tested, :2] - base[:2], axis=1)
        first = _onset(t[tested], away, n, a)
        last = a  # the last bad fix, the lie going on while alarms follow within merge_s
        for k in range(a + 1, len(tested)):
            if bad[k]:
                last = k
            elif t[tested[k]] - t[tested[last]] > settings.merge_s:
                break
        good_after = np.flatnonzero(~bad[last + 1 :])
        end = len(t) if len(good_after) == 0 else tested[last + 1 + int(good_after[0])]
        # untested fixes inside it too, and those between it and the last tested fix before it
        # that agreed (the keyframes at a jump's edge are the ones the gate drops), within merge_s
        start = tested[first] if first == 0 else tested[first - 1] + 1
        start = max(start, int(np.searchsorted(t, t[tested[first]] - settings.merge_s)))
        rejected[start:end] = True
        worst = first + int(np.argmax(off[first : last + 1]))
        lies.append(
            GnssLie(
                float(t[tested[first]]),
                float(t[tested[a]]),
                float(t[tested[worst]]),
                float(off[worst]),
                float(t[end - 1]),
                base,
            )
        )
        n = last + 1
    return GnssCheck(FixStatus(t, rejected), tuple(lies), residual)


def _onset(t: FloatArray, away: FloatArray, n: int, a: int) -> int:
    """Where a lie caught at index a (of times t (s) and distances `away` (m) of the residual from
    the GNSS's own offset) began, not before index n: a jump's first fix; a drag-off's, back from
    where it was half as far as at the alarm by as long again (a ramp: half-way in time), so
    that the GNSS's own wander does not take it back farther."""
    half = a
    while half > n and away[half - 1] > 0.5 * away[a]:
        half -= 1
    began = 2.0 * t[half] - t[a]
    return max(n, int(np.searchsorted(t, began - 1e-6)))


def on_scene(enu_fix: FloatArray, check: GnssCheck) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """The fixes moved onto the scene where rejected: (positions (N, 3) ENU m: a rejected fix
    less what its lie added (its median residual less the GNSS's own offset before the lie),
    i.e. the registered position at its time carrying that offset on, so that the fused
    corrections (scene - prior) run on without a step where the lie begins; a rejected fix
    nothing registered near (past the last keyframe) less what the lie added at the nearest
    tested one; the others as they were; keep (N,): False for fixes of a lie none of whose fixes
    was tested, which the track leaves out)."""
    t = check.status.t
    enu = np.asarray(enu_fix, np.float64).copy()
    keep = ~check.status.rejected
    tested = np.flatnonzero(np.isfinite(check.residual).all(axis=1))
    for lie in check.lies:
        inside = np.flatnonzero((t >= lie.began_s) & (t <= lie.ended_s))
        known = np.intersect1d(inside, tested)
        if len(known) == 0:
            continue
        nearest = known[np.abs(t[known][None, :] - t[inside][:, None]).argmin(axis=1)]
        enu[inside] -= check.residual[nearest] - lie.offset
        keep[inside] = True
    return enu, keep
