"""Which GNSS fixes a camera track stands on, and so what posed each frame: `used` (the fix
is in the track), `rejected` (it disagrees with the scene's registered keyframes or with the
IMU's motion beyond its stated accuracy: the track there stands on the scene, carried by the
IMU between keyframes, app.register.gnss and app.register.inertial), `missing` (no fix within
the gap limit: app.camera.trajectory.gap_intervals). Times are session seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.camera.trajectory import gap_intervals, gap_limit_s

FloatArray = npt.NDArray[np.float64]
USED, REJECTED, MISSING = "used", "rejected", "missing"
STATES = (USED, REJECTED, MISSING)


@dataclass(frozen=True)
class FixStatus:
    """t (N,) the fixes' session times (s, increasing); rejected (N,) whether each was set
    aside as a lie."""

    t: FloatArray
    rejected: npt.NDArray[np.bool_]

    @classmethod
    def all_used(cls, t: npt.ArrayLike) -> FixStatus:
        """Every fix at times t (s) used (no test made, or none failed)."""
        t = np.asarray(t, np.float64)
        return cls(t, np.zeros(len(t), bool))

    @property
    def gap_limit_s(self) -> float:
        """An interval between fixes longer than this (s) is an outage (gap_intervals' rule)."""
        return gap_limit_s(self.t)

    def at(self, tq: npt.ArrayLike) -> npt.NDArray[np.str_]:
        """(M,) USED, REJECTED or MISSING at session times tq (s): MISSING inside an outage or
        farther than the gap limit beyond the first or last fix; REJECTED between fixes either
        of which was rejected (or beyond a rejected first or last one); USED otherwise. A time
        on a fix's own time stands on that fix alone (USED or REJECTED), even at an outage's
        edge."""
        tq = np.atleast_1d(np.asarray(tq, np.float64))
        out = np.full(len(tq), USED, dtype="<U8")
        if len(self.t) == 0:
            out[:] = MISSING
            return out
        i = np.searchsorted(self.t, tq, side="right") - 1  # the fix at or before each time
        before, after = i < 0, i >= len(self.t) - 1
        a, b = np.clip(i, 0, len(self.t) - 1), np.clip(i + 1, 0, len(self.t) - 1)
        out[self.rejected[a] | self.rejected[b]] = REJECTED
        gaps = np.append(gap_intervals(self.t), False)
        limit = self.gap_limit_s
        out[(~before & ~after & gaps[a]) | (before & (self.t[0] - tq > limit))] = MISSING
        out[after & (tq - self.t[-1] > limit)] = MISSING
        on = (i >= 0) & (self.t[a] == tq)  # exactly at a fix: that fix's own verdict
        out[on] = np.where(self.rejected[a[on]], REJECTED, USED)
        return out

    def outages(self, t0_s: float, t1_s: float) -> list[tuple[float, float]]:
        """(start, end) session seconds of each stretch of [t0_s, t1_s] (the video's span) with no
        fix within the gap limit: between fixes around an outage, and before the first or after
        the last fix where the video runs on farther than the limit."""
        out: list[tuple[float, float]] = []
        if len(self.t) == 0:
            return [(t0_s, t1_s)]
        limit = self.gap_limit_s
        if self.t[0] - t0_s > limit:
            out.append((t0_s, float(self.t[0])))
        for k in np.flatnonzero(gap_intervals(self.t)):
            a, b = max(float(self.t[k]), t0_s), min(float(self.t[k + 1]), t1_s)
            if b > a:
                out.append((a, b))
        if t1_s - self.t[-1] > limit:
            out.append((float(self.t[-1]), t1_s))
        return out


def outage_said(start_s: float, end_s: float, t0_s: float) -> str:
    """'no GNSS from t = 30.0 s to 90.0 s (60 s)': an outage from session time start_s to end_s
    (s), said in clip time (seconds from the first frame's session time t0_s)."""
    return (
        f"no GNSS from t = {start_s - t0_s:.1f} s to {end_s - t0_s:.1f} s ({end_s - start_s:.0f} s)"
    )
