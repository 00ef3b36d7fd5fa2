"""What arrives, kept as MPEG-TS before anything else reads it: the stream's packets copied (no
re-encoding), video and KLV, in the order they came. A transport stream has no index or trailer
to write at the end, and every packet is handed to the file system as it is muxed (through a
small buffer), so a recording stays playable when the process is killed mid-flight."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av

WRITE_BUFFER = 188 * 7  # bytes FFmpeg gathers before it hands them to the file: one datagram
SEGMENT_S = 60.0  # the viewer's rolling recording: a new file every minute, at a keyframe


class Recorder:
    """Copies packets from an input container's video and KLV streams into `path`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._out = av.open(self._file, "w", format="mpegts", buffer_size=WRITE_BUFFER)
        self._streams: dict[str, object] = {}
        self.packets = 0
        self.errors = 0

    def add_input(self, video_stream, klv_stream, poses_written: bool = False) -> None:
        """The input's streams (again after a reconnect: the output streams are kept);
        poses_written: a KLV stream even when the input has none, for `write_set` (a MAVLink
        flight's poses, so that its recording is a clip with poses)."""
        if "video" not in self._streams and video_stream is not None:
            self._streams["video"] = self._out.add_stream_from_template(video_stream)
        if "klv" not in self._streams and (klv_stream is not None or poses_written):
            self._streams["klv"] = self._out.add_data_stream("klv")

    def write_set(self, payload: bytes, stream_s: float) -> None:
        """One Local Set at stream-clock second stream_s (the video's own clock)."""
        out = self._streams.get("klv")
        if out is None:
            return
        packet = av.Packet(payload)
        packet.stream, packet.time_base = out, Fraction(1, 90000)
        packet.pts = packet.dts = int(round(stream_s * 90000))
        try:
            self._out.mux(packet)
            self.packets += 1
        except (av.FFmpegError, ValueError):
            self.errors += 1
        self._file.flush()

    def write(self, packet, kind: str) -> None:
        """A copy of one demuxed packet of the input's `kind` stream ('video' or 'klv'); the
        packet itself is left as it was for the decoder."""
        out = self._streams.get(kind)
        if out is None or packet.pts is None and packet.dts is None:
            return
        copy = av.Packet(bytes(packet))
        copy.pts, copy.dts, copy.time_base = packet.pts, packet.dts, packet.time_base
        copy.is_keyframe = packet.is_keyframe
        copy.stream = out
        try:
            self._out.mux(copy)
            self.packets += 1
        except (av.FFmpegError, ValueError):
            self.errors += 1  # a packet FFmpeg refuses (times going back after a reconnect)
        self._file.flush()

    def close(self) -> None:
        try:
            self._out.close()
        except (av.FFmpegError, ValueError):
            pass
        self._file.close()


@dataclass
class Segment:
    """One recorded file and the span of stream-clock seconds (pts x time base) its video
    packets cover."""

    path: Path
    first_s: float | None = None
    last_s: float | None = None


class SegmentRecorder:
    """Recording in rolling segments (the viewer records every stream it opens): a new MPEG-TS
    in `folder` starts at the first video keyframe SEGMENT_S after the current one began, so
    that each segment is a clip of its own (none is ever deleted: a recording can be evidence).
    `segments` says which file holds which stretch of the stream, for scrubbing back."""

    def __init__(self, folder: str | Path, segment_s: float = SEGMENT_S) -> None:
        self.folder = Path(folder)
        self.segment_s = segment_s
        self.segments: list[Segment] = []
        self._inputs: tuple = (None, None, False)
        self._current: Recorder | None = None
        self.packets = self.errors = 0
        self._lock = threading.Lock()

    def add_input(self, video_stream, klv_stream, poses_written: bool = False) -> None:
        self._inputs = (video_stream, klv_stream, poses_written)
        if self._current is not None:
            self._current.add_input(video_stream, klv_stream, poses_written)

    def write_set(self, payload: bytes, stream_s: float) -> None:
        if self._current is not None:
            self._current.write_set(payload, stream_s)

    def _open(self) -> Recorder:
        path = self.folder / f"segment-{len(self.segments) + 1:04d}.ts"
        rec = Recorder(path)
        rec.add_input(*self._inputs)
        with self._lock:
            self.segments.append(Segment(path))
        return rec

    def write(self, packet, kind: str) -> None:
        t = None
        if kind == "video" and packet.pts is not None and packet.time_base is not None:
            t = float(packet.pts * packet.time_base)
        cur = self.segments[-1] if self.segments else None
        if self._current is None or (
            kind == "video"
            and packet.is_keyframe
            and t is not None
            and cur.first_s is not None
            and t - cur.first_s >= self.segment_s
        ):
            if self._current is not None:
                self._current.close()
            self._current = self._open()
            cur = self.segments[-1]
        self._current.write(packet, kind)
        self.packets += 1
        if t is not None:
            with self._lock:
                cur.first_s = t if cur.first_s is None else min(cur.first_s, t)
                cur.last_s = t if cur.last_s is None else max(cur.last_s, t)

    def span_s(self) -> tuple[float, float] | None:
        """(first, last) stream-clock seconds of the video recorded so far, None before any."""
        with self._lock:
            spans = [(s.first_s, s.last_s) for s in self.segments if s.first_s is not None]
        return (spans[0][0], max(last for _, last in spans)) if spans else None

    def holding(self, stream_s: float) -> Segment | None:
        """The segment whose video covers stream-clock second stream_s (the nearest one)."""
        with self._lock:
            spans = [s for s in self.segments if s.first_s is not None]
        if not spans:
            return None
        for s in spans:
            if s.first_s <= stream_s <= s.last_s:
                return s
        return min(spans, key=lambda s: min(abs(s.first_s - stream_s), abs(s.last_s - stream_s)))

    def close(self) -> None:
        if self._current is not None:
            self._current.close()
            self._current = None
