"""A live stream in the viewer (`geofuse view URL`, the Session panel's "Open stream"): the feed
of app.live.feed drawn in the window, recorded as it arrives in rolling segments, reviewable.

Each frame, following the live edge, the newest frame due from the jitter buffer is drawn with
the camera of its own time; the display never waits on the network. Scrubbing back ("review")
shows the frame of any moment that has arrived, decoded from the recording, with its pose;
frames keep arriving and being recorded meanwhile (not shown, not counted as dropped), and
"Live" returns to the edge. Latency (arrival -> shown) is measured on the window's swap.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

from app.camera.pinhole import Camera
from app.live.buffer import Arrival
from app.live.feed import Drawn, LiveFeed, LiveOptions, LiveRun
from app.live.recorder import SegmentRecorder
from app.render.renderer import FusionRenderer
from app.scene.mesh import MeshData
from app.ui.gnss import live_said
from app.ui.navigation import Navigator, chase

log = logging.getLogger("geofuse.viewer")
DRAWN_KEPT = 900  # frames whose latency the Stats panel summarises (30 s at 30 fps)
LIVE_FOLDER = Path("out/live")


def is_stream(text: str) -> bool:
    """Whether what was typed or given is a stream URL (udp://, rtsp://, ...), not a file."""
    scheme, sep, _ = text.partition("://")
    return bool(sep) and scheme.isalpha() and len(scheme) > 1


@dataclass
class LiveView:
    """The open stream: its feed, the renderer (once the first pose has placed the scene), the
    moment under review (None: following the live edge) and the frame waiting for its swap."""

    feed: LiveFeed
    folder: Path
    opened_s: float
    renderer: FusionRenderer | None = None
    review_s: float | None = None
    reviewed_s: float | None = None  # the media time of the reviewed frame on the renderer
    shown_s: float | None = None  # media time of the frame on the renderer
    pending: Drawn | None = None
    pose_state: str = ""  # the shown frame's pose: fresh, stale (older than the buffer), none
    ended: str = ""  # why the scene could not be built (then not tried again each frame)
    pose_states: dict[str, int] = field(default_factory=dict)
    mesh: MeshData | None = None  # the scene built around the first position
    shown_item: Arrival | None = None  # the frame on the renderer

    @property
    def run(self) -> LiveRun:
        return self.feed.run

    def recorded_span(self) -> tuple[float, float] | None:
        """(first, last) media seconds of the video recorded so far, None before any."""
        origin = self.feed.receiver.origin_s
        span = self.segments.span_s()
        if origin is None or span is None:
            return None
        return span[0] - origin, span[1] - origin

    @property
    def segments(self) -> SegmentRecorder:
        """The rolling recording (open_stream always records in segments)."""
        return self.feed.recorder


def open_stream(v, url: str, options: LiveOptions | None = None) -> None:
    """Receive `url` in the window (closing what was open), recording it under out/live/."""
    close(v)
    v.close_session()
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    folder = LIVE_FOLDER / stamp
    base = options or LiveOptions()
    opts = LiveOptions(
        **{**base.__dict__, "segments": folder, "record": None, "layers": v.options.layers}
    )
    run = LiveRun(url, drawn=deque(maxlen=DRAWN_KEPT), delay_s=opts.delay_s)
    feed = LiveFeed(url, opts, run, clock=time.perf_counter).start()
    v.live = LiveView(feed, folder, time.perf_counter())
    v.ui.info, v.ui.warnings = [f"receiving {url}; recording in {folder}/"], []
    v._messages_seen = 0
    log.info("receiving %s, recording in %s", url, folder)


def close(v) -> None:
    """Stop the stream (the recording is kept and said)."""
    L = v.live
    if L is None:
        return
    run = L.feed.stop()
    if L.renderer is not None:
        L.renderer.release()
    v.live = None
    log.info("%s", run.summary())
    v.ui.info.append(f"{run.url} closed: {run.summary()} (recorded in {L.folder}/)")


def home(projector: Camera) -> Navigator:
    """The window camera of a stream: following the aircraft (app.ui.navigation.chase), its
    reset the chase view of the first frame; moving or looking roams freely from there."""
    eye, target = chase(projector)
    nav = Navigator()
    nav.look_at(eye, target)
    nav.home = (nav.position.copy(), nav.yaw, nav.pitch)
    nav.mode = "follow"
    return nav


def review(v, t: float | None) -> None:
    """Show media time t (s) from the recording (None: back to the live edge)."""
    L = v.live
    if t is None:
        L.review_s = None
        return
    span = L.recorded_span()
    if span is None:
        raise ValueError("nothing has been recorded yet")
    L.review_s = float(min(max(t, span[0]), span[1]))


def update(v) -> None:
    """This frame's work: build the scene once the feed is ready, then the frame due (or the
    frame under review) and its camera onto the renderer. A stream runs on the real clock
    whatever clock the viewer's script set (the network does not wait for it)."""
    L = v.live
    feed = L.feed
    now = feed.clock()
    v.show_messages(L.run.messages)
    if L.renderer is None:
        if L.ended or not feed.ready():
            return
        try:
            mesh = feed.build_scene()
        except Exception as exc:  # a layer that cannot be read: said, the stream kept
            v.ui.error(f"{feed.url}: cannot build the scene ({exc})")
            L.ended = str(exc)
            return
        L.renderer = FusionRenderer(v.window.ctx, mesh)
        L.mesh = mesh
    if L.review_s is None:
        shown = feed.take(now)
        if shown is not None:
            item, due, camera, state = shown
            if L.shown_s is None:
                v.nav = home(camera)
            _show(L, item, camera)
            L.pose_state = state
            L.pending = Drawn(
                item.pts_s, item.arrival_s, due, math.nan, state, feed.registered, feed.gnss_now
            )
            L.reviewed_s = None
        return
    feed.discard_due(now)  # arriving frames are recorded, not shown, while reviewing
    if L.reviewed_s != L.review_s:
        item = feed.recorded_frame(L.review_s)
        if item is not None:
            camera, _ = feed.camera_at(item.pts_s)
            if camera is not None:
                _show(L, item, camera)
        L.reviewed_s = L.review_s


def _show(L: LiveView, item: Arrival, camera) -> None:
    y, u, v_ = item.payload
    L.renderer.set_video_yuv(y, u, v_, 0, y.shape[0] >= 720)
    L.renderer.set_projector(camera)
    L.shown_s = item.pts_s
    L.shown_item = item


def swapped(v) -> None:
    """The frame drawn this tick has reached the screen (the window swapped): its latency."""
    L = v.live
    if L is None or L.pending is None:
        return
    shown_at = L.feed.clock()
    d = L.pending
    L.run.add_drawn(replace(d, drawn_s=shown_at))
    L.pose_states[d.pose] = L.pose_states.get(d.pose, 0) + 1
    L.pending = None


def state(v) -> dict:
    """The open stream for a script's `state`: its figures, what is shown and recorded."""
    L = v.live
    run = L.feed.update_counts()
    span = L.recorded_span()
    proj = L.renderer.projector if L.renderer is not None else None
    return {
        "url": run.url,
        "received": run.received,
        "drawn": run.frames_drawn,
        "missing": run.missing,
        "dropped": run.skipped + run.late + run.overflow,
        "latency_ms": [run.latency_ms(50), run.latency_ms(95)],
        "added_ms": [run.added_ms(50), run.added_ms(95)],
        "poses": dict(L.pose_states),
        "shown_s": L.shown_s,
        "review_s": L.review_s,
        "recorded_s": None if span is None else list(span),
        "segments": [str(s.path) for s in L.segments.segments],
        "origin_s": run.origin_s,
        "frame": None if L.feed.frame is None else [L.feed.frame.lat_deg, L.feed.frame.lon_deg, L.feed.frame.h_m],
        "projector": None if proj is None else {"position": list(map(float, proj.position)), "orientation": list(map(float, proj.orientation))},
        "mavlink_lag_s": None if run.mavlink is None else run.mavlink.lag_s,
        "registration": None if run.registration is None else run.registration.line(),
        "gnss": {"frame": L.feed.gnss_now, "said": [t for t, _ in live_said(L.feed.gnss, L.feed.gnss_now, L.shown_s or 0.0)]},
    }  # fmt: skip
