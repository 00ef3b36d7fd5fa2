"""Automatic video <-> sensor time offset (`geofuse sync`): the camera's rotation rate seen in the
video against the gyroscope's (or, without one, a recorded attitude's, or a drone's course).

1. Video: sparse optical flow (OpenCV's pyramidal Lucas-Kanade on corners) between consecutive
   frames of a reduced grey copy; each pair's feature bearings (through the session's lens or
   pinhole) give the frame-to-frame rotation by a least-squares fit (Kabsch) with outlier
   rejection; rotation / time step = the rate (rad/s, camera frame) at the pair's mid time.
2. Reference: the gyroscope's rates turned from the device frame into the camera frame by the
   mount; else a recorded attitude (a DJI gimbal's, a camera's, a phone's own) differentiated;
   else, for a drone whose subtitle has no gimbal angles, the turn rate of its heading (its
   recorded yaw, or its direction of travel from the GNSS track) about the world's up axis, which
   the video's rates are projected on: the offset found is then the lag of the GNSS track (or
   the yaw) behind the video. A course that hardly turns is refused with the reason.
3. Coarse: the lag that maximises the cross-correlation of the two rate magnitudes over the
   whole clip (+-MAX_LAG_S); fine: the lag, in 1 ms steps within +-FINE_RANGE_S of it and refined
   by a parabola, that best fits the rate components on the windows that say most about time:
   those where the reference's rates change fastest (a time error dt moves a rate w by
   dt * dw/dt; the steady middle of a turn says little). The result is the offset to add to the
   video's times (seconds; video.time_offset_s).
4. Drift, on long clips: each strong window's own lag, regressed on time; kept when it moves the
   clip's ends by DRIFT_MIN_EFFECT_S or more.

Times: media seconds (the video's presentation times) and session seconds.
"""

from __future__ import annotations

from collections.abc import Callable

from app.sync.fit import SyncResult, estimate_offset
from app.sync.flow import frame_rotation, video_rates
from app.sync.rates import (
    RateCurve,
    attitude_rates,
    bearings_of,
    course_rates,
    gyro_rates,
    rate_reference,
    timed_by,
)
from app.sync.settings import (
    read_settings,
    settings_path,
    settings_text,
    synced_drift,
    synced_offset,
)

__all__ = [
    "RateCurve",
    "SyncResult",
    "attitude_rates",
    "bearings_of",
    "course_rates",
    "estimate_offset",
    "frame_rotation",
    "gyro_rates",
    "rate_reference",
    "read_settings",
    "settings_path",
    "settings_text",
    "sync_session",
    "synced_drift",
    "synced_offset",
    "timed_by",
    "video_rates",
]


def sync_session(session, progress: Callable[[float], None] | None = None) -> SyncResult:
    """The offset to add to the session's video times so that they agree with its gyroscope (or,
    without one, with a recorded attitude's rates)."""
    gyro = gyro_rates(session)
    rates = video_rates(session.video, bearings_of(session), session.rotation_cw, progress)
    clip_start = float(session.frame_times[0] - session.video.pts_s[0])
    return estimate_offset(rates, gyro, clip_start)
