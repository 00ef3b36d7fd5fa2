"""MAVLink telemetry as camera poses (pure: messages come in as the dictionaries pymavlink's
`to_dict()` gives, each with the time it arrived; app.live.mavlink receives them).

Messages used (MAVLink's common set, as ArduPilot and PX4 send them):

- GLOBAL_POSITION_INT: time_boot_ms; lat, lon (1e-7 deg); alt (mm above mean sea level: taken
  to the ellipsoid through EGM2008); relative_alt (mm above home: home's height, alt -
  relative_alt, is the assumed ground). lat = lon = 0 is "no fix": a gap, counted.
- ATTITUDE: time_boot_ms; roll, pitch, yaw (rad): the vehicle's body (x forward, y right, z
  down) in North-East-Down as Rz(yaw) Ry(pitch) Rx(roll), the convention of ST 0601's platform
  angles (app.io.misb.ypr_matrix).
- GIMBAL_DEVICE_ATTITUDE_STATUS: time_boot_ms; q [w, x, y, z]: the gimbal's (camera's) body in
  North-East-Down, its pitch and roll against the horizon; its yaw absolute (from north) when the
  flags say YAW_IN_EARTH_FRAME (64), or YAW_LOCK (16) without YAW_IN_VEHICLE_FRAME (32); else
  relative to the vehicle's heading (the message's own definition).
- MOUNT_STATUS (ArduPilot): pointing_a pitch, pointing_b roll, pointing_c yaw (centidegrees):
  pitch and roll against the horizon, yaw relative to the vehicle's heading. It has no time stamp:
  it is placed at its arrival through the clock link below.
- HOME_POSITION: latitude, longitude (1e-7 deg), altitude (mm above mean sea level, taken to the
  ellipsoid as GLOBAL_POSITION_INT's): where the vehicle took off (or the home the operator set).
  While no GLOBAL_POSITION_INT has a fix (GNSS jammed, or lost before the feed was joined) and
  the unfixed ones still give relative_alt (the barometer's height above home), the camera stands
  at the home point (without a HOME_POSITION, the one assumed: a live feed's --origin) at that
  height, marked not fixed (`TelemetryPose.fixed`): where a live feed
  searches the scene for it (app.live.register), never a position drawn as it is.
- GPS_RAW_INT: h_acc (mm, MAVLink 2's extension; 0: not given), the accuracy the receiver states
  for its position, which the live GNSS test holds the fixes to (app.live.gnss_watch). Its
  time_usec may be Unix time or boot time: it is placed at its arrival, as MOUNT_STATUS is. Its
  eph is a dilution of precision (HDOP x 100), not metres: not used.

The camera: with a gimbal, Rz(heading) Ry(pitch) Rx(roll) of the gimbal, heading = its yaw (plus
the vehicle's yaw when relative); without one, the vehicle's own rotation (a camera fixed along
the nose: said by the caller). Either goes through app.io.misb.camera_from_sensor, the
convention KLV uses.

Messages that cannot be true are dropped and counted by reason (MavlinkCounts.dropped), none
raises: a latitude or longitude out of range (an int32 reaches 214.7 deg), a height no fix has
(app.io.streams.HEIGHT_RANGE_M), angles that are not numbers or lie beyond +-2 pi rad (ATTITUDE
sends -pi..pi; 0..2 pi yaws are taken), a gimbal quaternion of zero length, a field missing.

Time: the autopilot's boot clock (time_boot_ms / 1000, s). Its link to the arrival clock
(monotonic s) is the smallest arrival - boot over recent messages (the one that travelled
fastest), as the video's jitter buffer links the video's presentation times.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.geodesy.geoid import undulation
from app.io.misb import camera_from_sensor, ypr_matrix
from app.io.streams import HEIGHT_RANGE_M, impossible_step, usual_interval

LINK_WINDOW = 500  # messages over which the fastest sets the boot -> arrival link
FLAG_YAW_LOCK, FLAG_YAW_IN_VEHICLE, FLAG_YAW_IN_EARTH = 16, 32, 64
USED = (
    "GLOBAL_POSITION_INT",
    "ATTITUDE",
    "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "MOUNT_STATUS",
    "GPS_RAW_INT",
    "HOME_POSITION",
)
ANGLE_LIMIT_RAD = 2.0 * math.pi  # ATTITUDE's angles are -pi..pi; beyond +-2 pi is not an angle
MOUNT_LIMIT_CDEG = 36_000  # MOUNT_STATUS pointing (centidegrees): beyond a turn is not an angle
ACCURACY_LIMIT_M = 10_000.0  # GPS_RAW_INT's h_acc: UINT32_MAX mm (4,295 km) is no accuracy

FloatArray = np.ndarray


class Unusable(ValueError):
    """A message that cannot be true; its text is the reason, read after a count ("3 ATTITUDE
    with angles that are not numbers")."""


def gimbal_angles(q: list[float], flags: int) -> tuple[float, float, float, bool]:
    """(yaw, pitch, roll) in degrees of a GIMBAL_DEVICE_ATTITUDE_STATUS quaternion [w, x, y, z]
    (Rz Ry Rx in North-East-Down), and whether the yaw is relative to the vehicle's heading;
    Unusable (a ValueError) for a quaternion of zero length or not a number."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not n or not math.isfinite(n):
        raise Unusable(
            "GIMBAL_DEVICE_ATTITUDE_STATUS with a quaternion of zero length or not a number"
        )
    w, x, y, z = w / n, x / n, y / n, z / n
    yaw = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))))
    roll = math.degrees(math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
    earth = bool(flags & FLAG_YAW_IN_EARTH) or (
        bool(flags & FLAG_YAW_LOCK) and not flags & FLAG_YAW_IN_VEHICLE
    )
    return yaw, pitch, roll, not earth


def camera_quat(
    vehicle_ypr: tuple[float, float, float],
    gimbal_ypr: tuple[float, float, float] | None,
    gimbal_relative: bool = True,
) -> FloatArray:
    """Camera -> ENU quaternion from the vehicle's (yaw, pitch, roll) and the gimbal's (degrees;
    None: the camera along the vehicle's nose); see the module docstring."""
    if gimbal_ypr is None:
        return camera_from_sensor(ypr_matrix(*vehicle_ypr))
    yaw, pitch, roll = gimbal_ypr
    heading = yaw + vehicle_ypr[0] if gimbal_relative else yaw
    return camera_from_sensor(ypr_matrix(heading, pitch, roll))


def _angle_at(t: list[float], a: list[float], x: float) -> float:
    """Degrees interpolated at x between samples (held beyond the ends), the short way round."""
    i = bisect.bisect_right(t, x)
    if i == 0:
        return a[0]
    if i == len(t):
        return a[-1]
    w = (x - t[i - 1]) / (t[i] - t[i - 1])
    d = (a[i] - a[i - 1] + 180.0) % 360.0 - 180.0
    return a[i - 1] + w * d


def value_at(t: list[float], v: list, x: float) -> np.ndarray:
    """The values v (per time t, increasing) at x: linear between two, the nearest held beyond."""
    i = bisect.bisect_right(t, x)
    if i == 0:
        return np.asarray(v[0], np.float64)
    if i == len(t):
        return np.asarray(v[-1], np.float64)
    w = (x - t[i - 1]) / (t[i] - t[i - 1])
    return (1 - w) * np.asarray(v[i - 1], np.float64) + w * np.asarray(v[i], np.float64)


def _position(m: dict[str, Any]) -> tuple[float, float, float, float | None]:
    """(lat, lon deg, ellipsoidal h m, home's ellipsoidal h m or None) of a GLOBAL_POSITION_INT
    with a fix; Unusable when out of range."""
    kind = "GLOBAL_POSITION_INT"
    lat, lon = m["lat"] / 1e7, m["lon"] / 1e7
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0):
        raise Unusable(
            f"{kind} with a latitude or longitude out of range (expected +-90, +-180 deg)"
        )
    h = m["alt"] / 1000.0 + float(undulation(lat, lon))
    home = h - m["relative_alt"] / 1000.0 if "relative_alt" in m else None
    low, high = HEIGHT_RANGE_M
    if not low <= h <= high or (home is not None and not low <= home <= high):
        raise Unusable(
            f"{kind} with a height no fix has (alt, or home's alt - relative_alt, beyond "
            f"{low / 1000:g} to {high / 1000:g} km)"
        )
    return lat, lon, h, home


def _home(m: dict[str, Any]) -> tuple[float, float, float]:
    """(lat, lon deg, ellipsoidal h m) of a HOME_POSITION; Unusable when out of range or at 0, 0
    (no home)."""
    lat, lon = m["latitude"] / 1e7, m["longitude"] / 1e7
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0) or (lat == 0.0 and lon == 0.0):
        raise Unusable("HOME_POSITION with a latitude or longitude out of range or at 0, 0")
    h = m["altitude"] / 1000.0 + float(undulation(lat, lon))
    if not HEIGHT_RANGE_M[0] <= h <= HEIGHT_RANGE_M[1]:
        raise Unusable("HOME_POSITION with a height no place has")
    return lat, lon, h


