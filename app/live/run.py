"""A live feed drawn without a window (`geofuse live`, `bench live`): the viewer's pipeline
(app.live.feed), off screen through EGL, with the same clock and the same figures.

The loop never waits on the network: it takes the newest frame due from the jitter buffer,
draws it projected with the pose of its own time and records when the drawing was finished (the
GPU waited for). It ends after `seconds`, once the stream has been silent for `silence_s`
(said), or at once when an address was refused (said).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from urllib.parse import urlsplit

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.live.feed import Drawn, LiveFeed, LiveOptions, LiveRun
from app.render.context import create_offscreen_context, keep_current, wait_for_gpu
from app.render.offscreen import OffscreenTarget
from app.render.renderer import FusionRenderer
from app.render.still import window_camera
from app.share.hub import Offer, Share
from app.simulate.autopilot import MavlinkSender
from app.simulate.feed import LockstepClock, Sender, free_udp_port, sending_clock

__all__ = ["Drawn", "LiveOptions", "LiveRun", "offer_drawn", "open_share", "run_live", "run_sent"]

VIEW_HFOV_DEG = 60.0  # the off-screen view, third person behind the projector


@keep_current()  # its own context, made and released here: the caller's stays current
def run_live(
    url: str,
    options: LiveOptions | None = None,
    clock: Callable[[], float] = time.monotonic,
    on_drawn: Callable[[Drawn, Camera], None] | None = None,
    on_start: Callable[[LiveFeed], None] | None = None,
) -> LiveRun:
    """Receive `url` and draw it off screen until `options.seconds` or silence; see the module
    docstring. on_drawn(d, projector): called after each frame is drawn; on_start(feed): once
    the feed is started, before the clock is first read."""
    options = options or LiveOptions()
    feed = LiveFeed(url, options, clock=clock)
    if on_start is not None:
        on_start(feed)
    feed.start()
    run = feed.run
    start = clock()
    ctx = renderer = target = share = None
    view_intr = Intrinsics.from_fov(*options.size, VIEW_HFOV_DEG)
    try:
        while True:
            now = clock()
            if options.seconds is not None and now - start >= options.seconds:
                run.ended = f"ended after {options.seconds:g} s"
                break
            if feed.refused is not None:
                run.ended = "ended: the address was refused"
                break
            if feed.silent_for(now, start) >= options.silence_s:
                run.ended = feed.silence(options.silence_s)
                run.messages.add(run.ended)
                break
            if renderer is None:
                if not feed.ready():
                    time.sleep(0.005)
                    continue
                mesh = feed.build_scene()
                ctx = create_offscreen_context()
                renderer = FusionRenderer(ctx, mesh)
                target = OffscreenTarget(ctx, *options.size)
                if options.sinks:
                    share = open_share(feed, mesh, options.sinks)
            shown = feed.take(now)
            if shown is None:
                time.sleep(min(max(feed.next_wake(now) - clock(), 0.0005), 0.005))
                continue
            item, due, camera, state = shown
            y, u, v = item.payload
            renderer.set_video_yuv(y, u, v, 0, y.shape[0] >= 720)
            renderer.set_projector(camera)
            view = window_camera(camera, view_intr, None, None, options.far_m)
            renderer.draw(view, target.fbo)
            wait_for_gpu(ctx)
            d = Drawn(
                item.pts_s, item.arrival_s, due, clock(), state, feed.registered, feed.gnss_now
            )
            run.add_drawn(d)
            feed.restream_frame(item.pts_s, camera)
            if share is not None:
                offer_drawn(share, feed, item, camera)
            if on_drawn is not None:
                on_drawn(d, camera)
    finally:
        if share is not None:
            share.close()
        feed.stop()
        if renderer is not None:
            target.release()
            renderer.release()
            ctx.release()
    return run


def run_sent(
    path: Path,
    options: LiveOptions,
    on_drawn: Callable[[Drawn, Camera], None] | None = None,
    lockstep: bool = False,
    telemetry: Callable[[float, Callable[[], float]], object] | None = None,
) -> LiveRun:
    """A recorded MPEG-TS (a simulated downlink) sent to this process over the loopback in real
    time, paced by its program clock (app.simulate.feed.Sender), from the moment run_live's
    receiver listens, and received, drawn and summed up by run_live: what the tests and
    benchmarks of live feeds run. lockstep (tests): sender and receiver share a clock that
    stands still while a keyframe is being registered, a frame due is not yet drawn or the
    receiver is behind (lockstep_cap), so the same frames are drawn with the same corrections
    however busy the machine is. telemetry(start_s, clock): a sender of the flight's telemetry
    beside the video (app.simulate.autopilot.MavlinkSender to options.mavlink), made and
    started when the video's sender starts, on the same clock; stopped at the end."""
    port = free_udp_port()
    feeds: list[LiveFeed] = []  # (run_live's, once started)
    beside: list = []

    def cap(now: float) -> float:
        return lockstep_cap(feeds[0], sender, now) if feeds else math.inf

    clock = LockstepClock(cap) if lockstep else time.monotonic
    sender = Sender(Path(path).read_bytes(), ("127.0.0.1", port), clock=clock)
    if lockstep:  # the receiver waits out the sender's pauses
        options = replace(options, read_timeout_s=max(options.read_timeout_s, clock.limit_s))
    try:
        return run_live(
            f"udp://127.0.0.1:{port}",
            options,
            sending_clock(
                sender,
                port,
                clock=clock,
                on_start=None
                if telemetry is None
                else lambda t: beside.append(telemetry(t, clock)),
            ),
            on_drawn,
            feeds.append,
        )
    finally:
        sender.stop()
        for other in beside:
            other.stop()


