"""The viewer's sharing (issue 53): the frame on the screen, its pose and footprint, and the
marks handed to the sinks the command line named (`--cot`, a served map) or the Share toggle
added, through one hub (app.share.hub) per open session or stream. The hub casts in its own
thread; here only the offer is made, with the frame's picture copied when the hub would take it.
A new session or stream closes the hub and makes another (the sinks are made again).

The Share toggle (`share on|off`, the Session panel) starts the browser map (app.share.web) and
adds its sink; the server outlives the hubs, so its URL stays the same across sessions."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.core.messages import Messages
from app.live.run import offer_drawn
from app.locate.marks import marks_geojson
from app.share.hub import Offer, Share, Sink
from app.share.web import DEFAULT_BIND, MapServer, web_sink_maker

__all__ = ["ViewerShare", "close", "start_web", "stop_web", "update"]

SinkMaker = Callable[[Messages], Sink]


@dataclass
class ViewerShare:
    """makers: the sinks to share with (each called with the hub's Messages when a hub is
    made); hub: the open session's or stream's; owner: what it was made for; marks_sent: the
    marks last handed over (their list, compared by content)."""

    makers: list[SinkMaker] = field(default_factory=list)
    hub: Share | None = None
    owner: object = None
    marks_sent: list | None = None
    made: dict = field(default_factory=dict)  # maker -> the sink it made for the open hub
    web: MapServer | None = None  # the browser map the Share toggle started
    web_maker: SinkMaker | None = None

    def add(self, make: SinkMaker) -> None:
        """Share with one more sink, from now on (the open hub gets it at once)."""
        self.makers.append(make)
        if self.hub is not None:
            sink = self.made[make] = make(self.hub.messages)
            self.hub.add_sink(sink)
            last = self.hub.last
            if last is not None:  # paused, the frame shown would not be offered again
                try:
                    sink.send_frame(last)
                except Exception as exc:  # a sink's fault is said, never the viewer's end
                    self.hub.messages.add(f"sharing to {sink.name}: frame failed: {exc}")

    def remove(self, make: SinkMaker) -> None:
        """Share with the sinks of `make` no more (the open hub's closed now); the hub itself
        closed when no maker is left."""
        self.makers = [m for m in self.makers if m is not make]
        sink = self.made.pop(make, None)
        if sink is not None and self.hub is not None:
            self.hub.remove_sink(sink)
        if not self.makers:
            close(self)


def close(share: ViewerShare) -> None:
    """Close the hub (and its sinks); the makers stay for the next session."""
    if share.hub is not None:
        share.hub.close()
    share.hub, share.owner, share.marks_sent = None, None, None
    share.made = {}


def start_web(v, bind: tuple[str, int] = DEFAULT_BIND) -> MapServer:
    """The Share toggle on: the browser map started (its imagery the world the command line
    named, if any) and fed from now on; its URL said among the notes. OSError where the address
    cannot be had."""
    share: ViewerShare = v.share
    if share.web is not None:
        return share.web
    world = next((x.world for x in v.options.layers if x.kind == "world"), None)
    server = MapServer(
        bind,
        imagery=None if world is None else world.imagery,
        attribution="" if world is None else world.attribution,
    ).start()
    share.web, share.web_maker = server, web_sink_maker(server)
    share.add(share.web_maker)
    if server.warning:
        v.ui.warnings.append(server.warning)
    v.ui.info.append(f"sharing: the browser map is at {server.url}")
    return server


def stop_web(v) -> None:
    """The Share toggle off: the browser map's sink removed and its server stopped."""
    share: ViewerShare = v.share
    if share.web is None:
        return
    share.remove(share.web_maker)
    share.web.close()
    v.ui.info.append(f"sharing: the browser map at {share.web.address} stopped")
    share.web, share.web_maker = None, None


def update(v) -> None:
    """This frame's offer: the shown frame of the open session (its source's camera) or stream."""
    share: ViewerShare = v.share
    if not share.makers:
        return
    if v.live is not None:
        _live(v, share)
    elif v.loaded is not None:
        _session(v, share)
    elif share.hub is not None:
        close(share)


def _hub(
    share: ViewerShare,
    owner: object,
    messages: Messages,
    make: Callable[[list[Sink]], Share],
) -> Share:
    """The owner's hub (made anew, its sinks with it, when the owner changed); what it says goes
    to the owner's own messages, which the viewer shows."""
    if share.owner is not owner:
        close(share)
        sinks = [m(messages) for m in share.makers]
        share.made = dict(zip(share.makers, sinks, strict=True))
        share.hub = make(sinks)
        share.owner = owner
    return share.hub


def _session(v, share: ViewerShare) -> None:
    L = v.loaded
    k = v.current_index
    track = L.library.track(L.source)
    if track is None or k < 0:
        return
    s = L.session
    hub = _hub(
        share,
        L,
        s.messages,
        lambda sinks: Share(
            s.scene(), s.frame, s.intrinsics, sinks, s.messages, lens=s.lens
        ).start(),
    )
    _marks(v, share, hub, s.frame)
    if hub.last is not None and hub.last.index == k and hub.idle():
        return  # paused on a frame already shared
    media = float(track.clock.media_s[k])
    t = float(track.clock.session_time(media))
    f = L.player.current
    picture = None
    if f is not None and hub.due():
        picture = tuple(np.array(p, copy=True) for p in (f.y, f.u, f.v))
    hub.offer(
        Offer(
            track.frame_camera(k),
            k,
            media,
            s.utc_of(t),
            Path(s.video.path).name,
            L.source,
            None if track.fixes is None else str(track.fixes.at([t])[0]),
            picture,
        )
    )


def _live(v, share: ViewerShare) -> None:
    L = v.live
    r = L.renderer
    if r is None or r.projector is None or L.mesh is None:
        return  # no scene yet
    feed = L.feed
    hub = _hub(
        share,
        L,
        feed.run.messages,
        lambda sinks: Share(L.mesh, feed.frame, feed.intrinsics, sinks, feed.run.messages).start(),
    )
    _marks(v, share, hub, feed.frame)
    if L.pending is not None and L.shown_item is not None:  # a frame drawn this tick
        offer_drawn(hub, feed, L.shown_item, r.projector)


def _marks(v, share: ViewerShare, hub: Share, frame) -> None:
    marks = list(v.ui.measure.marks)
    if marks != share.marks_sent:
        hub.set_marks(marks_geojson(marks, frame))
        share.marks_sent = marks
