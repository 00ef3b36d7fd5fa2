"""Attitude error measures.

BROAD's metric (Laidig et al. 2021): the error quaternion in the earth frame
q_err = q_est * conj(q_ref) (both device -> ENU), split into heading (its rotation about the
vertical, 2 atan(|z / w|)) and inclination (2 acos(sqrt(w^2 + z^2))); total = 2 acos(|w|); RMSE in
degrees over the scored samples. For 6D (IMU) estimates, whose absolute heading is unobservable,
one constant heading rotation (fitted over the scored samples) is removed first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.geodesy import rotations

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ErrorRMS:
    """RMS errors in degrees."""

    total: float
    heading: float
    inclination: float


def earth_error(q_est: npt.ArrayLike, q_ref: npt.ArrayLike) -> FloatArray:
    """q_est * conj(q_ref), canonical (w >= 0), (N, 4)."""
    return rotations.canonical(rotations.multiply(q_est, rotations.conjugate(q_ref)))


def remove_heading_offset(q_est: npt.ArrayLike, q_ref: npt.ArrayLike) -> FloatArray:
    """q_est rotated about the world vertical by the one constant angle that best aligns it with
    q_ref (circular mean of the per-sample heading errors)."""
    e = earth_error(q_est, q_ref)
    offset = rotations.circular_mean(2.0 * np.arctan2(e[:, 3], e[:, 0]))  # counter-clockwise, rad
    return rotations.multiply(rotations.heading_turn(np.degrees(offset)), q_est)


def broad_rms(
    q_est: npt.ArrayLike,
    q_ref: npt.ArrayLike,
    mask: npt.ArrayLike | None = None,
    remove_heading: bool = False,
) -> ErrorRMS:
    """BROAD RMSE (degrees) over the samples in `mask` where the reference is valid."""
    q_est = np.asarray(q_est, np.float64)
    q_ref = np.asarray(q_ref, np.float64)
    ok = np.all(np.isfinite(q_ref), axis=1) & np.all(np.isfinite(q_est), axis=1)
    if mask is not None:
        ok &= np.asarray(mask, bool)
    if not ok.any():
        raise ValueError("no valid samples to score")
    est, ref = q_est[ok], q_ref[ok]
    if remove_heading:
        est = remove_heading_offset(est, ref)
    e = earth_error(est, ref)
    w, z = np.abs(e[:, 0]), e[:, 3]
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    heading = 2.0 * np.arctan(np.abs(z) / np.maximum(w, 1e-12))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))

    def rms(x: FloatArray) -> float:
        return float(np.degrees(np.sqrt(np.mean(x * x))))

    return ErrorRMS(rms(total), rms(heading), rms(inclination))


def hpr_rms(
    q_est_cam: npt.ArrayLike, q_ref_cam: npt.ArrayLike
) -> tuple[float, float, float, float]:
    """RMS (deg) of heading (wrapped to +-180), pitch and roll of the optical axis, and total angle,
    for camera -> ENU quaternions: the layout of the paper's Table 2."""
    a = rotations.hpr_from_camera_quat(q_est_cam)
    b = rotations.hpr_from_camera_quat(q_ref_cam)
    d = rotations.wrap_degrees(a - b)
    total = np.degrees(rotations.angle_between(q_est_cam, q_ref_cam))
    r = np.sqrt(np.mean(d * d, axis=0))
    return float(r[0]), float(r[1]), float(r[2]), float(np.sqrt(np.mean(total * total)))
