"""Smartphone sensor error model for simulated sessions. Every number has a unit and a source.

Sources (typical values; a phone's OS calibration removes most of the raw offsets):
- Gyroscope and accelerometer: Bosch Sensortec BMI160 datasheet (BST-BMI160-DS000), a common
  phone IMU: gyroscope output noise 0.007 deg/s/sqrt(Hz); accelerometer noise density
  180 ug/sqrt(Hz); zero-rate offset +-3 deg/s and zero-g offset +-40 mg before calibration.
  Residuals after the OS's calibration are taken as 0.1 deg/s and 10 mg (our assumption, of the
  order reported for calibrated Android sensors), with a gyroscope bias random walk of
  0.0005 deg/s/sqrt(s).
- Magnetometer: AKM AK09916 datasheet (a common phone magnetometer): 0.15 uT/LSB resolution;
  we use 0.3 uT RMS noise. Hard-iron residual +-2 uT and soft-iron (scale/cross-axis) 2 % after
  calibration (assumption). Near steel and reinforced concrete the field is disturbed: modelled
  as a dipole-like extra field of `disturbance_uT` at 1 m from the building, falling off as 1/d^3.
- GNSS: smartphone fixes at 1 Hz with metre-level, time-correlated error: first-order
  Gauss-Markov, sigma 2.5 m horizontal and 4 m vertical, correlation time 30 s (consistent with
  the ~5 m 95 % horizontal accuracy that Merry & Bettinger, PLoS ONE 2019, measured for phones);
  speed noise 0.15 m/s, bearing from the noisy velocity.
- Multipath (urban canyons, under bridges, near tall buildings: issue 52): bursts of a few
  seconds in which the fix is pulled several metres off, coming in and going over a second or
  two; the receiver says it, in part, by a larger stated accuracy (u-blox's hAcc grows under
  multipath, if by less than the error). Our assumption: a burst every 20 s on average, 3-8 s
  long, 3-8 m horizontally (1.5 times that in height), its stated accuracy the clean one and half
  the burst added in quadrature.
- Callback clocks: each stream on its own clock with jitter of +-20 % of the period and 0.5 %
  of samples dropped, as phones deliver them (the paper's "each time any sensor callback").
- The phone's own fused orientation: the truth with a slowly wandering heading error (sigma 3 deg,
  correlation time 20 s) and 0.3 deg tilt noise, at 50 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.geodesy import rotations

DEG = np.pi / 180.0
G = 9.80665


@dataclass(frozen=True)
class SensorErrors:
    """Error-model parameters (units in the names); defaults as in the module docstring."""

    gyro_noise_dps_rthz: float = 0.007
    gyro_bias_dps: float = 0.1
    gyro_bias_walk_dps_rts: float = 0.0005
    acc_noise_ug_rthz: float = 180.0
    acc_bias_mg: float = 10.0
    mag_noise_ut: float = 0.3
    mag_hard_iron_ut: float = 2.0
    mag_soft_iron: float = 0.02
    disturbance_ut: float = 60.0
    gnss_sigma_h_m: float = 2.5
    gnss_sigma_v_m: float = 4.0
    gnss_tau_s: float = 30.0
    gnss_speed_sigma: float = 0.15
    phone_heading_sigma_deg: float = 3.0
    phone_heading_tau_s: float = 20.0
    phone_tilt_sigma_deg: float = 0.3
    jitter: float = 0.2
    drop: float = 0.005


def callback_clock(
    t0: float, t1: float, rate_hz: float, e: SensorErrors, rng: np.random.Generator
) -> np.ndarray:
    """Increasing sample times at about rate_hz with jitter and dropped callbacks."""
    n = int((t1 - t0) * rate_hz)
    t = t0 + (np.arange(n) + rng.uniform(-e.jitter, e.jitter, n)) / rate_hz
    t = np.sort(t[rng.random(n) >= e.drop])
    return t[np.concatenate([[True], np.diff(t) > 1e-6])]


def gauss_markov(
    t: np.ndarray, sigma: float, tau: float, rng: np.random.Generator, dims: int = 1
) -> np.ndarray:
    """First-order Gauss-Markov process (stationary std sigma, correlation time tau s) at times t."""
    out = np.empty((len(t), dims))
    out[0] = rng.normal(0.0, sigma, dims)
    for i in range(1, len(t)):
        a = np.exp(-(t[i] - t[i - 1]) / tau)
        out[i] = a * out[i - 1] + rng.normal(0.0, sigma * np.sqrt(1 - a * a), dims)
    return out


def gyroscope(
    t: np.ndarray, rates: np.ndarray, e: SensorErrors, rng: np.random.Generator
) -> np.ndarray:
    """rad/s: body rate + constant bias + bias random walk + white noise (per-sample std from the
    noise density and the local sample interval)."""
    dt = np.diff(t, prepend=t[0] - np.median(np.diff(t)))
    bias = rng.normal(0.0, e.gyro_bias_dps * DEG, 3)
    walk = np.cumsum(
        rng.normal(0.0, 1.0, (len(t), 3)) * (e.gyro_bias_walk_dps_rts * DEG) * np.sqrt(dt)[:, None],
        axis=0,
    )
    noise = (
        rng.normal(0.0, 1.0, (len(t), 3))
        * (e.gyro_noise_dps_rthz * DEG)
        / np.sqrt(dt)[:, None]
        * np.sqrt(0.5)
    )
    return rates + bias + walk + noise


def accelerometer(
    t: np.ndarray, force: np.ndarray, e: SensorErrors, rng: np.random.Generator
) -> np.ndarray:
    """m/s^2: specific force + constant bias + white noise."""
    dt = np.median(np.diff(t))
    bias = rng.normal(0.0, e.acc_bias_mg * 1e-3 * G, 3)
    noise = rng.normal(0.0, e.acc_noise_ug_rthz * 1e-6 * G / np.sqrt(2 * dt), (len(t), 3))
    return force + bias + noise


def magnetometer(
    q_device: np.ndarray,
    field_enu: np.ndarray,
    disturbance_enu: np.ndarray,
    e: SensorErrors,
    rng: np.random.Generator,
) -> np.ndarray:
    """uT in the device frame: (WMM field + local disturbance) seen by the device, through soft-
    and hard-iron errors, plus noise. disturbance_enu: (N, 3) extra field at each sample."""
    body = rotations.rotate(rotations.conjugate(q_device), field_enu[None, :] + disturbance_enu)
    soft = np.eye(3) + rng.normal(0.0, e.mag_soft_iron, (3, 3))
    hard = rng.normal(0.0, e.mag_hard_iron_ut, 3)
    return body @ soft.T + hard + rng.normal(0.0, e.mag_noise_ut, body.shape)


def phone_orientation(
    t: np.ndarray, q_true: np.ndarray, e: SensorErrors, rng: np.random.Generator
) -> np.ndarray:
    """The phone's own fused attitude: truth with a wandering heading error and tilt noise."""
    heading = gauss_markov(t, e.phone_heading_sigma_deg, e.phone_heading_tau_s, rng)[:, 0]
    tilt = rng.normal(0.0, e.phone_tilt_sigma_deg, (len(t), 2))
    err = rotations.from_scipy(
        rotations.to_scipy([1.0, 0, 0, 0]).from_rotvec(np.column_stack([tilt, heading]) * DEG)
    )
    return rotations.canonical(rotations.multiply(err, q_true))


