"""A recorded clip shared as if it were flying now (`geofuse serve CLIP`): its frames offered to a
sharing hub (app.share.hub) at their own pace in real time, each with its camera from the
session's solved track, its UTC, GNSS status and picture, with no window. The video is decoded
in order; a frame's picture is made only when the hub would take it. Playing never runs ahead
of the clip's own times; where decoding is slower than the video it runs behind them (each
frame still offered with its own pose).

Times: media seconds from the clip's first frame (CameraTrack.clock.media_s); `clock` is
monotonic seconds (injected in tests)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np

from app.core.messages import Messages
from app.io.video import decoded_at, rotate_for_display
from app.locate.marks import marks_geojson, marks_path, read_marks
from app.session.camera_track import CameraTrack
from app.session.model import Session
from app.share.frames import THUMBNAIL_WIDTH_PX
from app.share.hub import Offer, Share

__all__ = ["Replayed", "replay", "session_marks"]

MATCH_TOLERANCE = 0.5  # of a frame interval: a decoded frame is frame k within this


@dataclass
class Replayed:
    """What a replay did: frames offered, passes through the clip, and how it ended."""

    offered: int = 0
    passes: int = 0
    ended: str = ""


def session_marks(session: Session) -> dict | None:
    """The marks kept beside the session's input (app.locate.marks) as a GeoJSON
    FeatureCollection, None where there are none; a mark that cannot be read is said and left
    out."""
    path = marks_path(session.path)
    if not path.is_file():
        return None
    marks = read_marks(path, session.frame, skip=lambda exc: session.messages.add(str(exc)))
    return marks_geojson(marks, session.frame)


def _pictures(
    session: Session, media_s: np.ndarray, messages: Messages
) -> Iterator[tuple[int, av.VideoFrame | None]]:
    """(frame index, its decoded PyAV frame) in order; where the video cannot be decoded, every
    index with None (said once)."""
    info = session.video
    step = float(np.median(np.diff(media_s))) if len(media_s) > 1 else 1.0 / 30.0
    j = 0
    try:
        for k, frame in decoded_at(info, media_s, MATCH_TOLERANCE * step):
            yield k, frame  # a frame not decoded (damaged) is passed over
            j = k + 1
    except (av.FFmpegError, OSError) as exc:
        messages.add_once(
            "replay-video", f"{Path(info.path).name}: shared without pictures from here ({exc})"
        )
    for k in range(j, len(media_s)):
        yield k, None


def _thumbnail_rgb(frame: av.VideoFrame, rotation_cw: int) -> np.ndarray:
    """A decoded frame as (H, W, 3) uint8 RGB, scaled down to the thumbnail's size on its long
    side and turned for display."""
    scale = min(1.0, THUMBNAIL_WIDTH_PX / max(frame.width, frame.height))
    w, h = max(2, round(frame.width * scale)), max(2, round(frame.height * scale))
    rgb = frame.reformat(width=w, height=h, format="rgb24").to_ndarray()
    return rotate_for_display(rgb, rotation_cw)


def replay(
    session: Session,
    track: CameraTrack,
    share: Share,
    once: bool = False,
    seconds: float | None = None,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
    tick: Callable[[], None] | None = None,
) -> Replayed:
    """Offer the clip's frames to `share` in real time, from the first frame to the last, then
    again (once: a single pass); until `seconds` have gone, `stop` is set, or (once) the end.
    tick: called after each frame (the caller prints what was said meanwhile)."""
    media = np.asarray(track.clock.media_s, np.float64)
    clip = Path(session.video.path).name
    stop = stop or threading.Event()
    began = clock()
    out = Replayed()
    if len(media) == 0:
        out.ended = "the clip has no frames"
        return out
    while True:
        out.passes += 1
        start = clock() - float(media[0])
        for k, frame in _pictures(session, media, session.messages):
            due = start + float(media[k])
            while True:
                now = clock()
                if stop.is_set():
                    out.ended = "stopped"
                    return out
                if seconds is not None and now - began >= seconds:
                    out.ended = f"ended after {seconds:g} s"
                    return out
                if now >= due:
                    break
                stop.wait(min(due - now, 0.1))
            t = float(track.clock.session_time(float(media[k])))
            picture = None
            if frame is not None and share.due():
                picture = _thumbnail_rgb(frame, session.rotation_cw)
            share.offer(
                Offer(
                    track.frame_camera(k),
                    k,
                    float(media[k]),
                    session.utc_of(t),
                    clip,
                    track.source,
                    None if track.fixes is None else str(track.fixes.at([t])[0]),
                    picture,
                )
            )
            out.offered += 1
            if tick is not None:
                tick()
        if once:
            out.ended = "played once"
            return out
