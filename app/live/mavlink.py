"""The MAVLink receiver of a live feed: telemetry as ArduPilot and PX4 send it (`--mavlink
udp:HOST:PORT`, any connection pymavlink opens: udpin:, udpout:, tcp:, a serial device), read on
a daemon thread into app.io.mavlink's telemetry, each message stamped with the monotonic clock
when pymavlink hands it over (its arrival in geofuse).

pymavlink (the MAVLink project's own Python library) decodes every dialect and both protocol
versions; only the messages app.io.mavlink.USED are kept. Faults are said once and counted, none
ends the thread: a connection that cannot be opened (retried with back-off), silence, bytes that
are not MAVLink, of no known type or failing its checksum (their bytes counted), messages that
cannot be true (each reason said once, counted by app.io.mavlink). A network connection whose
port is not a port is refused at start (said, never tried).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from pymavlink import mavutil

from app.core.messages import Messages
from app.io.mavlink import USED, MavlinkTelemetry
from app.live.probe import mavlink_refusal

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
        self.bytes_received = 0  # everything that arrived, readable or not
        self.readable = 0  # MAVLink messages of a known type, used or not
        self.unreadable_bytes = 0  # not MAVLink, of no known type, or failing its checksum
        self.refused: str | None = None  # why the address was refused at start (never tried)
        self.last_arrival_s: float | None = None
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-mavlink", daemon=True)

    def start(self) -> MavlinkReceiver:
        """The thread started; an address whose port is not a port is refused instead (said as
        an error, `refused` set, nothing tried)."""
        self.refused = mavlink_refusal(self.address)
        if self.refused is not None:
            self.messages.error(self.refused)
            return self
        self._thread.start()
        return self

    def wait_ready(self, timeout_s: float = 5.0) -> bool:
        """Whether the connection is open (a listening socket bound) within timeout_s (s);
        False at once when the address was refused."""
        return self.refused is None and self._ready.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        attempt = 0
        while not self._stop.is_set():
            try:
                # udp:HOST:PORT listens (pymavlink's meaning, as ground stations use it)
                conn = mavutil.mavlink_connection(self.address, source_system=255)
            except (OSError, ValueError, OverflowError) as exc:
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
        parser, counted = None, 0  # conn's parser, and its bytes already in bytes_received
        while not self._stop.is_set():
            try:
                msg = conn.recv_match(blocking=True, timeout=READ_TIMEOUT_S)
            except Exception as exc:  # the socket's, and pymavlink's MAVError (one per dialect)
                self.messages.add_once(
                    "mavlink-read", f"{self.address}: reading MAVLink failed ({exc}); reopening"
                )
                return
            if conn.mav is not parser:  # a new one when pymavlink switches to MAVLink 2
                parser, counted = conn.mav, 0
            self.bytes_received += parser.total_bytes_received - counted
            counted = parser.total_bytes_received
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "BAD_DATA" or kind.startswith("UNKNOWN"):  # (pymavlink: no checksum)
                self._unreadable(len(msg.get_msgbuf()))
                continue
            self.readable += 1
            if kind not in USED:
                continue
            now = self.clock()
            self.received += 1
            self.last_arrival_s = now
            if not self.telemetry.add(kind, msg.to_dict(), now):
                self._say_dropped()

    def _unreadable(self, size: int) -> None:
        """size bytes that are not MAVLink, of no known type or failing its checksum: counted,
        said once."""
        self.unreadable_bytes += size
        self.messages.add_once(
            "mavlink-unreadable",
            f"{self.address}: bytes that are not MAVLink (or of no known type, or fail its checksum) are dropped (counted)",
        )

    def _say_dropped(self) -> None:
        """Each reason app.io.mavlink dropped a message for, said the first time."""
        for reason in list(self.telemetry.counts.dropped):
            self.messages.add_once(
                f"mavlink-dropped:{reason}", f"{self.address}: {reason}: dropped (counted)"
            )
