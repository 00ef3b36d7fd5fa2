"""Magnetometer calibration from the clip itself: the hard-iron offset fitted so that the
calibrated field's strength matches the World Magnetic Model's at the site.

A phone's own calibration leaves residual offsets of a few uT, worth several degrees of heading
where the horizontal field is ~30 uT. Reviewing a clip after the fact, geofuse can fit the offset
on the whole clip: minimise sum (|m - b| - F)^2 over b (uT) and the local field strength F, with
Gaussian priors (b ~ 5 uT around 0, F ~ 3 uT around the WMM's strength: local fields differ from
the model) weighted as PRIOR_WEIGHT of the samples, because the samples of a clip are strongly
correlated (the phone turns slowly), so their count overstates what they know. A per-axis scale is not fitted:
a walk's few orientations cannot separate it from the offset (tried: it ran off to -28 %).
Skipped (with a reason) when the field directions span too little.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

PRIOR_OFFSET_UT = 5.0
PRIOR_STRENGTH_UT = 3.0
PRIOR_WEIGHT = 0.01  # the prior counts as this fraction of the samples
MIN_SPREAD = 0.005  # second eigenvalue of the unit field directions' covariance
MAX_SAMPLES = 4000  # the fit uses at most this many samples, evenly spaced
RESIDUAL_UT = 1.0  # expected misfit of one sample's field strength (noise, unmodelled soft iron)


@dataclass(frozen=True)
class MagCalibration:
    offset_ut: np.ndarray
    rms_before_ut: float
    rms_after_ut: float

    def apply(self, mag: np.ndarray) -> np.ndarray:
        return mag - self.offset_ut

    def describe(self) -> str:
        b = ", ".join(f"{v:+.2f}" for v in self.offset_ut)
        return f"hard-iron offset ({b}) uT; field strength spread {self.rms_before_ut:.2f} -> {self.rms_after_ut:.2f} uT RMS"


def fit(mag: np.ndarray, field_strength_ut: float) -> MagCalibration | str:
    """The calibration, or a string saying why none was fitted."""
    m = np.asarray(mag, np.float64)
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < 50:
        return f"only {len(m)} magnetometer samples"
    m = m[np.linspace(0, len(m) - 1, min(len(m), MAX_SAMPLES)).astype(int)]
    u = m / np.linalg.norm(m, axis=1, keepdims=True)
    spread = np.sort(np.linalg.eigvalsh(np.cov(u.T)))
    if spread[1] < MIN_SPREAD:
        return f"the clip turns too little to calibrate the magnetometer (spread {spread[1]:.3f} < {MIN_SPREAD})"

    weight = RESIDUAL_UT * np.sqrt(PRIOR_WEIGHT * len(m))

    def residuals(p: np.ndarray) -> np.ndarray:
        # In units of RESIDUAL_UT: sum (r / s_r)^2 + PRIOR_WEIGHT * N * ((b / s_b)^2 + (dF / s_F)^2).
        b, strength = p[:3], p[3]
        prior = np.append(b / PRIOR_OFFSET_UT, (strength - field_strength_ut) / PRIOR_STRENGTH_UT)
        return np.concatenate([np.linalg.norm(m - b, axis=1) - strength, weight * prior])

    sol = least_squares(residuals, np.append(np.zeros(3), field_strength_ut))
    before = float(np.std(np.linalg.norm(m, axis=1)))
    after = float(np.sqrt(np.mean(sol.fun[: len(m)] ** 2)))
    return MagCalibration(sol.x[:3], before, after)
