"""The reference's rotation rates for sync (app.sync): the gyroscope's in the camera frame, a
recorded attitude's differentiated, or a drone's course turn about the world's up axis; which of
them a session offers, and the bearings of the video's pixels through its lens.

Rates: rad/s in the camera frame (OpenGL axes); times: session seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from app.attitude.heading import COURSE_HOLD_SPEED_MPS, smoothed_velocity
from app.core.constants import COURSE
from app.core.errors import GeofuseError
from app.geodesy import rotations


@dataclass(frozen=True)
class RateCurve:
    """Rotation rates: t (N,) seconds; omega (N, 3) rad/s in the camera frame (OpenGL axes), or,
    with an axis ((3,) unit vector in that frame), omega (N, 1): the rate about that axis only
    (a course knows only how the heading turns)."""

    t: np.ndarray
    omega: np.ndarray
    axis: np.ndarray | None = None

    def along(self, reference: RateCurve) -> RateCurve:
        """This three-axis curve made comparable with `reference`: its rate about the
        reference's axis where the reference has one, else itself."""
        if reference.axis is None:
            return self
        return RateCurve(self.t, (self.omega @ reference.axis)[:, None], reference.axis)


ATTITUDE_SMOOTH_S = 0.15  # moving average of rates differentiated from recorded attitudes
RECORDED_FOR_RATES = (
    "telemetry",
    "camera",
    "phone",
)  # recorded attitudes, best first, when no gyroscope
MIN_COURSE_TURN_DEG_S = 3.0  # a course turning slower than this carries no usable timing
MIN_COURSE_TURNING_S = 4.0  # ... and it must turn that fast for this long over the clip
SYNC_COURSE_SMOOTH_S = 1.0  # s: velocities are averaged, and the course's turn taken, over this


def attitude_rates(t: np.ndarray, q: np.ndarray) -> RateCurve:
    """Body rates (rad/s, the device frame) between successive attitudes q (N, 4) device -> world
    at times t (N,) s, at the midpoints: the rotation vector of q_i* q_(i+1) over the interval.
    (`omega` is then in the device frame; gyro_rates turns it into the camera frame.)"""
    t = np.asarray(t, np.float64)
    dt = np.diff(t)
    keep = dt > 1e-6
    step = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])[keep]
    rates = rotations.to_scipy(step).as_rotvec() / dt[keep, None]
    mid = (t[:-1] + t[1:])[keep] / 2.0
    # attitudes carry sample-to-sample noise that differentiation amplifies: a centred moving
    # average over ATTITUDE_SMOOTH_S (symmetric, so it moves no time) keeps the turns
    n = max(1, int(round(ATTITUDE_SMOOTH_S / max(float(np.median(dt[keep])), 1e-6))) | 1)
    if n > 1 and len(rates) > n:
        rates = uniform_filter1d(rates, n, axis=0, mode="nearest")
    return RateCurve(mid, rates)


def rate_reference(session) -> str | None:
    """What times the video: 'gyroscope', a recorded attitude's name, 'course' (a drone without
    gimbal angles: the heading it flies, from its yaw or its GNSS track), or None."""
    if session.gyr is not None:
        return "gyroscope"
    recorded = next((n for n in RECORDED_FOR_RATES if n in session.recorded), None)
    return recorded or (COURSE if session.course_pitch_deg is not None else None)


RATE_SOURCE_WORDS = {
    "gyroscope": "the gyroscope",
    "telemetry": "the recorded gimbal attitude",
    "camera": "the camera's recorded attitude",
    "phone": "the phone's recorded attitude",
    COURSE: "the aircraft's course (the GNSS track's lag behind the video)",
}


def timed_by(session) -> str:
    """What the session's video is timed against, in words, for messages."""
    name = rate_reference(session)
    return RATE_SOURCE_WORDS.get(name, str(name))


def gyro_rates(session) -> RateCurve:
    """The session's rotation rates in the camera frame of the displayed video: its gyroscope's,
    or, without one, those of a recorded attitude (a DJI gimbal's, a camera's or a phone's own),
    differentiated, or those of the course attitude (a drone whose camera looks where it flies:
    the offset found is then the lag of its GNSS track, or its yaw, behind the video); raises
    when it has none, or when the course turns too little to time anything by."""
    mount = rotations.conjugate(session.camera_mount())
    name = rate_reference(session)
    if name == "gyroscope":
        t, body = session.gyr.t, session.gyr.values
    elif name is None:
        raise GeofuseError(
            f"{session.path}: no gyroscope, no recorded attitude and no course: the offset cannot be found from rotation (set video.time_offset_s by hand)"
        )
    elif name == COURSE:
        return course_rates(session)
    else:
        stream = session.recorded[name]
        curve = attitude_rates(stream.t, stream.q)
        t, body = curve.t, curve.omega
    return RateCurve(t, rotations.rotate(np.tile(mount, (len(t), 1)), body))


