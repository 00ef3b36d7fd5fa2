"""The viewer's sharing (issue 53): the frame on the screen, its pose and footprint, and the
marks handed to the sinks the command line named (`--cot`, a served map) or the Share toggle
added, through one hub (app.share.hub) per open session or stream. The hub casts in its own
thread; here only the offer is made, with the frame's picture copied when the hub would take it.
A new session or stream closes the hub and makes another (the sinks are made again)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.core.messages import Messages
from app.live.run import offer_drawn
from app.locate.marks import marks_geojson
from app.share.hub import Offer, Share, Sink

__all__ = ["ViewerShare", "close", "update"]

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

    def add(self, make: SinkMaker) -> None:
        """Share with one more sink, from now on (the open hub gets it at once)."""
        self.makers.append(make)
        if self.hub is not None:
            self.hub.add_sink(make(self.hub.messages))


def close(share: ViewerShare) -> None:
    """Close the hub (and its sinks); the makers stay for the next session."""
    if share.hub is not None:
        share.hub.close()
    share.hub, share.owner, share.marks_sent = None, None, None


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
        share.hub = make([m(messages) for m in share.makers])
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
