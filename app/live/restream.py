"""`geofuse live URL --restream udp://HOST:PORT`: the received video sent on as MPEG-TS over UDP,
with a MISB ST 0601 KLV data stream whose sets carry the pose geofuse drew each frame with: the
registered one where live registration has corrected it (app.live.register), the platform's
otherwise, and which in the set itself (item 98, a Geo-Registration Local Set, only on a
registered pose: app.export.klv, whose `pose_items` `export klv` writes for files too). Downstream
FMV tools (ArcGIS Pro FMV, the QGIS FMV plugin, TAK's player) draw their footprint from it.

What is sent. The video packets are the received ones, copied (not re-encoded), with their own
time stamps (FFmpeg's MPEG-TS muxer adds an access unit delimiter to an H.264 packet that lacks
one, as the recorder's does); the received KLV is not sent on: it stays in the recording
(app.live.recorder). Each set holds the sensor's place (latitude, longitude, ellipsoidal and
sea-level heights), the optical axis (as `export klv` maps it: platform heading, sensor relative
elevation and roll), both fields of view, and the platform's naming items passed on from the
latest received set (PASSED_ON); not the frame centre or corners, which the drawing loop does not
cast. Its Precision Time Stamp is on the platform's clock: the latest received set's stamp less
its presentation time, plus the frame's (without received stamps: the wall clock at arrival).

Order. A video packet is held until the frame it belongs to has been drawn, then sent, followed by
that frame's set at the frame's presentation time, so that downstream a set never trails its frame
by more than the frame after it; a frame geofuse does not draw (dropped by the jitter buffer, or
without a pose) is sent without a set once HOLD_S of later video has arrived.

Never in the way. The receiver thread (through `Tee`, after the recorder) and the drawing loop
(`pose`) only hand over to a bounded queue (QUEUE_ITEMS; past it an item is dropped, counted and
said once); one thread of its own muxes and sends datagrams of seven TS packets. A target that
cannot be reached (no route; nothing listening, which a connected socket hears as the port being
unreachable) or a host that cannot be resolved is said once and counted, and the run goes on.
"""

from __future__ import annotations

import io
import math
import queue
import socket
import time
from collections import deque
from dataclasses import dataclass
from fractions import Fraction
from urllib.parse import parse_qsl, urlsplit

import av
import numpy as np

from app.camera.pinhole import Camera
from app.core.messages import Messages
from app.core.worker import Worker
from app.export.klv import pose_items
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.misb import KlvError, local_set, parse, split
from app.live.probe import stream_refusal

QUEUE_ITEMS = 1024  # packets and poses waiting for the restream thread (tens of seconds of a feed)
HOLD_S = 1.0  # a frame without a pose is sent without a set once this much later video arrived (s)
TS_PACKET = 188
DATAGRAM_BYTES = 7 * TS_PACKET  # what MPEG-TS over UDP sends per datagram
SEND_TIMEOUT_S = 0.5
KLV_TIME_BASE = Fraction(1, 90000)
TTL_RANGE = (1, 255)
# passed on from the received sets: Mission ID, Platform Tail Number, Platform Designation, Image
# Source Sensor, Platform Call Sign (what names the flight; no pose in them)
PASSED_ON = (3, 4, 10, 11, 59)
FORM = "udp://HOST:PORT"


def restream_refusal(url: str) -> str | None:
    """Why `url` cannot be a restream target (not udp://, no host, a port that is not a port, a
    query other than ttl=1..255), said before anything is sent; None when it can."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "udp":
        return f"--restream {url}: the restream is MPEG-TS over UDP (expected {FORM})"
    refused = stream_refusal(url)
    if refused is not None:
        return f"--restream {refused}"
    if not parts.hostname:
        return f"--restream {url}: no host to send to (expected {FORM})"
    for key, value in parse_qsl(parts.query, keep_blank_values=True):
        ttl = value.isascii() and value.isdigit() and TTL_RANGE[0] <= int(value) <= TTL_RANGE[1]
        if key != "ttl" or not ttl:
            return f"--restream {url}: {key}={value!r} is not understood (expected {FORM}, or ?ttl=1..255 for a multicast group)"
    return None


@dataclass
class RestreamCounts:
    """What the restream sent and lost: KLV sets (and of them those with the registered pose),
    video packets, items the queue had no room for, packets the muxer refused (times going back
    after a reconnect), datagrams and those the network refused; `failed`: why nothing could be
    sent at all (the host did not resolve)."""

    url: str
    sets: int = 0
    registered: int = 0
    video: int = 0
    dropped: int = 0
    refused: int = 0
    datagrams: int = 0
    unsent: int = 0
    failed: str | None = None

    def line(self) -> str:
        """The summary's part: `restreamed to URL: N KLV sets sent (M with the registered pose)`."""
        if self.failed is not None:
            return f"restream to {self.url}: nothing sent ({self.failed})"
        parts = [
            f"{self.sets} KLV sets sent ({self.registered} with the registered pose)",
            f"{self.video} video packets",
        ]
        if self.dropped:
            parts.append(f"{self.dropped} dropped (the restream fell behind)")
        if self.refused:
            parts.append(f"{self.refused} refused by the muxer")
        if self.unsent:
            parts.append(f"{self.unsent} of {self.datagrams} datagrams not delivered")
        return f"restreamed to {self.url}: " + ", ".join(parts)