def course_rates(session) -> RateCurve:
    """How fast a drone's heading turns (rad/s about the world's up axis, seen in the camera frame
    of the displayed video): from the aircraft's recorded yaw where the subtitle has one, else from
    its direction of travel (velocities averaged over SYNC_COURSE_SMOOTH_S; NaN while slower than
    COURSE_HOLD_SPEED_MPS); the turn is taken over SYNC_COURSE_SMOOTH_S too, centred, so that no
    time moves. Refused when it turns too little."""
    if session.aircraft_yaw is not None:
        t, heading = (np.asarray(x, np.float64) for x in session.aircraft_yaw)
        moving = np.ones(len(t), bool)
    else:
        pos = session.positions()
        t = pos.t
        vel = smoothed_velocity(t, pos.vel_enu, SYNC_COURSE_SMOOTH_S)
        heading = np.degrees(np.arctan2(vel[:, 0], vel[:, 1]))
        moving = np.hypot(vel[:, 0], vel[:, 1]) > COURSE_HOLD_SPEED_MPS
    keep = np.concatenate([[True], np.diff(t) > 1e-6])
    t, heading, moving = t[keep], np.unwrap(np.radians(heading[keep])), moving[keep]
    # the turn over SYNC_COURSE_SMOOTH_S centred on each fix (a derivative from neighbouring
    # fixes would amplify the positions' rounding); a heading turning clockwise (seen from
    # above) is a negative turn about the up axis
    half = SYNC_COURSE_SMOOTH_S / 2
    rate = -(np.interp(t + half, t, heading) - np.interp(t - half, t, heading)) / (2 * half)
    rate[~moving | (t - half < t[0]) | (t + half > t[-1])] = np.nan
    _check_course_turns(t, rate, session)
    pitch = float(session.course_pitch_deg)
    q = rotations.camera_quat_from_hpr(
        0.0, pitch, 0.0
    )  # the heading does not change where "up" is seen
    up = rotations.rotate(
        rotations.conjugate(q), np.array([0.0, 0.0, 1.0])
    )  # world up in the camera frame
    up = rotations.rotate(rotations.conjugate(session.camera_mount()), up)
    return RateCurve(t, rate[:, None], up / np.linalg.norm(up))


def _check_course_turns(t: np.ndarray, rate: np.ndarray, session) -> None:
    """Refuse a course that turns faster than MIN_COURSE_TURN_DEG_S for less than
    MIN_COURSE_TURNING_S in all: a straight flight or a hover carries no time."""
    deg = np.degrees(np.abs(np.nan_to_num(rate)))
    dt = np.diff(t, append=t[-1])
    turning = float(np.sum(dt[deg >= MIN_COURSE_TURN_DEG_S]))
    if turning < MIN_COURSE_TURNING_S:
        source = "yaw" if session.aircraft_yaw is not None else "course over the ground"
        raise GeofuseError(
            f"{session.path}: the aircraft's {source} turns faster than {MIN_COURSE_TURN_DEG_S:g} deg/s for only {turning:.1f} s "
            f"(at most {float(np.max(deg, initial=0.0)):.1f} deg/s; {MIN_COURSE_TURNING_S:g} s needed): a straight flight or a hover "
            "does not show when its GNSS track lags the video, so the offset cannot be estimated (set video.time_offset_s by hand)"
        )


def unit_bearings(ab: np.ndarray) -> np.ndarray:
    """Normalised image coordinates (N, 2) -> unit bearings (N, 3), OpenCV camera frame."""
    b = np.column_stack([ab, np.ones(len(ab))])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def pinhole_bearings(intr) -> Callable[[np.ndarray], np.ndarray]:
    """Display pixels -> unit bearings (OpenCV camera frame) through a pinhole (Intrinsics)."""
    return lambda uv: unit_bearings(
        np.column_stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy])
    )


def bearings_of(session) -> Callable[[np.ndarray], np.ndarray]:
    """Display pixels -> unit bearings (OpenCV camera frame) through the session's lens or pinhole."""
    lens = session.lens
    if lens is None:
        return pinhole_bearings(session.intrinsics)
    return lambda uv: unit_bearings(lens.undistort(uv))
