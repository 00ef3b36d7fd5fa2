"""The receiver thread of a live feed: opens the stream through the FFmpeg inside PyAV, records
every packet first (app.live.recorder), decodes the video into the jitter buffer and reads the
KLV sets into the growing track and the forward-only poses.

Time stamps: each packet is stamped with the monotonic clock when the demuxer hands it over (its
arrival in geofuse); media times are the stream's presentation times less the first video
packet's (app.io.video.media_seconds), the KLV's on the same clock.

Faults are said once each and counted, and none ends the thread: a packet FFmpeg cannot decode
(lost or corrupt datagrams), a KLV set failing its checksum, a stream that cannot be opened or
drops (reconnect with back-off: 0.5 s doubling to 8 s), a port already in use. Between attempts
to open a udp:// URL its port is listened to (app.live.probe): datagrams arriving that FFmpeg
could not open are counted and said as such (and what they look like), not as silence. A URL
whose port is not a port is refused at start (said, never tried).
"""

from __future__ import annotations

import ctypes
import functools
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

import av

from app.core.messages import Messages
from app.io.klv_track import KlvTrack, klv_streams
from app.io.streams import MAX_SPEED_MPS
from app.io.video import demux, ffmpeg_reason, media_seconds
from app.live.buffer import Arrival, JitterBuffer
from app.live.pose import LivePoses
from app.live.probe import MPEG_TS, Heard, listen, stream_refusal
from app.live.recorder import Recorder
from app.playback.decoder import yuv_planes

SCHEMES = ("udp", "rtp", "rtsp", "srt", "tcp", "http", "https", "file")
OPEN_TIMEOUT_S = 5.0
READ_TIMEOUT_S = 2.0
BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
LISTEN_MIN_S = 1.0  # a udp:// port FFmpeg could not open is listened to at least this long (s)
UDP_FIFO_PACKETS = 50_000  # FFmpeg's UDP ring (188-byte units): about 9 MB, seconds of 1080p


def stream_url(url: str) -> str:
    """The URL as FFmpeg should open it: UDP gets a large receive ring that does not stop the
    stream when it overruns, and reuses the address (so that two viewers can share a multicast
    group); other URLs are left as given."""
    parts = urlsplit(url)
    if parts.scheme != "udp":
        return url
    query = dict(parse_qsl(parts.query))
    query.setdefault("fifo_size", str(UDP_FIFO_PACKETS))
    query.setdefault("overrun_nonfatal", "1")
    return urlunsplit(parts._replace(query=urlencode(query)))


@functools.cache
def protocols_available() -> frozenset[str]:
    """The input protocols of the FFmpeg inside PyAV (avio_enum_protocols through ctypes: PyAV
    does not list them); empty where its libavformat cannot be found."""
    here = Path(av.__file__).resolve().parent
    names: set[str] = set()
    for lib in sorted(here.parent.glob("av.libs/libavformat*")) or sorted(here.glob("*avformat*")):
        try:
            enum = ctypes.CDLL(str(lib)).avio_enum_protocols
        except (OSError, AttributeError):
            continue
        enum.restype = ctypes.c_char_p
        enum.argtypes = [ctypes.POINTER(ctypes.c_void_p), ctypes.c_int]
        opaque = ctypes.c_void_p(None)
        while (name := enum(ctypes.byref(opaque), 0)) is not None:
            names.add(name.decode())
        break
    return frozenset(names)


def protocols_missing(url: str) -> str | None:
    """What this FFmpeg cannot open (its build lacks the URL's protocol), said before trying;
    None when it can, or when it cannot tell."""
    scheme = urlsplit(url).scheme
    have = protocols_available()
    if not scheme or not have:
        return None
    if _reads(scheme, have):
        return None
    readable = ", ".join(s for s in SCHEMES if _reads(s, have))
    return f"{url}: the FFmpeg inside PyAV was built without {scheme}:// (it reads {readable})"


def _reads(scheme: str, have: frozenset[str]) -> bool:
    if scheme == "rtsp":
        return "rtsp" in av.formats_available  # a demuxer over tcp/udp, not a protocol
    if scheme == "srt":
        return "libsrt" in have or "srt" in have
    return scheme in have


