"""The MAVLink receiver of a live feed: telemetry as ArduPilot and PX4 send it (`--mavlink
udp:HOST:PORT`, any connection pymavlink opens: udpin:, udpout:, tcp:, a serial device), read on
a daemon thread into app.io.mavlink's telemetry, each message stamped with the monotonic clock
when pymavlink hands it over (its arrival in geofuse).

pymavlink (the MAVLink project's own Python library) decodes every dialect and both protocol
versions; only the messages app.io.mavlink.USED are kept. Faults are said once and counted, none
ends the thread: a connection that cannot be opened (retried with back-off), silence.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from pymavlink import mavutil

from app.core.messages import Messages
from app.io.mavlink import USED, MavlinkTelemetry

BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
READ_TIMEOUT_S = 0.25


class MavlinkReceiver:
    """Receives MAVLink from `address` into `telemetry` until `stop`."""

    def __init__(
        self,
        address: str,
        telemetry: MavlinkTelemetry,
        messages: Messages,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.address = address
        self.telemetry = telemetry
        self.messages = messages
        self.clock = clock
        self.received = 0  # MAVLink messages of the types used
        self.last_arrival_s: float | None = None
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-mavlink", daemon=True)

    def start(self) -> MavlinkReceiver:
        self._thread.start()
        return self

    def wait_ready(self, timeout_s: float = 5.0) -> bool:
        """Whether the connection is open (a listening socket bound) within timeout_s."""
        return self._ready.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)

    def _run(self) -> None:
        attempt = 0
        while not self._stop.is_set():
            try:
                # udp:HOST:PORT listens (pymavlink's meaning, as ground stations use it)
                conn = mavutil.mavlink_connection(self.address, source_system=255)
            except (OSError, ValueError) as exc:
                hint = (
                    " (another program holds the port: choose another, or stop it)"
                    if "in use" in str(exc).lower()
                    else ""
                )
                self.messages.add_once(
                    "mavlink-open",
                    f"{self.address}: cannot open the MAVLink connection ({exc}){hint}; retrying",
                )
                self._stop.wait(BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
                attempt += 1
                continue
            self._ready.set()
            try:
                self._receive(conn)
            finally:
                conn.close()

    def _receive(self, conn) -> None:
        while not self._stop.is_set():
            try:
                msg = conn.recv_match(type=list(USED), blocking=True, timeout=READ_TIMEOUT_S)
            except (OSError, ValueError) as exc:
                self.messages.add_once(
                    "mavlink-read", f"{self.address}: reading MAVLink failed ({exc}); reopening"
                )
                return
            if msg is None:
                continue
            now = self.clock()
            self.received += 1
            self.last_arrival_s = now
            kind = msg.get_type()
            if kind == "BAD_DATA":
                continue
            self.telemetry.add(kind, msg.to_dict(), now)
