"""Registered keyframes fused with the prior track (GNSS positions, filtered attitude), as pure
numpy: registration does not replace the sensors, it measures their slowly varying errors.

At each registered keyframe k the correction is the registered pose against the prior's at the
same session time: a position offset dp_k (ENU m: the GNSS bias, correlated over tens of seconds)
and a world-side rotation dr_k (rotation vector, rad: R_registered = exp(dr_k) R_prior; the
filter's heading and tilt bias, and any boresight between device and camera seen from the
world). A keyframe that disagrees with its neighbours' median by more than the settings allow is
not used (named, with the figures). The used corrections are smoothed over time (Gaussian,
sigma = smooth_s: by default less than the keyframes' spacing, as the prior's error moves within
a second: docs/ACCURACY.md), interpolated between keyframes by a shape-preserving cubic (no jump
and no kink at a keyframe), and held
beyond the first and last, decaying toward the prior with time constant hold_s, so a stretch
where nothing registers falls back toward the unregistered source.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicHermiteSpline, PchipInterpolator

from app.camera.trajectory import PoseTrack, PositionTrack
from app.geodesy import rotations

FloatArray = npt.NDArray[np.float64]
POSITION_RATE_HZ = 10.0  # the corrected position track's samples (Hermite-interpolated between)


@dataclass(frozen=True)
class Keyframe:
    """One keyframe's registration. index: video frame; time_s: its session time under the
    prior's clock; used: whether the fused track takes it; reason: why not (empty when used);
    matches, inliers, error_px (RMS reprojection, frame pixels), iterations (renderings made);
    prior_* and position/q: the prior's and the registered pose (ENU m, camera -> ENU)."""

    index: int
    time_s: float
    used: bool
    reason: str
    matches: int
    inliers: int
    error_px: float
    iterations: int
    prior_position: FloatArray
    prior_q: FloatArray
    position: FloatArray | None = None
    q: FloatArray | None = None

    @property
    def registered(self) -> bool:
        """A pose was solved (used or not)."""
        return self.position is not None

    def correction(self) -> tuple[FloatArray, FloatArray]:
        """(dp (3,) ENU m, dr (3,) world-side rotation vector, rad) from the prior to the registered pose."""
        dp = np.asarray(self.position) - np.asarray(self.prior_position)
        dq = rotations.multiply(np.asarray(self.q), rotations.conjugate(np.asarray(self.prior_q)))
        return dp, rotations.to_scipy(dq).as_rotvec()


@dataclass(frozen=True)
class FuseSettings:
    """window_s: neighbours within this many seconds judge a keyframe (path_s: those whose
    positions judge it, `gate`); max_disagree_m /
    max_disagree_deg: a correction farther than this from their median is not used; smooth_s:
    Gaussian sigma (s) over the used corrections (0.1 s: at the default 0.5 s spacing each
    keyframe keeps its own, as the prior's error moves within a second; 1 s smoothed that away
    and left the textured orbit 0.58 m off at the centre line instead of 0.08 m:
    docs/ACCURACY.md); hold_s: beyond the first and last used keyframe the correction decays as
    exp(-dt / hold_s) (the GNSS error's correlation time); delay_*: the time-offset estimate
    (estimate_delay): high-pass sigma (s), the fewest used keyframes, the least RMS of the
    high-passed rates (rad/s), the largest offset believed (s)."""

    window_s: float = 4.0
    path_s: float = 2.0
    max_disagree_m: float = 2.5
    max_disagree_deg: float = 1.5
    smooth_s: float = 0.1
    hold_s: float = 30.0
    delay_sigma_s: float = 1.5
    delay_min_keyframes: int = 10
    delay_min_rate: float = 0.02
    max_delay_s: float = 1.0


