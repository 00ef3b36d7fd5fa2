"""Sensor Logger (Kelvin Choi's app, iOS and Android) CSV recordings: a folder or its zip export.

Documented by the app's author (awesome-sensor-logger: UNITS.md, COORDINATES.md, CROSSPLATFORM.md):
- every file has `time` (Unix ns) and `seconds_elapsed`; sensor axes are x, y, z (written z, y, x);
- Gyroscope.csv rad/s; Magnetometer.csv uT; Location.csv latitude, longitude (deg), altitude (m
  above the WGS84 ellipsoid), speed (m/s), bearing (deg from north; negative = invalid),
  horizontalAccuracy (m);
- acceleration: Android writes TotalAcceleration.csv (with gravity, +up at rest, as we want) and
  Accelerometer.csv without gravity; iOS writes Accelerometer.csv (user acceleration) and
  Gravity.csv, both with the opposite sign to Android unless "Standardise Units & Frames" was on.
  We use TotalAcceleration.csv when present; else Accelerometer + Gravity, negated for iOS
  (Metadata.csv `platform`) unless `standardised=True`;
- Orientation.csv qx, qy, qz, qw: the phone's own fused attitude. iOS and Android differ in world
  frame (x-north vs ENU) and possibly direction, so `reference_orientation` picks the convention
  that agrees with the logged gravity and magnetic field and says which it chose.
"""

from __future__ import annotations

import csv
import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.core.errors import DataFormatError
from app.geodesy import rotations
from app.io.csvlog import numeric
from app.io.streams import (
    GnssTrack,
    Messages,
    OrientationStream,
    VectorStream,
    checked_vector,
    clean_times,
    plausible_fixes,
    require_samples,
    resample,
)


@dataclass(frozen=True)
class SensorLoggerRecording:
    """The streams of one recording; times are Unix seconds."""

    acc: VectorStream
    gyr: VectorStream
    mag: VectorStream | None
    gnss: GnssTrack | None
    orientation: OrientationStream | None
    platform: str