def _reason(exc: BaseException, timeout: str) -> str:
    """FFmpeg's words for a failure, with its interrupt on a timeout said as what it means."""
    reason = ffmpeg_reason(exc)
    return timeout if "exit requested" in reason.lower() else reason


@dataclass
class ReceiverCounts:
    """What arrived and what went wrong (the network's faults and the stream's)."""

    frames: int = 0  # decoded video frames handed to the buffer
    missing: int = 0  # frames the presentation times skip: lost on the way (the network's)
    undecodable: int = 0  # packets FFmpeg could not decode (lost or corrupt datagrams)
    connects: int = 0
    failed_opens: int = 0
    refused: str | None = None  # why the URL was refused at start (never tried)
    unreadable: Heard = field(default_factory=Heard)  # datagrams heard that FFmpeg could not open


class Receiver:
    """Receives `url` on a daemon thread until `stop`; see the module docstring."""

    def __init__(
        self,
        url: str,
        buffer: JitterBuffer,
        poses: LivePoses,
        messages: Messages,
        recorder: Recorder | None = None,
        clock: Callable[[], float] = time.monotonic,
        on_frame: Callable[[float, object], None] | None = None,
        poses_elsewhere: bool = False,
        read_timeout_s: float = READ_TIMEOUT_S,
    ) -> None:
        """on_frame(t, luma): each decoded frame's media time (s) and luma plane, on this
        thread (the MAVLink lag estimator's feed); poses_elsewhere: the poses come from another
        feed (MAVLink), so a video without KLV is not said to have none; read_timeout_s: a read
        waiting longer than this (s) ends the connection, and it is opened again."""
        self.url = url
        self.read_timeout_s = read_timeout_s
        self.on_frame = on_frame
        self.poses_elsewhere = poses_elsewhere
        self.buffer = buffer
        self.poses = poses
        self.messages = messages
        self.recorder = recorder
        self.clock = clock
        self.track = KlvTrack(url)
        self.counts = ReceiverCounts()
        self.size: tuple[int, int] | None = None  # the video's (w, h) once known
        self.last_arrival_s: float | None = None
        self.lock = threading.Lock()  # guards buffer pushes against the drawing thread
        self._origin: float | None = None
        self._last_pts: float | None = None
        self._steps: deque[float] = deque(maxlen=31)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-live", daemon=True)

    def start(self) -> Receiver:
        """The thread started; a URL whose port is not a port is refused instead (said as an
        error, counts.refused set, nothing tried)."""
        refused = stream_refusal(self.url)
        if refused is not None:
            self.counts.refused = refused
            self.messages.error(refused)
            return self
        missing = protocols_missing(self.url)
        if missing:
            self.messages.add(missing)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(timeout_s)

    @property
    def origin_s(self) -> float | None:
        """The stream-clock seconds of media time 0 (its first time stamp), None before it."""
        return self._origin

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        attempt = 0
        while not self._stop.is_set():
            try:
                container = av.open(
                    stream_url(self.url),
                    timeout=(OPEN_TIMEOUT_S, self.read_timeout_s),
                    options={"analyzeduration": "200000", "probesize": "500000"},
                )
            except (av.FFmpegError, OSError) as exc:
                self.counts.failed_opens += 1
                self._failed_open(exc, BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)])
                attempt += 1
                continue
            attempt = 0
            self.counts.connects += 1
            if self.counts.connects > 1:
                self.messages.info(f"{self.url}: reconnected ({self.counts.connects - 1} so far)")
            with container:
                self._receive(container)
            if not self._stop.is_set():
                self.messages.add_once("drop", f"{self.url}: the stream dropped; reconnecting")

    def _failed_open(self, exc: BaseException, wait_s: float) -> None:
        """An open that failed, said once, then the back-off (wait_s, s): a udp:// port is
        listened to meanwhile, and datagrams heard there that FFmpeg could not open are said
        as such rather than as FFmpeg's "nothing arrived" (its probe waits for more)."""
        reason = _reason(exc, f"nothing arrived within {OPEN_TIMEOUT_S:g} s")
        in_use = "in use" in reason.lower()
        heard = None if in_use else listen(self.url, max(wait_s, LISTEN_MIN_S), self._stop)
        if heard is not None and heard.datagrams and MPEG_TS not in heard.kinds:
            self.counts.unreadable.merge(heard)
            self.messages.add_once(
                "unreadable", f"{self.url}: {heard.unreadable()}; still listening"
            )
            return
        if in_use:
            reason += " (another program holds the port: choose another, or stop it)"
        self.messages.add_once("open", f"{self.url}: cannot open the stream ({reason}); retrying")
        if heard is None:
            self._stop.wait(wait_s)

    def _receive(self, container) -> None:
        video = container.streams.video[0] if container.streams.video else None
        klvs = klv_streams(container)
        klv = klvs[0] if klvs else None
        if video is None:
            self.messages.add_once("novideo", f"{self.url}: no video stream in the feed")
            return
        if klv is None and not self.poses_elsewhere:
            self.messages.add_once(
                "noklv", f"{self.url}: no KLV data stream: the video has no pose of its own"
            )
        if self.recorder is not None:
            self.recorder.add_input(video, klv, self.poses_elsewhere)
        codec = video.codec_context
        codec.thread_type = "SLICE"  # frame threads would hold frames back: latency
        wanted = [s for s in (video, klv) if s is not None]
        try:
            for packet in demux(container, *wanted):
                if self._stop.is_set():
                    return
                if packet.pts is None and packet.dts is None and not packet.size:
                    continue
                now = self.clock()
                self.last_arrival_s = now
                kind = "video" if packet.stream is video else "klv"
                if self.recorder is not None:
                    self.recorder.write(packet, kind)
                if kind == "klv":
                    self._klv(packet)
                else:
                    self._video(codec, packet, now)
        except av.FFmpegError as exc:
            if not self._stop.is_set():
                reason = _reason(exc, f"nothing arrived for {self.read_timeout_s:g} s")
                self.messages.add_once("read", f"{self.url}: reading stopped ({reason})")

    def _media(self, pts: int | None, time_base) -> float | None:
        if pts is None:
            return None
        if self._origin is None:
            self._origin = float(pts * time_base)
        return media_seconds(pts, time_base, self._origin)

    def _count_missing(self, t: float) -> None:
        """Frames skipped between this one and the last (by the median frame interval)."""
        last = self._last_pts
        self._last_pts = t
        if last is None or t <= last:
            return
        self._steps.append(t - last)
        step = sorted(self._steps)[len(self._steps) // 2]
        gap = round((t - last) / step) - 1 if step > 0 else 0
        if 0 < gap < 300:
            self.counts.missing += gap

    def _klv(self, packet) -> None:
        payload = bytes(packet)
        t = self._media(packet.pts, packet.time_base)
        bad, jumps = self.track.counts.bad, self.poses.jumps
        for s in self.track.add(payload, t):
            self.poses.add(t, s)
        if self.poses.jumps > jumps:
            self.messages.add_once(
                "klv-jump",
                f"{self.url}: KLV positions no aircraft could reach from the set before"
                f" (faster than {MAX_SPEED_MPS:g} m/s) are not followed (counted)",
            )
        if self.track.counts.bad > bad:
            self.messages.add_once(
                "klv-bad", f"{self.url}: KLV sets failing their checksum are dropped (counted)"
            )

    def _video(self, codec, packet, arrival: float) -> None:
        try:
            frames = codec.decode(packet)
        except av.FFmpegError:
            self.counts.undecodable += 1
            self.messages.add_once(
                "undecodable",
                f"{self.url}: video packets that cannot be decoded (lost or corrupt datagrams) are skipped (counted)",
            )
            return
        for frame in frames:
            t = self._media(frame.pts, frame.time_base or packet.time_base)
            if t is None:
                continue
            self.size = (frame.width, frame.height)
            self._count_missing(t)
            item = Arrival(t, arrival, yuv_planes(frame))
            self.counts.frames += 1
            with self.lock:
                self.buffer.push(item)
            if self.on_frame is not None:
                self.on_frame(t, item.payload[0])