def gate(keyframes: list[Keyframe], settings: FuseSettings = FuseSettings()) -> list[Keyframe]:
    """The keyframes, with those that no registered neighbour within window_s confirms marked
    unused and the reason given: one whose correction is farther than max_disagree_m or
    max_disagree_deg from its neighbours' median (from its only neighbour's: then both are set
    aside, as neither can be told right) and, in metres, from the robust line through them
    (four at least: a correction that moves steadily, where the prior drags off the flight or
    stands still while it flies on, a lie no IMU screened out, agrees with its neighbours'
    line, not their median) and whose position lies farther than max_disagree_m off the path
    its neighbours' positions fly (a quadratic through those within path_s, two at least on
    each side, that passes within max_disagree_m / 3 of them, RMS: where the prior itself
    swerves, under a multipath burst or across an outage it runs straight through, the
    corrections swerve with it and the registered positions do not; a false match stands off
    that path), and one with no registered neighbour at all. A lone fit is not trusted: on
    the sample walk against its model without texture, each keyframe started at its true pose,
    the only one the lines accepted ended 6.8 m off and, used alone, moved the whole track
    (docs/ACCURACY.md, "A keyframe alone")."""
    finite = {k.index for k in keyframes if k.used and np.isfinite(k.position).all() and np.isfinite(k.q).all()}  # fmt: skip
    solved = [k for k in keyframes if k.index in finite]
    t = np.array([k.time_s for k in solved])
    corr = [k.correction() for k in solved]
    dp = np.array([c[0] for c in corr])
    dr = np.degrees(np.array([c[1] for c in corr]))
    pos = np.array([k.position for k in solved], np.float64).reshape(-1, 3)
    bad = {k.index: "registered at a non-finite pose" for k in keyframes if k.used and k.index not in finite}  # fmt: skip
    for i, k in enumerate(solved):
        near = np.flatnonzero((np.abs(t - t[i]) <= settings.window_s) & (np.arange(len(t)) != i))
        if len(near) == 0:
            bad[k.index] = (
                f"no other keyframe within {settings.window_s:g} s registered to confirm it"
            )
            continue
        off_m = float(np.linalg.norm(dp[i] - np.median(dp[near], axis=0)))
        if off_m > settings.max_disagree_m and len(near) >= 4:  # or on their steady line
            off_m = min(off_m, float(np.linalg.norm(dp[i] - _on_line(t[near] - t[i], dp[near]))))
        if off_m > settings.max_disagree_m:  # or on the path their positions fly
            off_m = min(
                off_m, _off_path(t - t[i], pos, i, settings.path_s, settings.max_disagree_m)
            )
        off_deg = float(np.linalg.norm(dr[i] - np.median(dr[near], axis=0)))
        if not off_m <= settings.max_disagree_m or not off_deg <= settings.max_disagree_deg:
            whom = "its only neighbour" if len(near) == 1 else f"its {len(near)} neighbours"
            bad[k.index] = f"disagrees with {whom} by {off_m:.2f} m, {off_deg:.2f} deg"
    return [replace(k, used=False, reason=bad[k.index]) if k.index in bad else k for k in keyframes]