def _attitude(m: dict[str, Any]) -> tuple[float, float, float]:
    """(yaw, pitch, roll) degrees of an ATTITUDE; Unusable when not angles."""
    rad = tuple(float(m[k]) for k in ("yaw", "pitch", "roll"))
    if not all(math.isfinite(a) for a in rad):
        raise Unusable("ATTITUDE with angles that are not numbers")
    if max(abs(a) for a in rad) > ANGLE_LIMIT_RAD:
        raise Unusable("ATTITUDE with angles beyond +-2 pi rad (expected -pi..pi)")
    return tuple(math.degrees(a) for a in rad)


def _mount(m: dict[str, Any]) -> tuple[float, float, float]:
    """(yaw, pitch, roll) degrees of a MOUNT_STATUS (centidegrees c, a, b); Unusable beyond a
    turn."""
    cdeg = tuple(float(m[k]) for k in ("pointing_c", "pointing_a", "pointing_b"))
    if max(abs(a) for a in cdeg) > MOUNT_LIMIT_CDEG:
        raise Unusable("MOUNT_STATUS with angles beyond +-360 deg")
    return tuple(a / 100.0 for a in cdeg)


@dataclass
class MavlinkCounts:
    """Messages used, by type; positions without a fix; messages dropped, by reason (each
    reason a phrase read after its count)."""

    used: dict[str, int] = field(default_factory=dict)
    no_fix: int = 0
    dropped: dict[str, int] = field(default_factory=dict)

    def drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1