@dataclass(frozen=True)
class _Video:
    """A received video packet's bytes and times (in its time base), and its stream-clock s."""

    data: bytes
    pts: int | None
    dts: int | None
    time_base: Fraction
    keyframe: bool
    t_s: float


@dataclass(frozen=True)
class _Klv:
    """A received KLV packet's payload at stream-clock second t_s (None: no PTS)."""

    payload: bytes
    t_s: float | None


@dataclass(frozen=True)
class _Pose:
    """The pose a frame was drawn with: its presentation time (stream-clock s), the camera (in
    `frame`'s ENU; immutable, so handed over as it is) and whether registration corrected it."""

    t_s: float
    frame: LocalFrame
    camera: Camera
    registered: bool


class _Datagrams(io.RawIOBase):
    """What the muxer writes (whole TS packets, at most DATAGRAM_BYTES at a time: its buffer
    size), handed to `send` as datagrams."""

    def __init__(self, send) -> None:
        super().__init__()
        self._send = send

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        data = bytes(b)
        for i in range(0, len(data), DATAGRAM_BYTES):
            self._send(data[i : i + DATAGRAM_BYTES])
        return len(data)


class Tee:
    """Packet sinks the receiver feeds (add_input, write), in turn: the recorder first, so that
    what arrives is kept before anything else reads it."""

    def __init__(self, *sinks) -> None:
        self.sinks = [s for s in sinks if s is not None]

    def add_input(self, video_stream, klv_stream, poses_written: bool = False) -> None:
        for s in self.sinks:
            s.add_input(video_stream, klv_stream, poses_written)

    def write(self, packet, kind: str) -> None:
        for s in self.sinks:
            s.write(packet, kind)


def _why(exc: OSError) -> str:
    if isinstance(exc, ConnectionRefusedError):
        return "nothing listens there: the port is unreachable"
    return exc.strerror or type(exc).__name__


