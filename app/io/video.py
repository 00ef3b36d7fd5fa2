"""Video metadata through PyAV: every frame's presentation time, frame rates, display rotation,
creation time. Decodes only the first frame (for its rotation side data); the rest is demuxing."""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import av
import numpy as np
import numpy.typing as npt

from app.core.errors import VideoError


@dataclass(frozen=True)
class VideoInfo:
    """pts_s: (N,) presentation times of the frames in display order, seconds from the stream's
    start; width/height: stored (coded) size; rotation_cw: the clockwise rotation a player applies
    for display (a phone's `rotate` tag: 90 for portrait upright); nominal_fps: the stream's
    declared rate; average_fps: frames / duration; creation_time: Unix seconds or None."""

    path: str
    pts_s: np.ndarray
    width: int
    height: int
    rotation_cw: int
    nominal_fps: float
    average_fps: float
    creation_time: float | None
    codec: str
    origin_s: float = 0.0  # the stream-clock seconds that are media time 0 (see media_seconds)
    declared_frames: int = 0  # frames the container's index announces (0: it does not say)
    corrupt_packets: int = 0  # video packets the demuxer found damaged (a transport stream's)
    undecodable_head: int = 0  # packets before the first frame that decodes, which do not
    junk_head_bytes: int = 0  # bytes before a transport stream's first packet (damaged)
    partial_packet_bytes: int = 0  # a transport stream's last packet, cut off after this many

    def note_damage(self, messages) -> None:
        """A warning when fewer frames can be read than the index announces (a file cut short
        with its index at the front): only the frames present are used; and one when packets
        arrived damaged or the first ones do not decode (a transport stream with bytes lost or
        flipped): what decodes is shown, the rest skipped."""
        name = Path(self.path).name
        if self.declared_frames > len(self.pts_s) + 1:
            messages.add(
                f"{name}: the video is cut short: {len(self.pts_s)} of the {self.declared_frames} frames its index announces can be read; only those are used"
            )
        if self.junk_head_bytes:
            messages.add(
                f"{name}: the transport stream's first {self.junk_head_bytes} bytes are not MPEG-TS packets (damaged): read from the first packet after them"
            )
        if self.partial_packet_bytes:
            messages.add(
                f"{name}: the transport stream ends {self.partial_packet_bytes} bytes into a packet: the file is cut short, what followed is lost"
            )
        if self.corrupt_packets or self.undecodable_head:
            lost = [
                f"{self.corrupt_packets} of {len(self.pts_s)} video packets arrive damaged"
                if self.corrupt_packets
                else "",
                f"the first {self.undecodable_head} packets do not decode"
                if self.undecodable_head
                else "",
            ]
            messages.add_once(
                f"video-damage:{self.path}",
                f"{name}: the video stream is damaged ({'; '.join(x for x in lost if x)}): frames that do not decode are skipped, the others shown",
            )

    @property
    def display_size(self) -> tuple[int, int]:
        return (
            (self.height, self.width)
            if self.rotation_cw in (90, 270)
            else (self.width, self.height)
        )

    @property
    def duration_s(self) -> float:
        return float(self.pts_s[-1] - self.pts_s[0]) if len(self.pts_s) else 0.0

    @property
    def variable_rate(self) -> bool:
        """True when frame intervals vary by more than 5 % (phones record variable frame rate)."""
        if len(self.pts_s) < 3:
            return False
        d = np.diff(self.pts_s)
        return bool(np.std(d) > 0.05 * np.mean(d))

    def eq5_times(self) -> np.ndarray:
        """The paper's Eq. 5 fallback: frame i at i / nominal_fps (constant rate)."""
        return np.arange(len(self.pts_s)) / self.nominal_fps


def media_seconds(pts: int, time_base, origin_s: float) -> float:
    """A packet's or frame's presentation timestamp as media seconds: pts x time_base on the
    stream's clock, less `origin_s` (the stream's start_time, or its first presentation time
    when the container gives none). The one conversion: the probe, the decoder thread and
    read_frame all use it, so a frame's media time is the same everywhere."""
    return float(pts * time_base) - origin_s