def run_flown(
    path: Path,
    options: LiveOptions,
    seconds: float,
    on_drawn: Callable[[Drawn, Camera], None] | None = None,
    lockstep: bool = False,
    **autopilot: object,
) -> LiveRun:
    """run_sent of a drone's video without KLV (app.simulate.drone) with its autopilot's MAVLink
    telemetry for `seconds` of flight beside it (app.simulate.autopilot.MavlinkSender, given
    `autopilot`: fixed, home, home_enu, lost_at_s, ...), on the same clock, to a free port that
    options.mavlink is set to."""
    port = free_udp_port()
    options = replace(options, mavlink=f"udp:127.0.0.1:{port}")

    def telemetry(start: float, clock: Callable[[], float]) -> MavlinkSender:
        return MavlinkSender(("127.0.0.1", port), seconds, start, clock=clock, **autopilot).start()

    return run_sent(path, options, on_drawn, lockstep, telemetry)


# lockstep: the video sent ahead of the newest frame received at most (s; a receiver holds
# 0.6 s of it while it starts)
AHEAD_S = 1.0


def lockstep_cap(feed: LiveFeed, sender: Sender, now: float) -> float:
    """The time (clock s) a lockstep run's clock may not pass at `now`: now itself while a
    keyframe is being registered or the receiver holds nothing within AHEAD_S of video of what
    `sender` sent (it catches up meanwhile); else when the next frame waiting falls due (one
    falls due at a time: each is drawn, none skipped); else no bound."""
    reg = feed.registration
    if reg is not None and reg.busy:
        return now
    with feed.receiver.lock:
        newest = feed.buffer.newest_pts()
        due = feed.buffer.next_due()
    origin = feed.receiver.origin_s  # (stream s of media 0: the sender's times are the stream's)
    received = sender.first_s if origin is None or newest == -math.inf else origin + newest
    if sender.sent_s is not None and sender.sent_s - received > AHEAD_S:
        return now
    return math.inf if due is None else due


def open_share(feed: LiveFeed, mesh, sinks: tuple) -> Share:
    """The sharing hub of a feed whose scene is built: its sinks made (each maker called with
    the run's Messages) and started."""
    messages = feed.run.messages
    made = [make(messages) for make in sinks]
    return Share(mesh, feed.frame, feed.intrinsics, made, messages).start()


def offer_drawn(share: Share, feed: LiveFeed, item, camera: Camera) -> None:
    """Hand the hub a frame just drawn (its picture only when the hub would take it now)."""
    share.offer(
        Offer(
            camera,
            feed.run.frames_drawn,
            float(item.pts_s),
            clip=without_credentials(feed.url),
            source=feed.pose_source,
            gnss=feed.gnss_now,
            picture=item.payload if share.due() else None,
        )
    )


def without_credentials(url: str) -> str:
    """The URL with any user name and password left out (what is shared names the stream, never
    a secret in its address)."""
    parts = urlsplit(url)
    if parts.username is None and parts.password is None:
        return url
    host = (parts.hostname or "") + (f":{parts.port}" if parts.port else "")
    return parts._replace(netloc=host).geturl()
