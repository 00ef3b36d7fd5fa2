"""A live feed's addresses and what arrives at them, for saying plainly what is wrong.

- A port that is not a port (`notaport`, 99999999, -5, 0) is refused before anything listens
  (`stream_refusal` for the video's URL, `mavlink_refusal` for a pymavlink connection): it can
  never open, so retrying it until `--for` ends would only hide the typing mistake.
- A UDP port whose datagrams FFmpeg cannot open as MPEG-TS is listened to between the attempts
  (`listen`): what arrives is counted (datagrams, bytes) and named by what it looks like
  (MPEG-TS, RTP, MAVLink, bare KLV, unknown), so that a feed of garbage is not called silence.
"""

from __future__ import annotations

import ipaddress
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from pymavlink import mavutil

from app.io.misb import EG0104_KEY, is_key

PORTS = (1, 65535)
NEEDS_PORT = ("udp", "rtp", "srt", "tcp")  # URL schemes without a default port
MAVLINK_NETWORK = ("udp", "udpin", "udpout", "udpbcast", "tcp", "tcpin")  # pymavlink's HOST:PORT
TS_PACKET, TS_SYNC = 188, 0x47
RTP_HEADER = 12
MAX_DATAGRAM = 65_535
POLL_S = 0.1  # how often a listener looks at its stop event (s)

MPEG_TS, RTP, MAVLINK, KLV, UNKNOWN = (
    "MPEG-TS",
    "RTP",
    "MAVLink",
    "bare KLV",
    "unknown",
)
HINTS = {
    RTP: "they are RTP: open rtp://HOST:PORT instead",
    MAVLINK: "they are MAVLink telemetry: give that port to --mavlink udp:HOST:PORT",
    KLV: "they are bare KLV sets, not carried in MPEG-TS beside a video",
}


def _port_refusal(where: str, port: str, form: str) -> str | None:
    """Why `port` (as typed) is not a port, None when it is one."""
    if port.isascii() and port.isdigit() and PORTS[0] <= int(port) <= PORTS[1]:
        return None
    return f"{where}: {port!r} is not a port (expected a whole number from {PORTS[0]} to {PORTS[1]}: {form})"


def stream_refusal(url: str) -> str | None:
    """Why a stream URL can never be opened for its port (not a number, out of range, missing
    where the scheme has no default), said before trying; None when its port is fine."""
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    host = parts.netloc.rpartition("@")[2]
    form = f"{scheme}://HOST:PORT"
    _, sep, port = host.rpartition(":")
    if not sep or host.endswith("]"):  # no port (an IPv6 literal's colons are not one)
        return f"{url}: no port (expected {form})" if scheme in NEEDS_PORT else None
    return _port_refusal(url, port, form)


def mavlink_refusal(address: str) -> str | None:
    """Why a pymavlink network connection (udp:HOST:PORT, udpin:, udpout:, udpbcast:, tcp:,
    tcpin:) can never open for its port; None when it is fine or not a network connection (a
    serial device, a log file: pymavlink says what is wrong with those)."""
    prefix, sep, rest = address.partition(":")
    if not sep or prefix.lower() not in MAVLINK_NETWORK:
        return None
    form = f"{prefix}:HOST:PORT"
    host, sep, port = rest.rpartition(":")
    if not sep or ":" in host:
        return f"{address}: expected {form}"
    return _port_refusal(address, port, form)


def datagram_kind(data: bytes) -> str:
    """What a datagram looks like: MPEG-TS (whole 188-byte packets, each beginning 0x47), RTP
    carrying them, MAVLink (a message pymavlink reads), bare KLV (a UAS Datalink or EG 0104
    key first), else unknown."""

    def ts(d: bytes) -> bool:
        return bool(d) and len(d) % TS_PACKET == 0 and all(b == TS_SYNC for b in d[::TS_PACKET])

    if ts(data):
        return MPEG_TS
    if len(data) > RTP_HEADER and data[0] >> 6 == 2 and ts(data[RTP_HEADER:]):
        return RTP
    if is_key(data) or is_key(data, key=EG0104_KEY):
        return KLV
    if data[:1] in (b"\xfd", b"\xfe"):  # a message of a known type read at its start
        dialect = mavutil.mavlink  # (pymavlink may switch it to MAVLink 2 meanwhile)
        parser = dialect.MAVLink(None)
        parser.robust_parsing = True
        try:
            first = (parser.parse_buffer(data) or [None])[0]
        except dialect.MAVError:
            first = None
        kind = first.get_type() if first is not None else "BAD_DATA"
        if kind != "BAD_DATA" and not kind.startswith("UNKNOWN"):
            return MAVLINK
    return UNKNOWN


@dataclass
class Heard:
    """Datagrams heard on a port: how many, their bytes, and what they looked like (kind ->
    count)."""

    datagrams: int = 0
    bytes: int = 0
    kinds: dict[str, int] = field(default_factory=dict)

    def add(self, data: bytes) -> str:
        """One datagram counted; its kind."""
        kind = datagram_kind(data)
        self.datagrams += 1
        self.bytes += len(data)
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        return kind

    def merge(self, other: Heard) -> None:
        self.datagrams += other.datagrams
        self.bytes += other.bytes
        for k, n in other.kinds.items():
            self.kinds[k] = self.kinds.get(k, 0) + n

    def unreadable(self) -> str:
        """What is said of datagrams none of which FFmpeg could open as MPEG-TS, with what
        most of them look like where it is something else."""
        most = max(self.kinds, key=self.kinds.__getitem__, default=UNKNOWN)
        hint = (
            f" ({HINTS[most]})" if most in HINTS and 2 * self.kinds[most] > self.datagrams else ""
        )
        return (
            f"{self.datagrams} datagrams ({self.bytes} bytes) arrived but none was readable as "
            f"MPEG-TS (expected {TS_PACKET}-byte packets beginning 0x{TS_SYNC:02X}: a video, with its MISB KLV){hint}"
        )


def _bound(url: str) -> socket.socket | None:
    """A UDP socket holding a udp:// URL's port as FFmpeg's reader holds it (any local address;
    a multicast group joined); None when the URL is not udp:// or the port cannot be had."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "udp" or stream_refusal(url) is not None or parts.port is None:
        return None
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        group = None
        try:
            group = ipaddress.ip_address(parts.hostname or "")
        except ValueError:
            pass
        if group is not None and group.version == 4 and group.is_multicast:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("", parts.port))
            mreq = struct.pack("4s4s", group.packed, socket.inet_aton("0.0.0.0"))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        else:
            sock.bind(("", parts.port))
    except OSError:
        sock.close()
        return None
    return sock


def listen(url: str, seconds: float, stop: threading.Event) -> Heard | None:
    """The datagrams arriving at a udp:// URL's port for `seconds` (s), ending early when
    `stop` is set or one looks like MPEG-TS (a stream begun: the caller reopens it at once);
    None when the URL is not udp:// or its port cannot be had (another program holds it)."""
    sock = _bound(url)
    if sock is None:
        return None
    heard = Heard()
    end = time.monotonic() + seconds
    with sock:
        while not stop.is_set() and (left := end - time.monotonic()) > 0:
            sock.settimeout(min(left, POLL_S))
            try:
                data = sock.recv(MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError:
                break
            if heard.add(data) == MPEG_TS:
                break
    return heard
