"""Video decoding on a worker thread: PyAV (FFmpeg's own threading on) into a bounded queue of
YUV frames. The thread only decodes; every GL call stays on the render thread.

A seek request carries the clock's serial; frames decoded after it carry that serial, so the
render thread drops anything older (ffplay's scheme). Corrupt packets are skipped and counted.

When drawing or decoding is slower than the video, the decoder keeps up with the clock instead of
falling behind it: the render thread publishes the media time it will show next (`due_s`);
frames already late by more than LATE_S are decoded (the codec needs them) but neither converted
nor queued, and when the decoder is more than RESEEK_BEHIND_S behind, it seeks forward to the
keyframe before the due time. Frames skipped either way are counted in `skipped`.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np

from app.io.video import demux, media_seconds, open_video

QUEUE_FRAMES = 12  # about 0.4 s of 30 fps video: enough to ride out decoder hiccups
LATE_S = 0.05  # a frame this far behind the media time due is not converted nor queued
RESEEK_BEHIND_S = 2.0  # this far behind the media time due, seek forward instead of decoding on


@dataclass(frozen=True)
class DecodedFrame:
    """One frame as stored (not yet turned for display): Y (H, W), U and V (H/2, W/2) uint8;
    pts_s: seconds from the stream's first frame; bt709: the stream's colour matrix."""

    serial: int
    pts_s: float
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    bt709: bool
    full_range: bool


def yuv_planes(frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Y, U, V planes of a PyAV frame as contiguous arrays (converted to yuv420p if needed)."""
    if frame.format.name not in ("yuv420p", "yuvj420p"):
        frame = frame.reformat(format="yuv420p")
    a = frame.to_ndarray()
    h, w = frame.height, frame.width
    y = a[:h]
    chroma = a[h:].reshape(2, h // 2, w // 2)
    return np.ascontiguousarray(y), np.ascontiguousarray(chroma[0]), np.ascontiguousarray(chroma[1])


def planes_to_rgb(planes: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """(H, W, 3) uint8 RGB of yuv420p planes (y (H, W), u and v (H/2, W/2)), BT.601, as the
    live registration and the shared pictures read them."""
    y, u, v = planes
    h, w = y.shape
    stacked = np.concatenate([y.reshape(-1), u.reshape(-1), v.reshape(-1)]).reshape(h * 3 // 2, w)
    return cv2.cvtColor(stacked, cv2.COLOR_YUV2RGB_I420)


class Decoder:
    """Decodes `path` on a daemon thread into `frames` (a bounded queue)."""

    def __init__(self, path: str | Path, origin_s: float = 0.0, start_time_s: float = 0.0) -> None:
        """origin_s: the stream-clock seconds of media time 0 (app.io.video.VideoInfo.origin_s)."""
        self.path = str(path)
        self.origin_s = origin_s
        self.due_s: float | None = None  # set by the render thread: the media time it shows next
        self.skipped = 0
        self._delivered = False  # a frame was queued since the last seek
        self.at_end = False  # the last frame of the stream has been queued; no more until a seek
        self.frames: queue.Queue[DecodedFrame | None] = queue.Queue(maxsize=QUEUE_FRAMES)
        self.corrupt_packets = 0
        self.error: str | None = None
        self._commands: queue.Queue[tuple[float, int] | None] = queue.Queue()
        self._commands.put((start_time_s, 0))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-decoder", daemon=True)
        self._thread.start()

    def seek(self, media_time_s: float, serial: int) -> None:
        """Decode from the frame at media_time_s on; frames will carry `serial`."""
        self.at_end = False
        self._commands.put((media_time_s, serial))

    def join(self, timeout: float | None = None) -> bool:
        """Wait until the decoder thread has ended (a video it could not open, or after close);
        True when it has."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def close(self) -> None:
        self._stop.set()
        self._commands.put(None)
        try:
            while True:
                self.frames.get_nowait()
        except queue.Empty:
            pass
        self._thread.join(timeout=2.0)

    def _put(self, item: DecodedFrame) -> bool:
        """Block until there is room, unless a command or stop arrives (then False)."""
        while not self._stop.is_set():
            if not self._commands.empty():
                return False
            try:
                self.frames.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            self._decode_all()
        except Exception as exc:  # a worker must not die silently: the viewer shows this
            self.error = f"{self.path}: decoding stopped ({type(exc).__name__}: {exc})"

    def _decode_all(self) -> None:

        try:
            container = open_video(self.path)
        except (av.FFmpegError, OSError) as exc:
            self.error = f"{self.path}: cannot open video ({exc})"
            return
        with container:
            if not container.streams.video:
                self.error = f"{self.path}: no video stream"
                return
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"  # FFmpeg's frame and slice threads
            rate = float(stream.guessed_rate or 30.0)
            bt709 = stream.codec_context.height >= 720
            command = self._commands.get()
            while command is not None and not self._stop.is_set():
                target, serial = command
                container.seek(
                    int((target + self.origin_s) / stream.time_base),
                    stream=stream,
                    backward=True,
                    any_frame=False,
                )
                self.at_end = False
                self._delivered = False
                command = self._decode_from(container, stream, target, serial, rate, bt709)
                if command is None and not self._delivered and target > 0.0:
                    # A transport stream has no index: the search for the keyframe before the
                    # target found none (a long GOP): decode from the start up to it.
                    container.seek(
                        int(self.origin_s / stream.time_base), stream=stream, backward=True
                    )
                    command = self._decode_from(container, stream, target, serial, rate, bt709)
                if command is None and not self._stop.is_set():
                    self.at_end = True
                    command = self._commands.get()  # end of stream: wait for a seek or stop

    def _decode_from(self, container, stream, target: float, serial: int, rate: float, bt709: bool):
        """Decode forward from the last seek; returns the next command, or None at end of stream."""

        packets = demux(container, stream)
        delivered = False  # the first frame after a seek is always delivered
        while not self._stop.is_set():
            if not self._commands.empty():
                return self._latest_command()
            try:
                packet = next(packets)
            except StopIteration:
                return None
            except av.FFmpegError:
                self.corrupt_packets += 1
                continue
            try:
                frames = packet.decode()
            except av.FFmpegError:
                self.corrupt_packets += 1
                continue
            for frame in frames:
                if frame.pts is None:
                    continue
                pts = media_seconds(frame.pts, stream.time_base, self.origin_s)
                if pts < target - 0.5 / rate:
                    continue  # before the seek target: decoded only to reach it
                due = self.due_s
                if delivered and due is not None and pts < due - LATE_S:
                    self.skipped += 1
                    if pts < due - RESEEK_BEHIND_S:
                        return (
                            due,
                            serial,
                        )  # too far behind: jump to the keyframe before the due time
                    continue
                delivered = self._delivered = True
                space = getattr(frame, "colorspace", None)
                item = DecodedFrame(
                    serial,
                    pts,
                    *yuv_planes(frame),
                    bt709 if space in (None, 2) else int(space) == 1,
                    frame.format.name == "yuvj420p",
                )
                if not self._put(item):
                    return self._latest_command()
        return None

    def _latest_command(self):
        """Collapse queued seeks to the newest (scrubbing sends many)."""
        command = self._commands.get()
        while command is not None:
            try:
                nxt = self._commands.get_nowait()
            except queue.Empty:
                break
            command = nxt
        return command