class _Source:
    """Files of a recording folder or zip, by case-insensitive name."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if path.is_dir():
            self.names = {p.name.lower(): p.name for p in path.iterdir() if p.is_file()}
            self.zip = None
        elif zipfile.is_zipfile(path):
            self.zip = zipfile.ZipFile(path)
            self.names = {
                Path(n).name.lower(): n for n in self.zip.namelist() if not n.endswith("/")
            }
        else:
            raise DataFormatError(
                path, "not a Sensor Logger recording (expected its folder or zip export)"
            )

    def has(self, name: str) -> bool:
        return name.lower() in self.names

    def where(self, name: str) -> Path:
        return self.path / self.names[name.lower()]

    def rows(self, name: str) -> tuple[dict[str, int], list[list[str]]]:
        real = self.names[name.lower()]
        data = (
            self.zip.read(real).decode("utf-8-sig")
            if self.zip
            else (self.path / real).read_text(encoding="utf-8-sig")
        )
        rows = list(csv.reader(io.StringIO(data)))
        if not rows:
            raise DataFormatError(self.where(name), "empty file (expected a header row)", line=1)
        return {c.strip().lower(): i for i, c in enumerate(rows[0])}, rows[1:]


def _columns(
    src: _Source, name: str, wanted: list[str], label: str, messages: Messages
) -> tuple[np.ndarray, np.ndarray]:

    cols, rows = src.rows(name)
    path = src.where(name)
    values, lines = numeric(path, rows, cols, ["time", *wanted], 2, messages)
    t = values[:, 0] * 1e-9
    keep = clean_times(t, lines, path, label, messages)
    require_samples(int(keep.sum()), 2, path, label)
    return t[keep], values[keep, 1:]


def _vector(src: _Source, name: str, kind: str, unit: str, messages: Messages) -> VectorStream:
    t, v = _columns(src, name, ["x", "y", "z"], kind, messages)
    return VectorStream(kind, t, v, unit, str(src.where(name)))


def _platform(src: _Source) -> str:
    for name in ("metadata.csv",):
        if src.has(name):
            cols, rows = src.rows(name)
            if "platform" in cols and rows:
                return rows[0][cols["platform"]].strip().lower()
    return "unknown"


def read_sensorlogger(
    path: str | Path, standardised: bool = False, messages: Messages | None = None
) -> SensorLoggerRecording:
    """Read a Sensor Logger recording. `standardised`: the app's "Standardise Units & Frames" was on."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    if not path.exists():
        raise DataFormatError(path, "recording does not exist")
    src = _Source(path)
    platform = _platform(src)
    if not src.has("gyroscope.csv"):
        raise DataFormatError(
            path, "no Gyroscope.csv in the recording (enable the gyroscope in Sensor Logger)"
        )
    gyr = _vector(src, "Gyroscope.csv", "gyr", "rad/s", messages)
    if src.has("totalacceleration.csv"):
        acc = _vector(src, "TotalAcceleration.csv", "acc", "m/s^2", messages)
    elif src.has("accelerometer.csv") and src.has("gravity.csv"):
        user = _vector(src, "Accelerometer.csv", "acc", "m/s^2", messages)
        grav = _vector(src, "Gravity.csv", "acc", "m/s^2", messages)
        total = user.values + resample(user.t, grav.t, grav.values)
        sign = -1.0 if platform == "ios" and not standardised else 1.0
        if platform == "unknown":
            messages.add(
                f"{path.name}: no platform in Metadata.csv; acceleration taken in Android's sign convention"
            )
        acc = VectorStream("acc", user.t, sign * total, "m/s^2", user.path)
    else:
        raise DataFormatError(
            path,
            "no acceleration with gravity: expected TotalAcceleration.csv, or Accelerometer.csv and Gravity.csv",
        )
    gyr, acc = checked_vector(gyr, messages), checked_vector(acc, messages)
    mag = (
        _vector(src, "Magnetometer.csv", "mag", "uT", messages)
        if src.has("magnetometer.csv")
        else None
    )
    mag = None if mag is None else checked_vector(mag, messages)
    if mag is None and not src.has("magnetometer.csv"):
        messages.add(f"{path.name}: no Magnetometer.csv: only the IMU (6D) filters are available")
    gnss = None
    if src.has("location.csv"):
        t, v = _columns(
            src, "Location.csv", ["latitude", "longitude", "altitude"], "GNSS", messages
        )
        cols, _ = src.rows("Location.csv")
        vel = None
        if "speed" in cols and "bearing" in cols:
            _, sb = _columns(src, "Location.csv", ["speed", "bearing"], "GNSS", Messages())
            valid = (sb[:, 0] >= 0) & (sb[:, 1] >= 0)
            if valid.all():
                b = np.radians(sb[:, 1])
                vel = np.column_stack(
                    [sb[:, 0] * np.sin(b), sb[:, 0] * np.cos(b), np.zeros(len(b))]
                )
            else:
                messages.add(
                    f"{path.name}: Location.csv has {int((~valid).sum())} fixes with invalid speed/bearing; velocity estimated from positions"
                )
        gnss = plausible_fixes(
            GnssTrack(t, v[:, 0], v[:, 1], v[:, 2], vel, None, str(src.where("Location.csv"))),
            messages,
        )
    orientation = None
    if src.has("orientation.csv"):
        t, q = _columns(src, "Orientation.csv", ["qw", "qx", "qy", "qz"], "orientation", messages)
        orientation = reference_orientation(
            OrientationStream(
                t, q / np.linalg.norm(q, axis=1, keepdims=True), str(src.where("Orientation.csv"))
            ),
            acc,
            mag,
            platform,
        )
    return SensorLoggerRecording(acc, gyr, mag, gnss, orientation, platform)


def reference_orientation(
    raw: OrientationStream, acc: VectorStream, mag: VectorStream | None, platform: str
) -> OrientationStream:
    """The recording's own attitude in our convention (device -> ENU), choosing among q and its
    conjugate and among world frames turned 0/90/180/270 deg about Up the one under which the
    logged gravity points up and the logged field points north (magnetic)."""
    a = resample(raw.t, acc.t, acc.values)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    m = None if mag is None else resample(raw.t, mag.t, mag.values)
    best = None
    for name, q in (("as logged", raw.q), ("conjugated", rotations.conjugate(raw.q))):
        up_err = np.mean(np.linalg.norm(rotations.rotate(q, a) - [0, 0, 1], axis=1))
        for turn in (0.0, 90.0, 180.0, -90.0):
            qq = rotations.multiply(
                rotations.heading_turn(-turn), q
            )  # counter-clockwise seen from above
            score = up_err
            if m is not None:
                h = rotations.rotate(qq, m)
                score += np.mean(np.abs(np.arctan2(h[:, 0], h[:, 1]))) / np.pi
            elif turn != (90.0 if platform == "ios" else 0.0):
                score += 1.0  # without a magnetometer, keep the platform's documented frame
            if best is None or score < best[0]:
                best = (score, qq, f"{name}, world turned {turn:+.0f} deg about Up")
    return OrientationStream(
        raw.t, rotations.canonical(best[1]), raw.path, f"convention: {best[2]}"
    )