@dataclass(frozen=True)
class Correction:
    """The smoothed corrections at the used keyframes' times t (K,) s: dp (K, 3) ENU m, dr (K, 3)
    world-side rotation vectors (rad); evaluated anywhere by calling it."""

    t: FloatArray
    dp: FloatArray
    dr: FloatArray
    hold_s: float = 30.0

    @classmethod
    def from_keyframes(
        cls, keyframes: list[Keyframe], settings: FuseSettings = FuseSettings()
    ) -> Correction:
        used = sorted((k for k in keyframes if k.used), key=lambda k: k.time_s)
        if not used:
            return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), settings.hold_s)
        t = np.array([k.time_s for k in used])
        corr = [k.correction() for k in used]
        dp = np.array([c[0] for c in corr])
        dr = np.array([c[1] for c in corr])
        w = np.exp(-0.5 * ((t[:, None] - t[None, :]) / settings.smooth_s) ** 2)
        w /= w.sum(axis=1, keepdims=True)
        return cls(t, w @ dp, w @ dr, settings.hold_s)

    def __call__(self, tq: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(dp (M, 3) m, dr (M, 3) rad) at session times tq (M,)."""
        tq = np.atleast_1d(np.asarray(tq, np.float64))
        if len(self.t) == 0:
            return np.zeros((len(tq), 3)), np.zeros((len(tq), 3))
        dp, dr = (_between(self.t, x, tq) for x in (self.dp, self.dr))
        outside = np.where(
            tq < self.t[0], self.t[0] - tq, np.where(tq > self.t[-1], tq - self.t[-1], 0.0)
        )
        fade = np.exp(-outside / self.hold_s)[:, None]
        return dp * fade, dr * fade


def _off_path(dt: FloatArray, pos: FloatArray, i: int, path_s: float, within_m: float) -> float:
    """How far (m) keyframe i's position lies from the quadratic in time through the other
    keyframes' positions (pos (K, 3) ENU m at dt (K,) s from it) within path_s either side:
    inf where fewer than two lie on either side, or where the quadratic misses its own points
    by more than within_m / 3 (RMS): a run of false matches among them bends it their way."""
    near = np.flatnonzero((np.abs(dt) <= path_s) & (np.arange(len(dt)) != i))
    before, after = np.unique(dt[near][dt[near] < 0]), np.unique(dt[near][dt[near] > 0])
    if len(before) < 2 or len(after) < 2:
        return float("inf")
    coef = np.polyfit(dt[near], pos[near], 2)
    misses = np.linalg.norm(np.vander(dt[near], 3) @ coef - pos[near], axis=1)
    if np.sqrt(np.mean(misses**2)) > within_m / 3:
        return float("inf")
    return float(np.linalg.norm(pos[i] - coef[-1]))


def _on_line(dt: FloatArray, x: FloatArray) -> FloatArray:
    """The value at dt = 0 of the robust line through x (N, 3) at times dt (N,) s (Theil-Sen:
    each axis's slope the median of the pairs', its intercept the median of the rest); NaN
    where no two times differ."""
    i, j = np.triu_indices(len(dt), 1)
    apart = dt[j] != dt[i]
    if not apart.any():
        return np.full(x.shape[1], np.nan)
    slope = np.median((x[j[apart]] - x[i[apart]]) / (dt[j[apart]] - dt[i[apart]])[:, None], axis=0)
    return np.median(x - dt[:, None] * slope, axis=0)


def _between(t: FloatArray, x: FloatArray, tq: FloatArray) -> FloatArray:
    """x (K, 3) given at increasing times t (K,), at times tq (M,): a shape-preserving cubic
    (PCHIP's rates, never beyond its neighbours' values, continuous in value and rate so the
    track has no kink at a keyframe), its rate zero at the first and last keyframe where the
    held value takes over; held at the first and last value outside t."""
    if len(t) < 2:
        return np.repeat(x[:1], len(tq), axis=0)
    rate = PchipInterpolator(t, x, axis=0).derivative()(t)
    rate[[0, -1]] = 0.0
    return CubicHermiteSpline(t, x, rate, axis=0)(np.clip(tq, t[0], t[-1]))


def world_rates(prior: PoseTrack, t: npt.ArrayLike, h: float = 0.02) -> FloatArray:
    """(N, 3) the prior camera's angular velocity (rad/s) in the world frame at times t (s),
    by a central difference over +-h seconds."""
    t = np.asarray(t, np.float64)
    _, _, qa = prior.at(t - h)
    _, _, qb = prior.at(t + h)
    return rotations.to_scipy(rotations.multiply(qb, rotations.conjugate(qa))).as_rotvec() / (
        2.0 * h
    )


def _high_pass(t: FloatArray, x: FloatArray, sigma_s: float) -> FloatArray:
    w = np.exp(-0.5 * ((t[:, None] - t[None, :]) / sigma_s) ** 2)
    return x - (w / w.sum(axis=1, keepdims=True)) @ x


def estimate_delay(
    keyframes: list[Keyframe], prior: PoseTrack, settings: FuseSettings = FuseSettings()
) -> float | None:
    """How late (s) the pipeline's frame times are against the moments the frames show, from the
    used keyframes: a frame shown delay_s late sees the camera turned back by w * delay_s (w its
    world-frame rate), so the fast part of the rotation corrections regresses on the fast part of
    the prior's rates (both high-passed over delay_sigma_s, which removes the filter's slow bias),
    the rates taken at the middle of the delay (the turn over it is their mean there).
    None where there are too few keyframes or too little rotation to tell, or it exceeds
    max_delay_s."""
    used = [k for k in keyframes if k.used]
    if len(used) < settings.delay_min_keyframes:
        return None
    t = np.array([k.time_s for k in used])
    dr = _high_pass(t, np.array([k.correction()[1] for k in used]), settings.delay_sigma_s)
    delay = 0.0
    for _ in range(3):  # the turn over the delay is the mean rate over it: rates at its middle
        w = _high_pass(t, world_rates(prior, t - delay / 2), settings.delay_sigma_s)
        energy = float(np.sum(w * w))
        if energy < settings.delay_min_rate**2 * len(t):
            return None
        delay = -float(np.sum(dr * w)) / energy
        if abs(delay) > settings.max_delay_s:
            return None
    return delay


def retimed(keyframes: list[Keyframe], prior: PoseTrack, delay_s: float) -> list[Keyframe]:
    """The keyframes with their prior poses taken delay_s earlier (the moment the frame shows)."""
    if not keyframes:
        return keyframes
    enu, _, q = prior.at(np.array([k.time_s for k in keyframes]) - delay_s)
    return [replace(k, prior_position=enu[i], prior_q=q[i]) for i, k in enumerate(keyframes)]


def corrected_pose_track(
    prior: PoseTrack, correction: Correction, delay_s: float = 0.0
) -> PoseTrack:
    """The prior pose track, delay_s later (a frame shown at t gets the prior's pose at
    t - delay_s), with the correction applied: positions resampled at POSITION_RATE_HZ (Hermite
    between samples, as any GNSS track), the device attitude turned world-side at its own
    sample times; the device -> camera mount is kept."""
    t0, t1 = prior.positions.t[0] + delay_s, prior.positions.t[-1] + delay_s
    ts = np.append(np.arange(t0, t1, 1.0 / POSITION_RATE_HZ), t1)
    enu, _, _ = prior.at(ts - delay_s)
    dp, _ = correction(ts)
    geo = prior.frame.enu_to_geodetic(enu + dp)
    positions = PositionTrack.from_fixes(ts, geo[:, 0], geo[:, 1], geo[:, 2])
    t_att = prior.t_att + delay_s
    _, dr = correction(t_att)
    turn = rotations.from_rotvec(dr)
    q_device = rotations.canonical(rotations.multiply(turn, prior.q_device))
    return PoseTrack(prior.frame, positions, t_att, q_device, prior.q_dev_to_cam)