@dataclass(frozen=True)
class Multipath:
    """Bursts of multipath (module docstring): every_s mean seconds between burst starts,
    length_s and size_m (min, max) of each (uniform), ramp_s to come in and go (s),
    v_ratio: the vertical pull against the horizontal one."""

    every_s: float = 20.0
    length_s: tuple[float, float] = (3.0, 8.0)
    size_m: tuple[float, float] = (3.0, 8.0)
    ramp_s: float = 1.5
    v_ratio: float = 1.5


def multipath(
    t: np.ndarray, accuracy_m: np.ndarray, rng: np.random.Generator, m: Multipath = Multipath()
) -> tuple[np.ndarray, np.ndarray]:
    """(the fixes' extra error (N, 3) ENU m, their stated horizontal accuracy (N,) m) at fix
    times t (N,) s, from the clean stated accuracy (N,) m: bursts starting at Poisson times
    (at least one in the span), each pulling the fix in one direction by its size under a
    trapezoid envelope, and the stated accuracy grown by half the pull in quadrature."""
    t = np.asarray(t, np.float64)
    span = t[-1] - t[0]
    starts = [t[0] + rng.uniform(0.0, max(span - m.length_s[1], 0.0))]
    at = t[0] + rng.exponential(m.every_s)
    while at < t[-1]:
        starts.append(at)
        at += rng.exponential(m.every_s)
    out = np.zeros((len(t), 3))
    pull = np.zeros(len(t))
    for start in starts:
        length = rng.uniform(*m.length_s)
        size = rng.uniform(*m.size_m)
        heading = rng.uniform(0.0, 2 * np.pi)
        up = rng.choice([-1.0, 1.0]) * m.v_ratio
        env = np.clip(np.minimum(t - start, start + length - t) / m.ramp_s, 0.0, 1.0)
        direction = np.array([np.sin(heading), np.cos(heading), up])
        out += (size * env)[:, None] * direction
        pull = np.maximum(pull, size * env)
    return out, np.hypot(np.asarray(accuracy_m, np.float64), 0.5 * pull)
