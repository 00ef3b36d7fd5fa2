"""Attitude from phone inertial sensors (paper 2.1.2): gradient descent (Madgwick) and
complementary filters, each AHRS (with magnetometer) or IMU (without), and an offline option.

    estimate(t, gyr, acc, mag=None, method="gd" | "cf" | "offline", **gains) -> (N, 4)

returns quaternions [w, x, y, z] mapping device vectors to ENU (v_enu = q v q*) at the gyro times
t (seconds, increasing); gyr (N, 3) rad/s, acc (N, 3) m/s^2 (specific force: +up at rest), mag
(N, 3) uT or None (IMU form), all in the device frame and already resampled to t (see
`resample`). Heading is relative to magnetic north unless `declination_deg` (east positive) is
given. IMU forms cannot observe heading: theirs starts from a convention (see
`initial_orientation`) and drifts with the gyroscope.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from app.attitude import kernels
from app.attitude.initial import init_samples, initial_orientation
from app.attitude.offline import forward_backward
from app.geodesy import rotations
from app.io.streams import resample  # noqa: F401  (re-exported: part of this package's API)

FloatArray = npt.NDArray[np.float64]
METHODS = ("gd", "cf", "offline")


@dataclass(frozen=True)
class Gains:
    """Filter gains with units. Defaults were tuned on the BROAD undisturbed trials (docs/ATTITUDE.md).

    beta: Madgwick gain, rad/s; beta_start / ramp_s: start-up gain, decaying linearly to beta over
    ramp_s seconds; tau_acc / tau_mag: complementary time constants toward the accelerometer tilt
    and the compass heading, seconds; acc_reject: skip accelerometer (and magnetometer) correction
    while |acc| differs from its running norm by more than this fraction; bias_tau: time constant
    (s) of the gyroscope-bias estimate made while the device rests (0: off); init_s: seconds of
    samples averaged for the initial orientation.
    """

    beta: float = 0.015
    beta_start: float = 0.5
    ramp_s: float = 3.0
    tau_acc: float = 10.0
    tau_mag: float = 20.0
    acc_reject: float = float("inf")
    bias_tau: float = 2.0
    init_s: float = 0.2


# Per-method defaults, tuned on the seven BROAD trials in ../shared/data/broad (docs/ATTITUDE.md):
# rejecting accelerometer samples hurt gradient descent on fast translation, while the
# complementary filter, whose correction grows with the error angle, needs a tight gate.
DEFAULT_GAINS = {
    "gd": Gains(),
    "cf": Gains(acc_reject=0.05),
    "offline": Gains(acc_reject=1.0),
}


def _check(
    t: npt.ArrayLike, gyr: npt.ArrayLike, acc: npt.ArrayLike, mag: npt.ArrayLike | None
) -> tuple[FloatArray, ...]:
    t = np.ascontiguousarray(t, np.float64)
    gyr = np.ascontiguousarray(gyr, np.float64)
    acc = np.ascontiguousarray(acc, np.float64)
    n = len(t)
    if t.ndim != 1 or n < 2:
        raise ValueError(f"t must be 1-D with at least 2 samples, got shape {t.shape}")
    for name, arr in (("gyr", gyr), ("acc", acc)):
        if arr.shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be strictly increasing (seconds)")
    m = np.zeros((n, 3)) if mag is None else np.ascontiguousarray(mag, np.float64)
    if m.shape != (n, 3):
        raise ValueError(f"mag must have shape ({n}, 3), got {m.shape}")
    return t, gyr, acc, m


def _declination(q: FloatArray, declination_deg: float) -> FloatArray:
    """Rotate a magnetic-north-referenced ENU attitude to true north (east declination positive)."""
    if not declination_deg:
        return q
    # true heading = magnetic heading + declination
    return rotations.canonical(rotations.multiply(rotations.heading_turn(declination_deg), q))


def _run(
    method: str,
    t: FloatArray,
    gyr: FloatArray,
    acc: FloatArray,
    mag: FloatArray,
    use_mag: bool,
    g: Gains,
    q0: FloatArray,
) -> FloatArray:
    if method == "gd":
        return kernels.madgwick(
            t, gyr, acc, mag, use_mag, q0, g.beta, g.beta_start, g.ramp_s, g.acc_reject, g.bias_tau
        )
    return kernels.complementary(
        t, gyr, acc, mag, use_mag, q0, g.tau_acc, g.tau_mag, g.acc_reject, g.bias_tau
    )


def estimate(
    t: npt.ArrayLike,
    gyr: npt.ArrayLike,
    acc: npt.ArrayLike,
    mag: npt.ArrayLike | None = None,
    method: str = "gd",
    declination_deg: float = 0.0,
    **gains: float,
) -> FloatArray:
    """(N, 4) device -> ENU quaternions at times t. See the module docstring for units and frames.

    method: "gd" (Madgwick gradient descent), "cf" (complementary) or "offline" (forward and
    backward gradient-descent passes fused, with the gyroscope bias estimated from the whole clip:
    the estimate at t uses samples after t). gains: fields of `Gains`.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    t, gyr, acc, m = _check(t, gyr, acc, mag)
    unknown = set(gains) - set(Gains.__dataclass_fields__)
    if unknown:
        raise ValueError(
            f"unknown gains {sorted(unknown)}; known: {sorted(Gains.__dataclass_fields__)}"
        )
    g = replace(DEFAULT_GAINS[method], **gains)
    use_mag = mag is not None
    init = init_samples(t, g.init_s, gyr)
    q0 = initial_orientation(acc[init], m[init] if use_mag else None)
    if method == "offline":
        q = forward_backward(t, gyr, acc, m, use_mag, g)
    else:
        q = _run(method, t, gyr, acc, m, use_mag, g, q0)
    return _declination(rotations.canonical(q), declination_deg)
