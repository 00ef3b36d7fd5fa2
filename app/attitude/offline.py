"""Offline attitude: the whole clip is known before playback, so the estimate at time t may use
samples after t. Two ideas, each simple:

1. Gyroscope bias from the clip itself: the median rate over the samples where the device is
   still (low rate, accelerometer norm steady), subtracted before filtering.
2. Forward and backward passes of the gradient-descent filter fused sample by sample. A causal
   filter lags: its error correlates with the recent motion; the backward pass (time reversed,
   rates negated) lags the other way, so their average cancels much of it. Near each end one pass
   has not converged; the weights ramp from the converged pass to 50/50 over `ramp_s`.
"""

from __future__ import annotations

import numpy as np

from app.attitude import kernels
from app.attitude.initial import init_samples, initial_orientation
from app.geodesy import rotations

# "Still" is the causal filters' "at rest" (app.attitude.kernels), one set of thresholds.
STILL_RATE = kernels.REST_RATE  # rad/s
STILL_ACC = kernels.REST_ACC  # fraction of g: accelerometer norm steadiness
MIN_STILL_S = kernels.REST_MIN_S  # seconds of stillness needed to trust the bias estimate


def gyro_bias(t: np.ndarray, gyr: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """Median rate (rad/s) over still samples, or zeros when the clip has under MIN_STILL_S of them."""
    rate = np.linalg.norm(gyr, axis=1)
    an = np.linalg.norm(acc, axis=1)
    still = (rate < STILL_RATE) & (np.abs(an - np.median(an)) < STILL_ACC * np.median(an))
    dt = np.diff(t, prepend=t[0])
    if dt[still].sum() < MIN_STILL_S:
        return np.zeros(3)
    return np.median(gyr[still], axis=0)


def _weights(t: np.ndarray, ramp_s: float) -> np.ndarray:
    """Weight of the forward pass: 0 at the start (backward converged there), 0.5 in the middle,
    1 at the end (forward converged there)."""
    start = np.clip((t - t[0]) / ramp_s, 0.0, 1.0) * 0.5
    end = np.clip((t[-1] - t) / ramp_s, 0.0, 1.0) * 0.5
    return np.where(t - t[0] < t[-1] - t, start, 1.0 - end)


def blend(qa: np.ndarray, qb: np.ndarray, wa: np.ndarray) -> np.ndarray:
    """Per-sample weighted average of two quaternion tracks (normalised linear blend on the same
    hemisphere; exact to first order for the small differences between two estimates)."""
    qb = np.where(np.sum(qa * qb, axis=1, keepdims=True) < 0, -qb, qb)
    q = wa[:, None] * qa + (1.0 - wa[:, None]) * qb
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def forward_backward(
    t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, use_mag: bool, g
) -> np.ndarray:
    """Bias-corrected forward and backward Madgwick passes, fused. Returns (N, 4)."""
    if not g.bias_tau:
        gyr = gyr - gyro_bias(t, gyr, acc)
    head = init_samples(t, g.init_s, gyr)
    q0 = initial_orientation(acc[head], mag[head] if use_mag else None)
    fwd = kernels.madgwick(
        t, gyr, acc, mag, use_mag, q0, g.beta, g.beta_start, g.ramp_s, g.acc_reject, g.bias_tau
    )
    # Backward: reversed time axis; a device rotating at w forward rotates at -w backward.
    tr = (t[-1] - t)[::-1].copy()
    tail = init_samples(tr, g.init_s, gyr[::-1])
    acc_r, mag_r = acc[::-1].copy(), mag[::-1].copy()
    qb0 = initial_orientation(acc_r[tail], mag_r[tail] if use_mag else None)
    if not use_mag:
        # Without a magnetometer the backward pass's heading is arbitrary: start it from the
        # forward pass's final attitude so both share one heading reference.
        qb0 = fwd[-1].copy()
    # The kernel holds gyr[i-1] over [t[i-1], t[i]]; reversed index j-1 must then carry the
    # forward rate of sample N-2-(j-1), hence the shift by one.
    gyr_r = -np.roll(gyr[::-1], -1, axis=0)
    bwd = kernels.madgwick(
        tr,
        gyr_r.copy(),
        acc_r,
        mag_r,
        use_mag,
        qb0,
        g.beta,
        g.beta_start,
        g.ramp_s,
        g.acc_reject,
        g.bias_tau,
    )[::-1]
    return rotations.canonical(blend(fwd, bwd, _weights(t, g.ramp_s)))
