"""Sequential filter loops, compiled with numba (cached on disk). Pure functions of arrays.

Conventions: quaternions [w, x, y, z], q maps device vectors to the world (ENU):
v_enu = q * v_dev * conj(q); gyroscope rad/s, device frame; accelerometer in any unit (only its
direction is used), device frame, measuring +up when at rest (specific force); magnetometer in any
unit, device frame. The world's magnetic reference lies in the North-Up plane, so the heading
these filters produce is relative to *magnetic* north; declination is applied by the caller.

The loops work on scalars and tuples of scalars only (nothing is allocated per sample), which is
what makes them faster than a C++ batch filter.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EPS = 1e-12
REST_RATE = 0.05  # rad/s: below this (raw) the device may be at rest
REST_ACC = 0.03  # fraction: accelerometer norm steadiness at rest
REST_MIN_S = 1.0  # seconds of rest before the bias estimate follows the rate
REST_STEADY = 0.01  # rad/s: at rest the rate stays this close to its own low-passed value ...
REST_SMOOTH_S = 0.5  # ... low-passed with this time constant (s); slow pans are not steady


@njit(cache=True, inline="always")
def _normalised(w: float, x: float, y: float, z: float) -> tuple:
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n < EPS:
        return 1.0, 0.0, 0.0, 0.0
    return w / n, x / n, y / n, z / n


@njit(cache=True, inline="always")
def _to_world(w: float, x: float, y: float, z: float, vx: float, vy: float, vz: float) -> tuple:
    """q * v * conj(q) for a 3-vector (device -> world)."""
    return (
        (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz,
        2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz,
        2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz,
    )


@njit(cache=True, inline="always")
def _mul(
    aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float, bz: float
) -> tuple:
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True, inline="always")
def field_gradient(
    w: float,
    x: float,
    y: float,
    z: float,
    dx: float,
    dy: float,
    dz: float,
    sx: float,
    sy: float,
    sz: float,
) -> tuple:
    """J^T f for f(q) = conj(q) d q - s: unit world reference d, unit device measurement s.

    Madgwick (2010), report eq. 19-20 with a general reference direction (dx, dy, dz).
    """
    f0 = 2 * dx * (0.5 - y * y - z * z) + 2 * dy * (w * z + x * y) + 2 * dz * (x * z - w * y) - sx
    f1 = 2 * dx * (x * y - w * z) + 2 * dy * (0.5 - x * x - z * z) + 2 * dz * (w * x + y * z) - sy
    f2 = 2 * dx * (w * y + x * z) + 2 * dy * (y * z - w * x) + 2 * dz * (0.5 - x * x - y * y) - sz
    return (
        (2 * dy * z - 2 * dz * y) * f0
        + (-2 * dx * z + 2 * dz * x) * f1
        + (2 * dx * y - 2 * dy * x) * f2,
        (2 * dy * y + 2 * dz * z) * f0
        + (2 * dx * y - 4 * dy * x + 2 * dz * w) * f1
        + (2 * dx * z - 2 * dy * w - 4 * dz * x) * f2,
        (-4 * dx * y + 2 * dy * x - 2 * dz * w) * f0
        + (2 * dx * x + 2 * dz * z) * f1
        + (2 * dx * w + 2 * dy * z - 4 * dz * y) * f2,
        (-4 * dx * z + 2 * dy * w + 2 * dz * x) * f0
        + (-2 * dx * w - 4 * dy * z + 2 * dz * y) * f1
        + (2 * dx * x + 2 * dy * y) * f2,
    )


@njit(cache=True, inline="always")
def _unbiased_rate(
    gyr: np.ndarray,
    acc: np.ndarray,
    i: int,
    dt: float,
    norm_ref: float,
    rest: np.ndarray,
    bias_tau: float,
) -> tuple:
    """The rate held over [t[i-1], t[i]] less the causal gyroscope-bias estimate made at rest.

    Rest: the raw rate under REST_RATE (rad/s), within REST_STEADY of its REST_SMOOTH_S low-pass,
    and the accelerometer norm within REST_ACC of its running value `norm_ref`, for more than
    REST_MIN_S seconds; then the raw rate is low-passed into the bias with time constant
    `bias_tau` (s; 0 = off). `rest` is the estimator's state, updated in place:
    [seconds at rest, bias x, y, z, low-passed rate x, y, z].
    """
    gx, gy, gz = gyr[i - 1, 0], gyr[i - 1, 1], gyr[i - 1, 2]
    if bias_tau <= 0.0:
        return gx, gy, gz
    ax, ay, az = acc[i - 1, 0], acc[i - 1, 1], acc[i - 1, 2]
    acc_norm = math.sqrt(ax * ax + ay * ay + az * az)
    k = dt / (REST_SMOOTH_S + dt)
    rest[4] += k * (gx - rest[4])
    rest[5] += k * (gy - rest[5])
    rest[6] += k * (gz - rest[6])
    rate = math.sqrt(gx * gx + gy * gy + gz * gz)
    wobble = math.sqrt((gx - rest[4]) ** 2 + (gy - rest[5]) ** 2 + (gz - rest[6]) ** 2)
    if (
        rate < REST_RATE
        and wobble < REST_STEADY
        and norm_ref > 0.0
        and abs(acc_norm - norm_ref) < REST_ACC * norm_ref
    ):
        rest[0] += dt
    else:
        rest[0] = 0.0
    if rest[0] > REST_MIN_S:
        kb = dt / (bias_tau + dt)
        rest[1] += kb * (gx - rest[1])
        rest[2] += kb * (gy - rest[2])
        rest[3] += kb * (gz - rest[3])
    return gx - rest[1], gy - rest[2], gz - rest[3]


@njit(cache=True, inline="always")
def _accept(an: float, norm_ref: float, acc_reject: float) -> tuple:
    """(use this accelerometer sample, updated running norm): a sample is used when its norm is
    within `acc_reject` (fraction) of the slowly tracked running norm."""
    if norm_ref == 0.0:
        norm_ref = an
    ok = abs(an - norm_ref) <= acc_reject * norm_ref
    return ok, norm_ref + 0.001 * (an - norm_ref)


@njit(cache=True)
def _start(q0: np.ndarray, gyr: np.ndarray, n: int) -> tuple:
    """(output (n, 4) with row 0 = the normalised q0, its w, x, y, z, and the initial state of
    `_unbiased_rate`: no rest yet, zero bias, the low-passed rate at the first sample)."""
    out = np.empty((n, 4))
    w, x, y, z = _normalised(q0[0], q0[1], q0[2], q0[3])
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    rest = np.zeros(7)
    rest[4], rest[5], rest[6] = gyr[0, 0], gyr[0, 1], gyr[0, 2]
    return out, w, x, y, z, rest


@njit(cache=True, nogil=True)
def madgwick(
    t: np.ndarray,
    gyr: np.ndarray,
    acc: np.ndarray,
    mag: np.ndarray,
    use_mag: bool,
    q0: np.ndarray,
    beta: float,
    beta_start: float,
    ramp_s: float,
    acc_reject: float,
    bias_tau: float,
) -> np.ndarray:
    """Madgwick's gradient-descent filter (AHRS with `use_mag`, IMU without). Returns (N, 4).

    beta: gain (rad/s) after the start-up ramp; beta_start: gain at t[0], decaying linearly to
    beta over `ramp_s` seconds (fast convergence from a rough start); acc_reject: an accelerometer
    sample whose norm differs from its running norm by more than this fraction is not used for
    correction (impacts, tapping); bias_tau: time constant (s) of the rest-based gyroscope bias
    estimate (0 turns it off). dt comes from consecutive timestamps; the rate of sample i-1 is held
    over [t[i-1], t[i]].
    """
    n = t.shape[0]
    out, w, x, y, z, rest = _start(q0, gyr, n)
    norm_ref = 0.0
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        if dt > 0.0 and dt <= 1.0:
            gx, gy, gz = _unbiased_rate(gyr, acc, i, dt, norm_ref, rest, bias_tau)
            dw = 0.5 * (-x * gx - y * gy - z * gz)
            dx_ = 0.5 * (w * gx + y * gz - z * gy)
            dy_ = 0.5 * (w * gy - x * gz + z * gx)
            dz_ = 0.5 * (w * gz + x * gy - y * gx)
            s0 = s1 = s2 = s3 = 0.0
            ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
            an = math.sqrt(ax * ax + ay * ay + az * az)
            if an > EPS and math.isfinite(an):
                ok, norm_ref = _accept(an, norm_ref, acc_reject)
                if ok:
                    s0, s1, s2, s3 = field_gradient(
                        w, x, y, z, 0.0, 0.0, 1.0, ax / an, ay / an, az / an
                    )
                    if use_mag:
                        mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
                        mn = math.sqrt(mx * mx + my * my + mz * mz)
                        if mn > EPS and math.isfinite(mn):
                            mx, my, mz = mx / mn, my / mn, mz / mn
                            hx, hy, hz = _to_world(w, x, y, z, mx, my, mz)
                            m0, m1, m2, m3 = field_gradient(
                                w, x, y, z, 0.0, math.sqrt(hx * hx + hy * hy), hz, mx, my, mz
                            )
                            s0, s1, s2, s3 = s0 + m0, s1 + m1, s2 + m2, s3 + m3
            sn = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
            if sn > EPS:
                elapsed = t[i] - t[0]
                gain = (
                    beta
                    if elapsed >= ramp_s
                    else beta_start + (beta - beta_start) * elapsed / ramp_s
                )
                k = gain / sn
                dw -= k * s0
                dx_ -= k * s1
                dy_ -= k * s2
                dz_ -= k * s3
            w, x, y, z = _normalised(w + dw * dt, x + dx_ * dt, y + dy_ * dt, z + dz_ * dt)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w, x, y, z
    return out


@njit(cache=True, inline="always")
def _rotation(ax: float, ay: float, az: float, angle: float) -> tuple:
    s = math.sin(0.5 * angle)
    return math.cos(0.5 * angle), ax * s, ay * s, az * s


@njit(cache=True, nogil=True)
def complementary(
    t: np.ndarray,
    gyr: np.ndarray,
    acc: np.ndarray,
    mag: np.ndarray,
    use_mag: bool,
    q0: np.ndarray,
    tau_acc: float,
    tau_mag: float,
    acc_reject: float,
    bias_tau: float,
) -> np.ndarray:
    """Complementary filter: gyro integration, corrected toward the accelerometer's tilt and (AHRS)
    the tilt-compensated compass heading, each with a first-order time constant (seconds).

    Each step: q <- q * exp(0.5 g dt) (exact for a constant rate); then the rotation taking the
    measured up (in the world) onto (0, 0, 1) is applied by the fraction dt/(tau_acc + dt) about a
    horizontal world axis (tilt only), and the heading error of the horizontal magnetic field is
    removed by the fraction dt/(tau_mag + dt) about world Up (heading only). Splitting the two keeps
    magnetic disturbances out of tilt (Valenti et al. 2015 do the same with quaternions).
    acc_reject and bias_tau as in `madgwick`.
    """
    n = t.shape[0]
    out, w, x, y, z, rest = _start(q0, gyr, n)
    norm_ref = 0.0
    for i in range(1, n):
        dt = t[i] - t[i - 1]
        if dt > 0.0 and dt <= 1.0:
            gx, gy, gz = _unbiased_rate(gyr, acc, i, dt, norm_ref, rest, bias_tau)
            rate = math.sqrt(gx * gx + gy * gy + gz * gz)
            if rate > EPS:
                rw, rx, ry, rz = _rotation(gx / rate, gy / rate, gz / rate, rate * dt)
                w, x, y, z = _mul(w, x, y, z, rw, rx, ry, rz)
            ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
            an = math.sqrt(ax * ax + ay * ay + az * az)
            if an > EPS and math.isfinite(an):
                ok, norm_ref = _accept(an, norm_ref, acc_reject)
                if ok:
                    ux, uy, uz = _to_world(w, x, y, z, ax / an, ay / an, az / an)
                    s = math.sqrt(ux * ux + uy * uy)  # axis = up x (0,0,1) = (uy, -ux, 0)
                    if s > EPS:
                        rw, rx, ry, rz = _rotation(
                            uy / s, -ux / s, 0.0, math.atan2(s, uz) * dt / (tau_acc + dt)
                        )
                        w, x, y, z = _mul(rw, rx, ry, rz, w, x, y, z)
            if use_mag:
                mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
                mn = math.sqrt(mx * mx + my * my + mz * mz)
                if mn > EPS and math.isfinite(mn):
                    hx, hy, hz = _to_world(w, x, y, z, mx / mn, my / mn, mz / mn)
                    if hx * hx + hy * hy > EPS:
                        err = math.atan2(hx, hy)  # the field's horizontal angle east of north
                        rw, rx, ry, rz = _rotation(0.0, 0.0, 1.0, err * dt / (tau_mag + dt))
                        w, x, y, z = _mul(rw, rx, ry, rz, w, x, y, z)
            w, x, y, z = _normalised(w, x, y, z)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w, x, y, z
    return out
