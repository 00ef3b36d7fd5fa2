"""The offset (and drift) that best fits the video's rates to the reference's (app.sync, steps
3-4): a coarse lag from the rate magnitudes' cross-correlation, a fine one on the windows that
say most about time, a drift on long clips.

Times: session seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from app.sync.rates import RateCurve

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

    def report(self, first_frame_s: float) -> list[str]:
        """What `geofuse sync` prints after the offset line: the drift (when fitted; the pivot
        in seconds from the first frame at `first_frame_s`, session s) and the windows fitted."""
        lines = []
        if self.drift_ppm:
            lines.append(
                f"clock drift: the video's clock runs {self.drift_ppm:+.0f} ppm against the sensors' ({self.drift_ppm * 1e-6 * 60 * 1000:+.1f} ms a minute); the offset holds at {self.reference_s - first_frame_s:.1f} s"
            )
        lines.append(
            f"fitted on {len(self.windows)} windows of {self.windows[0][1] - self.windows[0][0]:.1f} s that say most about time (where the rates change fastest)"
            if self.windows
            else "no window with rotation"
        )
        return lines


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