class Restreamer(Worker):
    """Sends the feed on to `url` (see the module docstring) from its own thread until `stop`;
    `counts` says what went."""

    def __init__(self, url: str, messages: Messages) -> None:
        self.url, self.messages = url, messages
        self.counts = RestreamCounts(url)
        self._queue: queue.Queue = queue.Queue(QUEUE_ITEMS)
        self._sock: socket.socket | None = None
        self._address: tuple | None = None  # where to send, when the socket is not connected
        self._out = av.open(
            _Datagrams(self._send),
            "w",
            format="mpegts",
            buffer_size=DATAGRAM_BYTES,
            options={"max_interleave_delta": "1"},  # a packet goes out without waiting for a set
        )
        self._video_out = self._klv_out = None
        self._held: deque[_Video] = deque()
        self._utc_offset: float | None = None  # platform UTC s - stream-clock s
        self._arrival_offset: float | None = None  # wall-clock UTC s - stream-clock s
        self._passed_on: list[tuple[int, bytes]] = []
        self._last_set_ticks = -1
        super().__init__("geofuse-restream")

    # --- handed over (the receiver's thread, the drawing loop): never waits ----------------------

    def _put(self, item: object) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.counts.dropped += 1
            self.messages.add_once(
                "restream-full",
                f"--restream {self.url}: the restream fell behind; what it had no room for is dropped (counted)",
            )

    def add_input(self, video_stream, klv_stream, poses_written: bool = False) -> None:
        """The input's streams (again after a reconnect: the output streams are kept)."""
        if self._video_out is None and video_stream is not None:
            self._video_out = self._out.add_stream_from_template(video_stream)
            self._klv_out = self._out.add_data_stream("klv")

    def write(self, packet, kind: str) -> None:
        """A copy of one demuxed packet ('video' or 'klv'), handed to the restream thread."""
        if packet.pts is None and packet.dts is None or packet.time_base is None:
            return
        tb = Fraction(packet.time_base)
        if kind == "klv":
            self._put(_Klv(bytes(packet), None if packet.pts is None else float(packet.pts * tb)))
            return
        t = packet.dts if packet.dts is not None else packet.pts
        self._put(
            _Video(
                bytes(packet), packet.pts, packet.dts, tb, bool(packet.is_keyframe), float(t * tb)
            )
        )

    def pose(self, stream_s: float, frame: LocalFrame, camera: Camera, registered: bool) -> None:
        """The pose a frame was drawn with (its presentation time on the stream's clock, s; the
        camera in `frame`'s ENU; registered: corrected by live registration)."""
        self._put(_Pose(stream_s, frame, camera, registered))

    # --- the restream thread --------------------------------------------------------------------

    def _run(self) -> None:
        self._sock = self._connect()
        try:
            while True:
                try:
                    item = self._queue.get(timeout=0.1)
                except queue.Empty:
                    if self._stop.is_set():
                        break
                    continue
                if self._sock is not None and self._video_out is not None:
                    self._take(item)
            if self._sock is not None:
                self._release(math.inf)
        finally:
            try:
                self._out.close()
            except (av.FFmpegError, ValueError, OSError):
                pass
            if self._sock is not None:
                self._sock.close()

    def _connect(self) -> socket.socket | None:
        """A UDP socket connected to the target (so that an unreachable port is heard; where
        it cannot connect, sending to it instead), None when its host cannot be resolved
        (said)."""
        parts = urlsplit(self.url)
        ttl = dict(parse_qsl(parts.query)).get("ttl")
        try:
            family, kind, proto, _, address = socket.getaddrinfo(
                parts.hostname, parts.port, type=socket.SOCK_DGRAM
            )[0]
            sock = socket.socket(family, kind, proto)
        except OSError as exc:
            self.counts.failed = f"cannot resolve {parts.hostname}: {_why(exc)}"
            self.messages.add(f"--restream {self.url}: {self.counts.failed}; nothing is sent")
            return None
        sock.settimeout(SEND_TIMEOUT_S)
        if ttl is not None:
            level, option = (
                (socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS)
                if family == socket.AF_INET6
                else (socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)
            )
            sock.setsockopt(level, option, int(ttl))
        try:
            sock.connect(address)
        except OSError as exc:  # no route now: said, and tried again with each datagram
            self._unsent(exc)
            self._address = address
        return sock

    def _send(self, data: bytes) -> None:
        if self._sock is None:
            return
        self.counts.datagrams += 1
        try:
            if self._address is None:
                self._sock.send(data)
            else:
                self._sock.sendto(data, self._address)
        except OSError as exc:
            self.counts.unsent += 1
            self._unsent(exc)

    def _unsent(self, exc: OSError) -> None:
        self.messages.add_once(
            "restream-send",
            f"--restream {self.url}: cannot send ({_why(exc)}); still sending, the run goes on (counted)",
        )

    def _take(self, item: object) -> None:
        if isinstance(item, _Video):
            if self._arrival_offset is None:
                self._arrival_offset = time.time() - item.t_s
            self._held.append(item)
            self._release(item.t_s - HOLD_S)
        elif isinstance(item, _Klv):
            self._read_klv(item)
        elif isinstance(item, _Pose):
            self._release(item.t_s + 1e-6)
            self._send_set(item)

    def _release(self, until_s: float) -> None:
        """The held video packets up to stream-clock second until_s muxed, in the order they
        came."""
        while self._held and self._held[0].t_s <= until_s:
            v = self._held.popleft()
            packet = av.Packet(v.data)
            packet.pts, packet.dts, packet.time_base = v.pts, v.dts, v.time_base
            packet.is_keyframe = v.keyframe
            packet.stream = self._video_out
            self.counts.video += self._mux(packet)

    def _mux(self, packet: av.Packet) -> bool:
        try:
            self._out.mux(packet)
        except (av.FFmpegError, ValueError):
            self.counts.refused += 1  # times going back (a reconnect, an encoder's restart)
            return False
        return True

    def _read_klv(self, item: _Klv) -> None:
        """The platform's clock (UTC - stream clock) and naming items from a received packet."""
        for raw in split(item.payload):
            try:
                s = parse(raw)
            except KlvError:
                continue
            if s.time_us and item.t_s is not None:
                self._utc_offset = s.time_us / 1e6 - item.t_s
            named = [(tag, s.other[tag]) for tag in PASSED_ON if tag in s.other]
            if named:
                self._passed_on = named

    def _send_set(self, p: _Pose) -> None:
        ticks = int(round(p.t_s / KLV_TIME_BASE))
        if ticks <= self._last_set_ticks:  # a frame drawn again (its times go back): one set
            return
        lat, lon, h = (float(v) for v in p.frame.enu_to_geodetic(np.asarray(p.camera.position)))
        msl = h - float(undulation(lat, lon))
        q = np.asarray(p.camera.orientation, np.float64)[None]
        hpr = tuple(float(a) for a in rotations.hpr_from_camera_quat(q)[0])
        fov = (p.camera.intrinsics.hfov_deg, p.camera.intrinsics.vfov_deg)
        offset = self._utc_offset if self._utc_offset is not None else self._arrival_offset
        utc = p.t_s + (offset if offset is not None else time.time() - p.t_s)
        items = pose_items(utc, (lat, lon, h), msl, hpr, fov, p.registered)
        packet = av.Packet(local_set(items + self._passed_on))
        packet.stream, packet.time_base = self._klv_out, KLV_TIME_BASE
        packet.pts = packet.dts = ticks
        if self._mux(packet):
            self._last_set_ticks = ticks
            self.counts.sets += 1
            self.counts.registered += p.registered
