"""The initial orientation of the attitude filters (paper 2.1.2: initialised from the first
accelerometer and magnetometer samples), shared by the causal filters and the offline passes."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.geodesy import rotations

FloatArray = npt.NDArray[np.float64]


def initial_orientation(acc: npt.ArrayLike, mag: npt.ArrayLike | None = None) -> FloatArray:
    """Device -> ENU quaternion from averaged accelerometer (and magnetometer) samples (TRIAD).

    Up is the accelerometer direction; with a magnetometer, north is the horizontal part of the
    field; without one, north is the horizontal part of the device's y axis (or, when y is near
    vertical, of its -z axis), which fixes the arbitrary heading of the IMU forms.
    """
    a = np.mean(np.atleast_2d(acc), axis=0)
    up = a / np.linalg.norm(a)
    if mag is not None:
        ref = np.mean(np.atleast_2d(mag), axis=0)
    else:
        ref = np.array([0.0, 1.0, 0.0]) if abs(up[1]) < 0.9 else np.array([0.0, 0.0, -1.0])
    east = np.cross(ref, up)
    if np.linalg.norm(east) < 1e-9:
        raise ValueError("initial magnetic field is parallel to gravity: heading undefined")
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    # Rows are the world axes in device coordinates: R_world<-device.
    return rotations.from_matrix(np.stack([east, north, up]))


INIT_MAX_TURN_RAD = np.radians(
    0.5
)  # averaging over a window in which the device turns more is biased


def init_samples(t: FloatArray, seconds: float, gyr: FloatArray | None = None) -> slice:
    """The first `seconds` of samples to average for the initial orientation, or only the first
    sample when the device turns by more than INIT_MAX_TURN_RAD within that window."""
    k = max(1, min(int(np.searchsorted(t, t[0] + seconds)) + 1, len(t)))
    if (
        gyr is not None
        and k > 1
        and np.linalg.norm(gyr[:k], axis=1).max() * (t[k - 1] - t[0]) > INIT_MAX_TURN_RAD
    ):
        return slice(0, 1)
    return slice(0, k)
