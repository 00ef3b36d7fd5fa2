"""How far a pose source's poses may be off, one standard deviation: what `locate` and the
Measure panel turn into metres on a surface, and what the scene memory's quality weighs a frame
by (app.export.memory).

Per source: the truth none; `registered` its used keyframes' reprojection error (as an attitude
error) and REGISTERED_SIGMA_M of position at a keyframe, growing back toward the prior's away
from the keyframes as the fused correction decays (app.register.fuse: exp(-dt / hold_s)); where
the registration carried the track by the IMU (app.register.inertial, issue 52) its position's
standard deviation at each frame instead, which grows with the time from the last keyframe or
fix it stood on (an outage, a lie, a stretch the scene did not register) and shrinks at the
next (and grows where the fused track stands off it); the others the GNSS fixes' horizontal
accuracy where the receiver gave it (else GNSS_SIGMA_M) and FILTER_SIGMA_DEG, the attitude error
the method is held to (docs/ACCURACY.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.core.constants import TRUTH
from app.register.fuse import FuseSettings
from app.session.camera_track import CameraTrack
from app.session.model import REGISTERED, Session

GNSS_SIGMA_M = 3.0  # a phone's or drone's GNSS position error without its own accuracy (2-4 m)
FILTER_SIGMA_DEG = 2.0  # the attitude error the sensor filters are held to (the paper's RMS)
REGISTERED_SIGMA_M = 0.3  # the registered position's error on the sample (docs/ACCURACY.md)


@dataclass(frozen=True)
class PoseSigmas:
    """The pose's errors one standard deviation: position_m (ENU, each axis), attitude_deg."""

    position_m: float
    attitude_deg: float
    why: str


def _prior_sigmas(session: Session) -> PoseSigmas:
    acc = session.gnss.h_acc
    if acc is not None and np.isfinite(acc).any():
        pos, why = float(np.nanmedian(acc)), "the GNSS fixes' own accuracy"
    else:
        pos, why = GNSS_SIGMA_M, f"a GNSS error of {GNSS_SIGMA_M:g} m"
    return PoseSigmas(pos, FILTER_SIGMA_DEG, f"{why}, {FILTER_SIGMA_DEG:g} deg of attitude")


def pose_sigmas(session: Session, track: CameraTrack, frame: int | None = None) -> PoseSigmas:
    """The pose's errors under the track's source (see the module docstring): at video frame
    `frame` where given (frame_sigmas: `registered` varies along the clip), else at its
    keyframes for `registered`."""
    at = _track_sigmas(session, track)
    if frame is None or track.source != REGISTERED:
        return at
    pos, att = frame_sigmas(session, track, [frame])
    return PoseSigmas(float(pos[0]), float(att[0]), f"{at.why}, at frame {frame}")


def _track_sigmas(session: Session, track: CameraTrack) -> PoseSigmas:
    if track.source == TRUTH:
        return PoseSigmas(0.0, 0.0, "the true pose")
    if track.source == REGISTERED and track.registration is not None:
        errors = [k.error_px for k in track.registration.keyframes if k.used]
        fx = track.intrinsics.fx
        deg = math.degrees(float(np.median(errors)) / fx) if errors else FILTER_SIGMA_DEG
        return PoseSigmas(REGISTERED_SIGMA_M, deg, "registered: the keyframes' reprojection error")
    return _prior_sigmas(session)


def frame_sigmas(
    session: Session, track: CameraTrack, frames: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """(position m, attitude deg) one standard deviation of the track's pose at each video frame
    (N,): pose_sigmas', and for `registered` growing from the keyframes' toward the prior's
    with the time (s) from the nearest used keyframe, as the correction decays (hold_s); its
    position, where the registration carried the track by the IMU, that track's standard
    deviation at the frame (the root mean square of its east, north and up ones), grown by how
    far the fused track stands from it there (a multipath burst the keyframes' corrections
    follow late: each axis's share of the distance in quadrature)."""
    frames = np.atleast_1d(np.asarray(frames, np.int64))
    at = _track_sigmas(session, track)
    pos = np.full(len(frames), at.position_m)
    att = np.full(len(frames), at.attitude_deg)
    reg = track.registration
    used = [] if reg is None or track.source != REGISTERED else [k for k in reg.keyframes if k.used]
    if not used:
        return pos, att
    prior = _prior_sigmas(session)
    t = track.clock.session_time(np.asarray(session.video.pts_s, np.float64)[frames])
    t_used = np.sort([k.time_s for k in used])
    gap = np.min(np.abs(t[:, None] - t_used[None, :]), axis=1)
    held = np.exp(-gap / FuseSettings().hold_s)  # how much of the correction still holds
    pos = prior.position_m + (at.position_m - prior.position_m) * held
    if reg.carried is not None:  # the carried track's, and how far the fused one is from it
        p, sigma = reg.carried.at(t)
        off = np.sum((track.poses.at(t)[0] - p) ** 2, axis=1)
        pos = np.sqrt(np.mean(sigma**2, axis=1) + off / 3.0)
    return pos, prior.attitude_deg + (at.attitude_deg - prior.attitude_deg) * held
