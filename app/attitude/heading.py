"""Heading policy: where an attitude's rotation about Up comes from when the filter alone cannot
say. Three rules, each a pure function of arrays:

- **compass anchor** (`anchor_heading`): an IMU (6D) track's arbitrary heading fixed once by the
  magnetometer's mean direction over the clip, then turned to true north by the declination;
- **course alignment** (`course_heading_turn`, `align_to_course`): the one constant turn that best
  aligns the camera's forward direction with the GNSS direction of travel while it moves;
- **course attitude** (`course_attitude`): a drone clip with no camera attitude at all: heading
  along the direction of travel, pitch a user setting;

and the magnetometer plausibility check against the World Magnetic Model (`magnetometer_plausible`).
Quaternions are [w, x, y, z], device (or camera) -> ENU; angles in degrees unless named _rad;
velocities (N, 3) m/s ENU.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.core.constants import DRONE_DEFAULT_PITCH_DEG
from app.core.messages import Messages
from app.geodesy import rotations
from app.io.streams import OrientationStream

FloatArray = npt.NDArray[np.float64]

COURSE_MIN_SPEED_MPS = 0.7  # slower, the direction of travel is too noisy to give a heading
COURSE_SMOOTHING_S = 5.0  # velocities are averaged over this window before they give a course
COURSE_HOLD_SPEED_MPS = 1.5  # a course attitude holds its last heading below this speed: GNSS noise
# on a hovering drone or a standing walker makes apparent speeds of ~1 m/s in random directions
MAG_PLAUSIBLE = (0.5, 1.5)  # magnetometer strength / World Magnetic Model strength accepted


@dataclass(frozen=True)
class HeadingPolicy:
    """Where a session's heading comes from. from_course: IMU filters (and a camera's own
    relative attitude) are turned to the GNSS course; course_pitch_deg: the session offers the
    `course` source at this pitch (nothing measures its attitude); prefer: the source shown first;
    note: what the viewer and the CLI say about it ("" when the magnetometer gives heading)."""

    from_course: bool = False
    course_pitch_deg: float | None = None
    prefer: str | None = None
    note: str = ""


def heading_policy(
    has_imu: bool,
    has_mag: bool,
    recorded: Collection[str],
    pitch_deg: float = DRONE_DEFAULT_PITCH_DEG,
    aircraft_yaw: bool = False,
) -> HeadingPolicy:
    """The one rule for every kind of session (phone, action camera, drone, manifest or clip):
    - no IMU and no recorded attitude (a drone subtitle without gimbal angles): the `course`
      source, heading from the aircraft's yaw where the subtitle has it, else from the track;
    - an IMU without a (plausible) magnetometer: IMU filters aligned to the GNSS course; a
      phone's own recorded orientation, when there is one, is shown first;
    - a magnetometer: heading from it (IMU forms anchored to its mean; nothing to say)."""
    measured = set(recorded) - {"truth"}
    if not has_imu and not measured:
        origin = "the aircraft's yaw" if aircraft_yaw else "the track"
        return HeadingPolicy(
            False,
            pitch_deg,
            "course",
            f"no camera attitude in the telemetry: heading from {origin}, pitch {pitch_deg:g} deg assumed",
        )
    if has_imu and not has_mag:
        if "phone" in measured:
            return HeadingPolicy(
                True,
                None,
                "phone",
                "heading from the GNSS course for the IMU filters (no magnetometer); the phone's own orientation is shown first",
            )
        return HeadingPolicy(True, None, None, "heading from the GNSS course (no magnetometer)")
    return HeadingPolicy()


def anchor_heading(q: npt.ArrayLike, mag: npt.ArrayLike, declination_deg: float) -> FloatArray:
    """An IMU track's arbitrary heading fixed once: the constant turn about Up that makes the
    magnetometer (N, 3, device frame, resampled to q's times) point to magnetic north on average
    (circular mean over the clip), then to true north (declination east positive). The track's
    dynamics stay those of the IMU filter; transient magnetic disturbances cannot steer it."""
    h = rotations.rotate(q, mag)
    field_heading = rotations.circular_mean(
        np.arctan2(h[:, 0], h[:, 1])
    )  # the field's angle east of north
    turn = rotations.heading_turn(declination_deg - np.degrees(field_heading))
    return rotations.canonical(rotations.multiply(turn, q))


def course_heading_turn(
    t_fix: FloatArray, vel_enu: FloatArray, t: FloatArray, q_camera: FloatArray
) -> FloatArray | None:
    """The one constant turn about Up (a quaternion) that best aligns the camera's optical axis
    (q_camera: (N, 4) camera -> ENU at times t, s) with the direction of travel (velocities (M, 3)
    at fix times t_fix) while the camera moves faster than COURSE_MIN_SPEED_MPS; None when it
    never does (fewer than three moving fixes)."""
    speed = np.hypot(vel_enu[:, 0], vel_enu[:, 1])
    moving = (speed > COURSE_MIN_SPEED_MPS) & (t_fix >= t[0]) & (t_fix <= t[-1])
    if moving.sum() < 3:
        return None
    course = np.arctan2(vel_enu[moving, 0], vel_enu[moving, 1])
    heading = np.radians(
        rotations.hpr_from_camera_quat(rotations.slerp(t, q_camera, t_fix[moving]))[:, 0]
    )
    return rotations.heading_turn(np.degrees(rotations.circular_mean(course - heading)))


def align_to_course(
    t_fix: FloatArray,
    vel_enu: FloatArray,
    t: FloatArray,
    q_device: FloatArray,
    mount: FloatArray,
    messages: Messages,
) -> FloatArray:
    """q_device (N, 4) turned about Up so that the camera (device -> camera quaternion `mount`)
    looks along the course; unchanged, with one warning, when the camera never moves fast enough."""
    turn = course_heading_turn(t_fix, vel_enu, t, rotations.multiply(q_device, mount))
    if turn is None:
        messages.add_once(
            "course-too-slow",
            f"the camera never moves faster than {COURSE_MIN_SPEED_MPS} m/s: heading cannot come from the course and stays arbitrary",
        )
        return q_device
    return rotations.canonical(rotations.multiply(turn, q_device))


def smoothed_velocity(
    t: FloatArray, vel_enu: FloatArray, window_s: float = COURSE_SMOOTHING_S
) -> FloatArray:
    """(N, 3) velocities averaged over the fixes within +-window_s/2 of each (GNSS noise on
    fix-to-fix velocities shrinks by the square root of the fixes averaged)."""
    t = np.asarray(t, np.float64)
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(vel_enu, axis=0)])
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def course_headings(t_fix: FloatArray, vel_enu: FloatArray) -> FloatArray:
    """Direction of travel (deg from north, [0, 360)) at each fix from velocities smoothed over
    COURSE_SMOOTHING_S; held through stops and hovering (smoothed speed below
    COURSE_HOLD_SPEED_MPS), the first moving heading before the first move."""
    vel_enu = smoothed_velocity(t_fix, np.asarray(vel_enu, np.float64))
    speed = np.hypot(vel_enu[:, 0], vel_enu[:, 1])
    heading = np.degrees(np.arctan2(vel_enu[:, 0], vel_enu[:, 1])) % 360.0
    moving = speed > COURSE_HOLD_SPEED_MPS
    if not moving.any():
        return np.zeros(len(heading))
    idx = np.maximum.accumulate(np.where(moving, np.arange(len(heading)), -1))
    idx[idx < 0] = int(np.flatnonzero(moving)[0])
    return heading[idx]


def course_attitude(
    t_fix: FloatArray,
    vel_enu: FloatArray,
    pitch_deg: float,
    source: str = "",
    yaw: tuple[FloatArray, FloatArray] | None = None,
) -> OrientationStream:
    """The `course` attitude source: camera -> ENU quaternions, the given pitch (deg above the
    horizon, a setting), no roll, and a heading from the aircraft's own yaw where the telemetry
    has it (yaw: (t s, deg clockwise from north)), else along the direction of travel (held
    while the platform moves slower than COURSE_HOLD_SPEED_MPS)."""
    if yaw is not None:
        t, heading = np.asarray(yaw[0], np.float64), np.asarray(yaw[1], np.float64)
        note = f"heading from the aircraft's yaw, pitch {pitch_deg:g} deg (a setting)"
    else:
        t, heading = np.asarray(t_fix, np.float64), course_headings(t_fix, vel_enu)
        note = f"heading from the direction of travel, pitch {pitch_deg:g} deg (a setting)"
    q = rotations.camera_quat_from_hpr(
        heading, np.full(len(heading), pitch_deg), np.zeros(len(heading))
    )
    return OrientationStream(t, q, source, note)


def magnetometer_plausible(field_ut: npt.ArrayLike, expected_ut: float) -> tuple[bool, float]:
    """(accepted, measured median strength uT): a magnetometer (N, 3) uT is used only when its
    field strength lies within MAG_PLAUSIBLE of the World Magnetic Model's at the place."""
    measured = float(np.median(np.linalg.norm(np.asarray(field_ut, np.float64), axis=1)))
    return MAG_PLAUSIBLE[0] <= measured / expected_ut <= MAG_PLAUSIBLE[1], measured
