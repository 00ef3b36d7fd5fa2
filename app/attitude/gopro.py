"""A GoPro's telemetry in the conventions of DESIGN.md: the IMU's axes turned into the device
frame, the camera's own orientation (CORI) levelled, the magnetometer checked.

- The IMU axes are turned into GoPro's camera frame (CORI/GRAV's: X right, Y down, Z out of the
  lens, which GRAV shows: gravity along +Y on an upright camera). That turn is fitted per file as
  the signed axis permutation under which the gyroscope matches the rates of the camera's own
  orientation (CORI); without CORI, the one fitted on the GoPro MAX sample is assumed. Finally
  the camera frame becomes our device frame (x right, y up, z toward the viewer): (x, -y, -z).
  Tested with gravity on a camera held upright: the accelerometer reads +g along device +y.
- MAGN is used only when its field strength is plausible for the place (app.attitude.heading
  .magnetometer_plausible); otherwise heading comes from the GNSS course.
- CORI (camera orientation since the start of capture) becomes the `camera` source: its
  conjugate maps the camera to the capture-start frame; tilt is aligned with gravity here and
  heading by the course later (app.attitude.heading.align_to_course).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.attitude.heading import magnetometer_plausible
from app.geodesy import rotations
from app.geodesy.geomag import field_enu
from app.io.gopro import DEFAULT_ORIN, GoProRaw, orin_map, read_gopro_raw
from app.io.streams import (
    GnssTrack,
    Messages,
    OrientationStream,
    VectorStream,
    checked_vector,
    resample,
)

CV_TO_DEVICE = np.diag([1.0, -1.0, -1.0])  # camera (X right, Y down, Z forward) -> device frame
DEFAULT_IMU_TO_CV = np.array(
    [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]
)  # fitted on the MAX sample
FIT_MAX_RESIDUAL = 0.5  # median rate residual / median rate above which no axis order is accepted
LEVEL_WINDOW_S = 1.0  # seconds of accelerometer averaged for CORI's levelling


@dataclass(frozen=True)
class GoProRecording:
    """A GoPro clip's streams in the device frame (clip seconds)."""

    raw: GoProRaw
    acc: VectorStream
    gyr: VectorStream
    mag: VectorStream | None
    camera: OrientationStream | None

    @property
    def gnss(self) -> GnssTrack | None:
        return self.raw.gnss

    @property
    def hfov_deg(self) -> float:
        return self.raw.hfov_deg

    @property
    def gps_utc_at_zero(self) -> float | None:
        return self.raw.gps_utc_at_zero


def fit_imu_to_camera(
    t_gyr: np.ndarray, gyr: np.ndarray, t_cori: np.ndarray, cori: np.ndarray
) -> tuple[np.ndarray, float]:
    """The signed axis permutation M (proper rotation) with camera rate = M @ gyro rate that best
    matches the rates of conj(CORI); returns (M, median residual / median rate)."""
    q = rotations.conjugate(cori / np.linalg.norm(cori, axis=1, keepdims=True))
    dq = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])
    w = rotations.to_scipy(dq).as_rotvec() / np.maximum(np.diff(t_cori), 1e-6)[:, None]
    tm = (t_cori[:-1] + t_cori[1:]) / 2
    g = resample(tm, t_gyr, gyr)
    best = (np.inf, DEFAULT_IMU_TO_CV)
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for i, (j, s) in enumerate(zip(perm, signs, strict=True)):
                m[i, j] = s
            if np.linalg.det(m) < 0:
                continue
            r = float(np.median(np.linalg.norm(g @ m.T - w, axis=1)))
            if r < best[0]:
                best = (r, m)
    scale = float(np.median(np.linalg.norm(w, axis=1))) or 1.0
    return best[1], best[0] / scale


def level(camera: OrientationStream, acc: VectorStream) -> OrientationStream:
    """CORI's start frame has an arbitrary tilt: turn it so that the accelerometer's mean up (over
    the first LEVEL_WINDOW_S) points to world Up. Heading stays arbitrary until the course fixes it."""
    first = acc.t <= acc.t[0] + LEVEL_WINDOW_S
    up_dev = acc.values[first].mean(axis=0)
    q0 = rotations.slerp(camera.t, camera.q, [acc.t[0] + LEVEL_WINDOW_S / 2])[0]
    up = rotations.rotate(q0, up_dev / np.linalg.norm(up_dev))
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    if s < 1e-9:
        return camera
    turn = rotations.from_rotvec(axis / s * np.arctan2(s, up[2]))
    return OrientationStream(
        camera.t,
        rotations.canonical(rotations.multiply(turn, camera.q)),
        camera.path,
        camera.note,
    )


def _checked_magnetometer(
    mag: VectorStream, gnss: GnssTrack | None, utc0: float | None, path: Path, messages: Messages
) -> VectorStream | None:
    """The magnetometer, if its field strength is plausible for the place (WMM), else None."""
    if gnss is None:
        messages.add(
            f"{path.name}: no GPS fix to check the magnetometer against the World Magnetic Model: not used"
        )
        return None
    expected = float(
        np.linalg.norm(
            field_enu(float(gnss.lat[0]), float(gnss.lon[0]), float(gnss.h[0]), utc0 or 0.0)
        )
    )
    ok, measured = magnetometer_plausible(mag.values, expected)
    if ok:
        return mag
    messages.add(
        f"{path.name}: magnetometer reads {measured:.0f} uT where the World Magnetic Model expects {expected:.0f} uT: not used; heading comes from the GNSS course"
    )
    return None


