"""A drone flown by an autopilot (ArduPilot, PX4), simulated: the MAVLink telemetry it sends
beside a video without KLV, for tests, `geofuse simulate feed --mavlink` and demos.

The flight is app.simulate.drone's weave over the sample site (the video: drone.write_video to a
.ts path); the vehicle flies it nose first, pitched VEHICLE_PITCH_DEG down and banked into its
turns, and its gimbal holds the camera drone.PITCH_DEG below the horizon, its yaw with the
vehicle's (GIMBAL_DEVICE_ATTITUDE_STATUS with the yaw in the vehicle frame, or ArduPilot's
MOUNT_STATUS). Heights are sent above sea level (through EGM2008), the home at take-off on the
ground (HOME_ENU, sent as HOME_POSITION once a second where asked). Without a fix (`fixed` False:
GNSS jammed) GLOBAL_POSITION_INT carries latitude and longitude 0 and only its relative_alt, the
barometer's height above home, as ArduPilot sends it. Messages are encoded and sent by pymavlink,
as an autopilot's own would be.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.simulate import drone
from app.simulate.stadium import SITE_ORIGIN

VEHICLE_PITCH_DEG = -6.0  # flying forward, nose down
BANK_GAIN = 0.8  # roll (deg) per deg/s of turn
BOOT_MS = 300_000  # the autopilot's boot clock at the flight's start
RATES_HZ = {"ATTITUDE": 25.0, "GLOBAL_POSITION_INT": 10.0, "GIMBAL": 10.0}
HOME_HZ = 1.0
HOME_ENU = (-160.0, -160.0)  # the take-off point (ENU m about the site, on its ground): 82 m
# south-west of where the flight's video begins


def vehicle_state(
    t: float, path_of=drone.flight
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """((lat, lon, ellipsoidal h), (yaw, pitch, roll) deg) of the vehicle at flight time t s
    (path_of: the flight, as drone.flight)."""
    pos, heading = path_of(np.array([t - 0.05, t, t + 0.05]))
    turn = ((heading[2] - heading[0] + 180.0) % 360.0 - 180.0) / 0.1  # deg/s
    lat, lon, h = LocalFrame(*SITE_ORIGIN).enu_to_geodetic(pos[1:2])[0]
    return (float(lat), float(lon), float(h)), (
        float(heading[1]),
        VEHICLE_PITCH_DEG,
        BANK_GAIN * turn,
    )


def messages_at(
    t: float,
    kind: str,
    gimbal: str | None,
    mav,
    path_of=drone.flight,
    fixed: bool = True,
    home_enu: tuple[float, float] = HOME_ENU,
) -> list:
    """The messages of `kind` (a RATES_HZ key, or HOME_POSITION) the autopilot sends at flight
    time t s, encoded by `mav` (a pymavlink MAVLink object); gimbal: 'device', 'mount' or None
    (no gimbal); fixed: False, positions without a fix (the module docstring); home_enu: the
    home point (ENU m about the site, on its ground)."""
    (lat, lon, h), (yaw, pitch, roll) = vehicle_state(t, path_of)
    boot = BOOT_MS + int(round(t * 1000))
    if kind == "ATTITUDE":
        return [mav.attitude_encode(boot, *np.radians([roll, pitch, yaw]), 0.0, 0.0, 0.0)]
    home_msl = SITE_ORIGIN[2] - float(undulation(lat, lon))
    if kind == "HOME_POSITION":
        home = LocalFrame(*SITE_ORIGIN).enu_to_geodetic([*home_enu, 0.0])
        ll = [int(round(float(v) * 1e7)) for v in home[:2]]
        return [mav.home_position_encode(*ll, int(round(home_msl * 1000)), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)]  # fmt: skip
    if kind == "GLOBAL_POSITION_INT":
        msl = h - float(undulation(lat, lon))
        where = (int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(msl * 1000)))
        return [
            mav.global_position_int_encode(
                boot,
                *(where if fixed else (0, 0, 0)),
                int(round((msl - home_msl) * 1000)),
                0,
                0,
                0,
                int(round(yaw * 100)) % 36000,
            )
        ]
    if gimbal == "device":  # earth-levelled pitch, yaw in the vehicle frame (0: with the nose)
        half = math.radians(drone.PITCH_DEG) / 2
        q = [math.cos(half), 0.0, math.sin(half), 0.0]
        flags = mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        return [mav.gimbal_device_attitude_status_encode(0, 0, boot, flags, q, 0, 0, 0, 0)]
    if gimbal == "mount":
        return [mav.mount_status_encode(0, 0, int(drone.PITCH_DEG * 100), 0, 0)]
    return []


class MavlinkSender:
    """Sends the autopilot's telemetry for flight times 0..seconds as MAVLink 2 datagrams to
    `address` (host, port) in real time: the messages of flight time t leave at start_s + t -
    lead_s on `clock` (lead_s > 0: the telemetry ahead of a video that left at start_s + t);
    fixed False: without a GNSS fix (lost_at_s: from that flight time on, until back_at_s); home: HOME_POSITION
    sent too, at home_enu (the module docstring)."""

    def __init__(
        self,
        address: tuple[str, int],
        seconds: float,
        start_s: float,
        lead_s: float = 0.0,
        gimbal: str | None = "device",
        clock: Callable[[], float] = time.monotonic,
        path_of=drone.flight,
        fixed: bool = True,
        home: bool = False,
        home_enu: tuple[float, float] = HOME_ENU,
        lost_at_s: float | None = None,
        back_at_s: float = math.inf,
    ) -> None:
        self.path_of, self.fixed, self.home, self.home_enu = path_of, fixed, home, home_enu
        self.lost_at_s, self.back_at_s = lost_at_s, back_at_s
        self.address = address
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.seconds, self.start_s, self.lead_s = seconds, start_s, lead_s
        self.gimbal = gimbal
        self.clock = clock
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-autopilot", daemon=True)

    def _schedule(self) -> list[tuple[float, str]]:
        out = []
        for kind, hz in RATES_HZ.items():
            out += [(float(t), kind) for t in np.arange(0.0, self.seconds, 1.0 / hz)]
        if self.home:
            out += [(float(t), "HOME_POSITION") for t in np.arange(0.0, self.seconds, 1.0 / HOME_HZ)]  # fmt: skip
        return sorted(out)

    def start(self) -> MavlinkSender:
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(5.0)
        self.sock.close()

    def _run(self) -> None:
        for t, kind in self._schedule():
            due = self.start_s + t - self.lead_s
            while (wait := due - self.clock()) > 0:
                if self._stop.wait(min(wait, 0.01)):  # (read again: the clock may stand)
                    return
            lost = self.lost_at_s is not None and self.lost_at_s <= t < self.back_at_s
            fixed = self.fixed and not lost
            for m in messages_at(t, kind, self.gimbal, self.mav, self.path_of, fixed, self.home_enu):  # fmt: skip
                self.sock.sendto(m.pack(self.mav), self.address)
                self.sent += 1
