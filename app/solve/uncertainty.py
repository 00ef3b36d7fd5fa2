"""How far a pose source's poses may be off, one standard deviation: what `locate` and the
Measure panel turn into metres on a surface, and what the scene memory's quality weighs a frame
by (app.export.memory).

Per source: the truth none; `registered` its used keyframes' reprojection error (as an attitude
error) and REGISTERED_SIGMA_M of position at a keyframe, growing back toward the prior's away
from the keyframes as the fused correction decays (app.register.fuse: exp(-dt / hold_s)); the
others the GNSS fixes' horizontal accuracy where the receiver gave it (else GNSS_SIGMA_M) and
FILTER_SIGMA_DEG, the attitude error the method is held to (docs/ACCURACY.md).
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


def pose_sigmas(session: Session, track: CameraTrack) -> PoseSigmas:
    """The pose's errors under the track's source (see the module docstring), at its keyframes
    for `registered`."""
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
    with the time (s) from the nearest used keyframe, as the correction decays (hold_s)."""
    frames = np.atleast_1d(np.asarray(frames, np.int64))
    at = pose_sigmas(session, track)
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
    return (
        prior.position_m + (at.position_m - prior.position_m) * held,
        prior.attitude_deg + (at.attitude_deg - prior.attitude_deg) * held,
    )