def stream_origin_s(stream, first_pts_s: float) -> float:
    """Media time 0 on the stream's clock: its start_time, else its first presentation time."""
    return (
        float(stream.start_time * stream.time_base)
        if stream.start_time is not None
        else float(first_pts_s)
    )


def _creation_time(meta: dict[str, str]) -> float | None:
    value = meta.get("creation_time") or meta.get("com.apple.quicktime.creationdate")
    if not value:
        return None
    try:
        return datetime.fromisoformat(value.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return None


# MPEG transport streams: read as such when FFmpeg's probe fails (a damaged start)
TS_SUFFIXES = (".ts", ".m2ts", ".mts")


def open_video(path: str | Path):
    """The PyAV input container of a video file. A transport stream (TS_SUFFIXES) whose start is
    damaged past FFmpeg's recognition is opened as MPEG-TS all the same (what follows may well
    decode); av.FFmpegError or OSError where it cannot be opened."""
    try:
        return av.open(str(path))
    except av.FFmpegError:
        if Path(path).suffix.lower() not in TS_SUFFIXES:
            raise
    return av.open(str(path), format="mpegts")


TS_SYNC = 0x47  # the first byte of every transport stream packet
TS_SCAN_BYTES = 1 << 20  # how far into a damaged transport stream its first packet is looked for


def ts_edges(path: Path) -> tuple[int, int]:
    """(bytes before its first packet, bytes into its last packet) of a transport stream
    (188-byte packets, or 192 with the Blu-ray time code first): where three sync bytes (0x47)
    first follow each other a packet apart in its first TS_SCAN_BYTES; (0, 0) where none do."""
    with path.open("rb") as f:
        head = f.read(TS_SCAN_BYTES)
    i = head.find(TS_SYNC)
    while 0 <= i < len(head) - 2 * 192:
        for size, sync in ((188, 0), (192, 4)):
            if i >= sync and all(head[i + k * size] == TS_SYNC for k in range(3)):
                return i - sync, (path.stat().st_size - i + sync) % size
        i = head.find(TS_SYNC, i + 1)
    return 0, 0


def demux(container, *streams) -> Iterator[av.Packet]:
    """container.demux(*streams), ending where PyAV's end-of-file flush meets a stream that
    appeared mid-file (a damaged transport stream whose tables name a stream it did not have at
    the start: PyAV 18 raises IndexError there, after the last packet has been read)."""
    packets = container.demux(*streams)
    while True:
        try:
            packet = next(packets)
        except (StopIteration, IndexError):
            return
        yield packet


@dataclass
class Undecodable:
    """Packets skipped because FFmpeg could not decode them (a damaged stream)."""

    packets: int = 0


def decode(container, stream, skipped: Undecodable | None = None) -> Iterator[av.VideoFrame]:
    """The frames of `stream` (in an open PyAV `container`) from where it stands, a packet that
    does not decode skipped (counted in `skipped`) rather than ending the stream; an error
    reading the file ends it (the frames read so far stand)."""
    packets = demux(container, stream)
    while True:
        try:
            packet = next(packets)
        except (StopIteration, av.FFmpegError):
            return
        try:
            frames = packet.decode()
        except av.FFmpegError:
            if skipped is not None:
                skipped.packets += 1
            continue
        yield from frames


def ffmpeg_reason(exc: BaseException) -> str:
    """An FFmpeg or OS error as words for people: its message without the error number and the
    path that the caller names anyway."""
    reason = getattr(exc, "strerror", None) or str(exc)
    return str(reason).split(": '")[0].strip() or type(exc).__name__


def probe(path: str | Path) -> VideoInfo:
    """Read a video's timing and orientation. Raises VideoError naming the file."""

    path = Path(path)
    if not path.is_file():
        raise VideoError(path, "video file does not exist")
    try:
        container = open_video(path)
    except (av.FFmpegError, OSError) as exc:
        raise VideoError(path, f"not a video FFmpeg can read ({ffmpeg_reason(exc)})") from exc
    with container:
        if not container.streams.video:
            raise VideoError(path, "no video stream")
        stream = container.streams.video[0]
        tb = stream.time_base
        head = Undecodable()
        first = next(decode(container, stream, head), None)
        if first is None:
            raise VideoError(
                path,
                f"no decodable frame ({head.packets} video packets, none decodes; expected H.264, HEVC or another codec FFmpeg reads)",
            )
        rotation = int(round(getattr(first, "rotation", 0) or 0))
        container.seek(0)
        pts = []
        corrupt = 0
        try:
            for packet in demux(container, stream):
                if packet.pts is not None and packet.size:
                    pts.append(packet.pts)
                    corrupt += bool(packet.is_corrupt)
        except av.FFmpegError:
            pass  # a truncated file: keep the packets read so far
        if not pts:
            raise VideoError(path, "no frames with presentation timestamps")
        pts.sort()
        origin = stream_origin_s(stream, float(pts[0] * tb))
        pts_s = np.array([media_seconds(p, tb, origin) for p in pts])
        nominal = float(stream.guessed_rate or stream.average_rate or 0.0)
        span = pts_s[-1] - pts_s[0]
        average = (len(pts_s) - 1) / span if span > 0 else nominal
        meta = {**container.metadata, **stream.metadata}
        return VideoInfo(
            str(path),
            pts_s,
            stream.codec_context.width,
            stream.codec_context.height,
            (-rotation) % 360,  # FFmpeg's display matrix turns counter-clockwise; the tag clockwise
            nominal,
            float(average),
            _creation_time(meta),
            stream.codec_context.name,
            origin,
            int(stream.frames or 0),
            corrupt,
            head.packets,
            *(ts_edges(path) if container.format.name == "mpegts" else (0, 0)),
        )


def rotate_for_display(rgb: np.ndarray, rotation_cw: int) -> np.ndarray:
    """A stored frame (H, W, 3) turned clockwise by rotation_cw degrees, as a player shows it."""
    return np.ascontiguousarray(np.rot90(rgb, k=-(rotation_cw // 90) % 4))


def decode_at(container, stream, stream_s: float, tolerance_s: float = 0.0):
    """The first frame of `stream` (in an open PyAV `container`) whose time on the stream's clock
    (pts x time base, s) reaches stream_s - tolerance_s, decoded from a keyframe before it; None
    when no frame does. A transport stream has no index: FFmpeg finds its keyframe by bisecting
    the file's time stamps and may land after the target (or find nothing, in a long GOP), so a
    seek that overshoots is retried from further back, and finally from the start.
    av.FFmpegError passes."""
    tb = stream.time_base
    start = float(stream.start_time * tb) if stream.start_time is not None else 0.0
    for seek_s in (stream_s, stream_s - 1.0, stream_s - 5.0, start):
        if seek_s < start and seek_s != start:
            continue
        container.seek(int(seek_s / tb), stream=stream, backward=True, any_frame=False)
        first = True
        for frame in decode(container, stream):
            if frame.pts is None:
                continue
            t = float(frame.pts * tb)
            if first and t > stream_s + tolerance_s and seek_s != start:
                break  # landed after the target: from further back
            first = False
            if t >= stream_s - tolerance_s:
                return frame
    return None


def read_frame(path: str | Path, index: int, info: VideoInfo | None = None) -> np.ndarray:
    """Frame `index` (display order) as (H, W, 3) uint8 RGB in display orientation."""

    path = Path(path)
    info = info or probe(path)
    if not 0 <= index < len(info.pts_s):
        raise VideoError(path, f"frame {index} out of range (0..{len(info.pts_s) - 1})")
    target = info.pts_s[index] + info.origin_s
    with open_video(path) as container:
        stream = container.streams.video[0]
        try:
            frame = decode_at(container, stream, target, 0.5 / max(info.nominal_fps, 1.0))
        except av.FFmpegError as exc:
            raise VideoError(path, f"cannot decode frame {index} ({exc})") from exc
    if frame is None:
        raise VideoError(path, f"frame {index} not found")
    return rotate_for_display(frame.to_ndarray(format="rgb24"), info.rotation_cw)


SEEK_AFTER_S = 2.0  # a first time wanted this far (s) into the video is sought, not decoded to
SEEK_BACK_S = (0.0, 2.0, 10.0)  # sought this much (s) before it, until a frame lands before it


def decoded_at(
    info: VideoInfo, times_s: npt.ArrayLike, tolerance_s: float
) -> Iterator[tuple[int, av.VideoFrame]]:
    """The video decoded in one pass, as (k, decoded frame) for each k of `times_s` (media
    seconds, increasing) that a frame's presentation time matches within tolerance_s; a time
    no frame matches (a packet that does not decode) is passed over. Where the first time lies
    past SEEK_AFTER_S the decoding starts at the keyframe before it (a stretch at minute 25 does
    not decode the 25 minutes before it): sought SEEK_BACK_S before it in turn until the first
    frame decoded lies before it (a transport stream has no index: FFmpeg's search by its
    timestamps may land past the time asked), else from the start. PyAV's and the file's
    errors (av.FFmpegError, OSError) reach the caller."""
    times = np.asarray(times_s, np.float64)
    if not len(times):
        return
    start = float(times[0]) - tolerance_s
    with open_video(Path(info.path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        for back in SEEK_BACK_S if start > SEEK_AFTER_S else ():
            frames = _timed(container, stream, info.origin_s, max(start - back, 0.0))
            first = next(frames, None)
            if first is None:
                break  # not to be sought: from the start
            if first[0] <= times[0] + tolerance_s:
                yield from _matched(itertools.chain([first], frames), times, tolerance_s)
                return
    with open_video(Path(info.path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        yield from _matched(_timed(container, stream, info.origin_s), times, tolerance_s)


def _timed(
    container, stream, origin_s: float, from_s: float | None = None
) -> Iterator[tuple[float, av.VideoFrame]]:
    """(media seconds, frame) of `stream` in the container, from the keyframe at or before
    media time from_s (s; None: from where it stands). Nothing where it cannot be sought."""
    if from_s is not None:
        try:
            container.seek(
                int((from_s + origin_s) / stream.time_base),
                stream=stream,
                backward=True,
                any_frame=False,
            )
        except av.FFmpegError:
            return
    for frame in decode(container, stream):
        if frame.pts is not None:
            yield media_seconds(frame.pts, stream.time_base, origin_s), frame


def _matched(
    frames: Iterator[tuple[float, av.VideoFrame]],
    times: npt.NDArray[np.float64],
    tolerance_s: float,
) -> Iterator[tuple[int, av.VideoFrame]]:
    """(k, frame) for each k of `times` (increasing, s) that a frame's time matches within
    tolerance_s (decoded_at)."""
    j = 0
    for t, frame in frames:
        while j < len(times) and times[j] < t - tolerance_s:
            j += 1  # that frame was not decoded (damaged): pass it over
        if j == len(times):
            return
        if abs(times[j] - t) <= tolerance_s:
            yield j, frame
            j += 1


def frames_at(
    info: VideoInfo, indices: Sequence[int], long_side: int | None = None
) -> Iterator[tuple[int, np.ndarray]]:
    """Frames `indices` (display order, increasing) decoded in one pass as (index, (H, W, 3) uint8
    RGB in display orientation), scaled so that the long side is at most `long_side` pixels.
    Frames are matched to indices by presentation time; a damaged frame (a packet that does not
    decode) is skipped, an error converting a decoded frame raises VideoError."""

    wanted = sorted(set(int(i) for i in indices))
    if not wanted:
        return
    path = Path(info.path)
    scale = 1.0 if long_side is None else min(1.0, long_side / max(info.width, info.height))
    size = (max(2, round(info.width * scale)), max(2, round(info.height * scale)))
    half_frame = 0.5 / max(info.nominal_fps, 1.0)
    try:
        for j, frame in decoded_at(info, [info.pts_s[i] for i in wanted], half_frame):
            rgb = frame.reformat(width=size[0], height=size[1], format="rgb24").to_ndarray()
            yield wanted[j], rotate_for_display(rgb, info.rotation_cw)
    except av.FFmpegError as exc:
        raise VideoError(path, f"cannot decode the video ({exc})") from exc