@dataclass(frozen=True)
class TelemetryPose:
    """The camera at a boot time: geodetic (lat, lon deg, ellipsoidal h m), camera -> ENU
    quaternion, and how far past the newest position or attitude it lies (s, 0 when between;
    fix_age_s: past the newest position); fixed: False where no fix placed it (the home point at the barometer's height: see the
    module docstring)."""

    geodetic: tuple[float, float, float]
    q: FloatArray
    age_s: float
    gimbal: bool
    fixed: bool = True
    fix_age_s: float = 0.0  # how far past the newest position alone (s)


class MavlinkTelemetry:
    """Positions, attitudes and gimbal angles on the boot clock, growing as messages arrive;
    thread-safe (a receiver adds, the drawing thread and the lag estimator ask)."""

    def __init__(self, assumed_home: tuple[float, float, float] | None = None) -> None:
        """assumed_home: (lat, lon deg, the ground's ellipsoidal h m) taken for home until a
        HOME_POSITION says where it is (a live feed's --origin)."""
        self.counts = MavlinkCounts()
        self.home_h: float | None = None  # home's ellipsoidal height (m): the take-off ground
        self.home: tuple[float, float, float] | None = None  # HOME_POSITION's (lat, lon, h)
        self.home_from = "HOME_POSITION"
        if assumed_home is not None:
            self.home = tuple(float(v) for v in assumed_home)
            self.home_h, self.home_from = self.home[2], "--origin"
        self._rel_t: list[float] = []  # heights above home of positions without a fix (m)
        self._rel: list[float] = []
        self._pos_t: list[float] = []
        self._pos: list[tuple[float, float, float]] = []
        self._att_t: list[float] = []
        self._att: list[tuple[float, float, float]] = []  # yaw, pitch, roll (deg)
        self._gim_t: list[float] = []
        self._gim: list[tuple[float, float, float]] = []
        self._gim_relative = True
        self._acc_t: list[float] = []
        self._acc: list[float] = []  # GPS_RAW_INT's h_acc (m)
        self._links: deque[float] = deque(maxlen=LINK_WINDOW)
        self._lock = threading.Lock()

    @property
    def link_s(self) -> float | None:
        """arrival - boot of the fastest recent message (s), None before any."""
        with self._lock:
            return min(self._links) if self._links else None

    @property
    def has_gimbal(self) -> bool:
        return bool(self._gim_t)

    @property
    def unfixed(self) -> bool:
        """Whether the camera stands at the home point for want of any fix (module docstring)."""
        return not self._pos_t and self.home is not None and bool(self._rel_t)

    def __len__(self) -> int:
        """Poses available: positions (or, without any fix, heights above a home point) once an
        attitude has arrived too."""
        if not self._att_t:
            return 0
        return len(self._rel_t) if self.unfixed else len(self._pos_t)

    def first(self) -> tuple[float, float, float] | None:
        """The first fix (lat, lon deg, ellipsoidal h m); without any, the home point at the
        first height above it; None before either."""
        with self._lock:
            if self._pos:
                return self._pos[0]
            if self.unfixed:
                lat, lon, h = self.home
                return lat, lon, h + self._rel[0]
            return None

    def add(self, kind: str, m: dict[str, Any], arrival_s: float) -> bool:
        """One message (`kind`: its type name; `m`: its fields) that arrived at arrival_s
        (monotonic s); False when it is not one of USED or carries nothing usable (counted:
        no_fix, or dropped by reason; see the module docstring)."""
        if kind not in USED:
            return False
        with self._lock:
            try:
                return self._add(kind, m, arrival_s)
            except Unusable as exc:
                self.counts.drop(str(exc))
            except (KeyError, TypeError, ValueError, OverflowError):
                self.counts.drop(f"{kind} with a field missing or not a number")
            return False

    def _add(self, kind: str, m: dict[str, Any], arrival_s: float) -> bool:
        """add's work under the lock: each message's values read (Unusable when they cannot be
        true) before anything is kept."""
        if kind == "HOME_POSITION":  # no time: where home is holds until it is moved
            self.home, self.home_from = _home(m), "HOME_POSITION"
            if self.home_h is None:
                self.home_h = self.home[2]
            self.counts.used[kind] = self.counts.used.get(kind, 0) + 1
            return True
        if kind == "GLOBAL_POSITION_INT" and m["lat"] == 0 and m["lon"] == 0:
            self.counts.no_fix += 1
            if "relative_alt" in m and "time_boot_ms" in m:  # the barometer's, above home
                boot = float(m["time_boot_ms"]) / 1000.0
                self._insert(self._rel_t, self._rel, boot, float(m["relative_alt"]) / 1000.0)
                self._links.append(arrival_s - boot)
            return False
        if "time_boot_ms" in m:
            boot = float(m["time_boot_ms"]) / 1000.0
        elif self._links:
            boot = arrival_s - min(self._links)
        else:  # a MOUNT_STATUS or GPS_RAW_INT before any timed message: nothing places it yet
            return False
        if kind == "GLOBAL_POSITION_INT":
            lat, lon, h, home = _position(m)
            if self.home_h is None and home is not None:
                self.home_h = home
            self._insert(self._pos_t, self._pos, boot, (lat, lon, h))
        elif kind == "ATTITUDE":
            self._insert(self._att_t, self._att, boot, _attitude(m))
        elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            yaw, pitch, roll, self._gim_relative = gimbal_angles(m["q"], int(m.get("flags", 0)))
            self._insert(self._gim_t, self._gim, boot, (yaw, pitch, roll))
        elif kind == "GPS_RAW_INT":
            h_acc = float(m.get("h_acc", 0) or 0) / 1000.0
            if not 0.0 < h_acc < ACCURACY_LIMIT_M:  # not given (0), or no accuracy a fix has
                return False
            self._insert(self._acc_t, self._acc, boot, h_acc)
        else:  # MOUNT_STATUS
            pyr = _mount(m)
            self._gim_relative = True
            self._insert(self._gim_t, self._gim, boot, pyr)
        if "time_boot_ms" in m:
            self._links.append(arrival_s - boot)
        self.counts.used[kind] = self.counts.used.get(kind, 0) + 1
        return True

    def missing(self) -> str | None:
        """What the messages used so far lack to pose the camera (a position, an attitude or
        both), as a phrase; None when both have arrived."""
        with self._lock:
            pos, att = bool(self._pos_t) or self.unfixed, bool(self._att_t)
        if not att and not pos:
            return "no position (GLOBAL_POSITION_INT with a fix) and no attitude (ATTITUDE): the camera cannot be placed"
        if att and not pos:
            return "attitudes but no position (GLOBAL_POSITION_INT with a fix, or HOME_POSITION and the height above it): the camera cannot be placed"
        if pos and not att:
            return "positions but no attitude (ATTITUDE): the camera cannot be pointed"
        return None

    @staticmethod
    def _insert(times: list[float], values: list, t: float, v) -> None:
        i = bisect.bisect_right(times, t)
        if i and times[i - 1] == t:
            values[i - 1] = v
            return
        times.insert(i, t)
        values.insert(i, v)

    def at(self, boot_s: float) -> TelemetryPose | None:
        """The camera at boot_s from the messages arrived so far (positions linear, angles the
        short way round, held past the newest); None before a position and an attitude."""
        with self._lock:
            unfixed = self.unfixed
            if not (self._pos_t or unfixed) or not self._att_t:
                return None
            if unfixed:  # the home point at the barometer's height above it
                lat, lon, h = self.home
                h = h + float(value_at(self._rel_t, self._rel, boot_s))
                newest = self._rel_t[-1]
            else:
                lat, lon, h = value_at(self._pos_t, self._pos, boot_s)
                newest = self._pos_t[-1]
            vehicle = tuple(
                _angle_at(self._att_t, [a[j] for a in self._att], boot_s) for j in range(3)
            )
            gimbal = None
            if self._gim_t:
                gimbal = tuple(
                    _angle_at(self._gim_t, [g[j] for g in self._gim], boot_s) for j in range(3)
                )
            age = max(boot_s - newest, boot_s - self._att_t[-1], 0.0)
            relative = self._gim_relative
        q = camera_quat(vehicle, gimbal, relative)
        place = (float(lat), float(lon), float(h))
        fix_age = max(boot_s - newest, 0.0)
        return TelemetryPose(place, q, age, gimbal is not None, not unfixed, fix_age)

    def fix_interval_s(self) -> float | None:
        """The usual interval between the recent fixes (s), None before two."""
        with self._lock:
            return usual_interval(self._pos_t)

    def jumps_between(self, a_s: float, b_s: float) -> list[tuple[float, float]]:
        """(from, to) boot times (s) of the consecutive positions between which the fix stepped
        as no platform moves (app.io.streams.impossible_step), those ending in (a_s, b_s] or
        under way at b_s: `at` draws the step as a line between them."""
        with self._lock:
            i = max(bisect.bisect_right(self._pos_t, a_s) - 1, 0)
            j = bisect.bisect_right(self._pos_t, b_s) + 1
            t, p = self._pos_t[i:j], self._pos[i:j]
        return [
            (t[k], t[k + 1])
            for k in range(len(t) - 1)
            if t[k + 1] > a_s and t[k] < b_s and impossible_step(t[k + 1] - t[k], p[k], p[k + 1])
        ]

    def accuracy_at(self, boot_s: float) -> float | None:
        """The horizontal accuracy (m) GPS_RAW_INT last stated at or before boot_s (the first
        before any), None where none has."""
        with self._lock:
            if not self._acc_t:
                return None
            i = max(bisect.bisect_right(self._acc_t, boot_s) - 1, 0)
            return self._acc[i]

    def attitude_times(self, since_s: float = -math.inf) -> FloatArray:
        """Boot times (s) of the vehicle attitudes since since_s: where the camera's rotation is
        sampled for the lag estimate."""
        with self._lock:
            return np.array([t for t in self._att_t if t >= since_s], np.float64)