STILL_RATE_RAD_S = 0.1  # gyroscope rates below this count as still, for the gravity check
LEVEL_TOLERANCE_DEG = 35.0  # gravity within this of the device's up: the camera was held level


def gravity_up_angle(
    acc_imu: np.ndarray, gyr_imu: np.ndarray, imu_to_cv: np.ndarray = DEFAULT_IMU_TO_CV
) -> float:
    """Angle (deg) between the device's +y (up on an upright camera) and the mean accelerometer
    direction over still samples, IMU-axis samples mapped to the device frame by imu_to_cv."""
    n = min(len(acc_imu), len(gyr_imu))
    still = np.linalg.norm(gyr_imu[:n], axis=1) < STILL_RATE_RAD_S if n else np.zeros(0, bool)
    sample = acc_imu[:n][still] if still.sum() >= 10 else acc_imu
    up = sample.mean(axis=0) @ (CV_TO_DEVICE @ imu_to_cv).T
    return float(np.degrees(np.arccos(np.clip(up[1] / max(np.linalg.norm(up), 1e-9), -1.0, 1.0))))


def choose_axis_order(
    acc_stored: np.ndarray, gyr_stored: np.ndarray, model: str
) -> tuple[str, float]:
    """For a file without ORIN or CORI: the data order (among the documented ones, the model's
    first, and XYZ) under which gravity in still sections points up for a camera held level;
    returns (order, its angle from up in degrees). Orders within 5 deg of the best keep their
    rank (the model's documented one wins a tie)."""
    documented = [v for k, v in DEFAULT_ORIN.items() if k.lower() in model.lower()]
    candidates = list(dict.fromkeys(documented + list(DEFAULT_ORIN.values()) + ["XYZ"]))
    angles = [
        gravity_up_angle(orin_map(o, acc_stored), orin_map(o, gyr_stored)) for o in candidates
    ]
    best = min(angles)
    k = next(i for i, a in enumerate(angles) if a <= best + 5.0)
    return candidates[k], angles[k]


def to_device_frame(raw: GoProRaw, messages: Messages) -> GoProRecording:
    """Turn a clip's raw telemetry into device-frame streams (see the module docstring)."""
    path = raw.path
    (ta, a), (tg, g) = raw.acc, raw.gyr
    if not raw.orin_recorded and raw.cori is None and raw.acc_stored is not None:
        order, angle = choose_axis_order(raw.acc_stored, raw.gyr_stored, raw.model)
        a, g = orin_map(order, raw.acc_stored), orin_map(order, raw.gyr_stored)
        if angle <= LEVEL_TOLERANCE_DEG:
            messages.info(
                f"{path.name}: no ORIN or CORI: axis order {order} chosen, under which gravity points up ({angle:.0f} deg off) for a camera held level"
            )
        else:
            messages.add(
                f"{path.name}: no ORIN or CORI, and no axis order puts gravity up (best {order}, {angle:.0f} deg off): the camera's axes cannot be verified; attitude may be turned"
            )
    camera = None
    imu_to_cv = DEFAULT_IMU_TO_CV
    cori = raw.cori
    if cori is not None:
        unit = np.abs(np.linalg.norm(cori[1], axis=1) - 1.0) < 0.1
        if unit.sum() < 2:
            messages.add(
                f"{path.name}: CORI holds no unit quaternions ({int((~unit).sum())} of {len(unit)} are not): not used"
            )
            cori = None
        elif not unit.all():
            messages.add(
                f"{path.name}: {int((~unit).sum())} CORI samples that are not unit quaternions dropped"
            )
            cori = (cori[0][unit], cori[1][unit])
    if cori is not None:
        tc, cq = cori
        m, rel = fit_imu_to_camera(tg, g, tc, cq)
        if rel < FIT_MAX_RESIDUAL:
            imu_to_cv = m
        else:
            messages.add(
                f"{path.name}: the gyroscope does not match CORI under any axis order (residual {rel:.0%}); the MAX axis mapping is assumed"
            )
        q_cv = rotations.conjugate(cq / np.linalg.norm(cq, axis=1, keepdims=True))
        q_dev = rotations.multiply(
            q_cv, np.array([0.0, 1.0, 0.0, 0.0])
        )  # device -> camera-cv is a half turn about x
        camera = OrientationStream(
            tc, q_dev, str(path), "GoPro CORI: camera orientation since capture start"
        )
    else:
        messages.add(
            f"{path.name}: no CORI stream: the IMU axis mapping fitted on the GoPro MAX is assumed"
        )
    to_dev = CV_TO_DEVICE @ imu_to_cv
    acc = checked_vector(VectorStream("acc", ta, a @ to_dev.T, "m/s^2", str(path)), messages)
    gyr = checked_vector(VectorStream("gyr", tg, g @ to_dev.T, "rad/s", str(path)), messages)
    if camera is not None:
        camera = level(camera, acc)
    mag = None
    if raw.magn is not None:
        tm, mv = raw.magn
        mag = checked_vector(VectorStream("mag", tm, mv @ to_dev.T, "uT", str(path)), messages)
        if mag is not None:
            mag = _checked_magnetometer(mag, raw.gnss, raw.gps_utc_at_zero, path, messages)
    return GoProRecording(raw, acc, gyr, mag, camera)


def read_gopro(path: str | Path, messages: Messages | None = None) -> GoProRecording:
    """A GoPro MP4's telemetry in the device frame (app.io.gopro reads it; this turns it)."""
    messages = messages if messages is not None else Messages()
    return to_device_frame(read_gopro_raw(path, messages), messages)
