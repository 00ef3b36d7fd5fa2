"""The live clock: a jitter buffer between a stream's arrivals and the display (pure: every time
is passed in, seconds on one monotonic clock).

A frame arrives at `arrival_s` carrying its presentation time `pts_s` (media seconds). The link
between the two clocks is the smallest `arrival - pts` seen over the recent frames (the frame that
travelled fastest sets it; a window lets it follow a sender's clock drift, and a jump of more than
RESYNC_S, a restarted encoder, starts it afresh). A frame is due at pts + link + delay: the delay
absorbs the network's jitter, so frames are shown at their own pace, not in bursts.

Joining a stream, the demuxer hands over in one burst what it read while probing it (half a
second): the link starts at the first frame's and slews toward the fastest at CATCH_UP (the
display plays 25 % fast until it reaches the live edge) instead of skipping the burst. `take(now)`
hands over the newest due frame; older due frames not yet shown are skipped (counted: the display
fell behind); a frame arriving after a newer one was shown is late (counted, dropped).
"""

from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass, field
from typing import Any

DEFAULT_DELAY_S = 0.1
LINK_WINDOW = 300  # frames over which the fastest arrival sets the link (10 s at 30 fps)
RESYNC_S = 2.0  # a jump of the link by more than this: the sender restarted; start afresh
CATCH_UP = 0.25  # seconds of link slewed per second of clock: the display plays 25 % fast


@dataclass(frozen=True)
class Arrival:
    """A frame as it arrived: its presentation time (media s), when it arrived (s, monotonic)
    and what to draw (decoded planes)."""

    pts_s: float
    arrival_s: float
    payload: Any = None


@dataclass
class JitterBuffer:
    """Frames waiting for their due time; see the module docstring."""

    delay_s: float = DEFAULT_DELAY_S
    capacity: int = 90
    pending: list[Arrival] = field(default_factory=list)
    skipped: int = 0  # due frames never shown: a newer one was due at the same draw
    late: int = 0  # arrived after a newer frame was shown
    overflow: int = 0  # dropped because the buffer was full (nothing drew for a while)
    resyncs: int = 0
    shown_pts: float = float("-inf")
    _links: deque = field(default_factory=lambda: deque(maxlen=LINK_WINDOW))
    _link: float | None = None  # the link in use, slewing toward the fastest
    _fastest: float | None = None  # min(_links), kept as one value other threads may read
    _slewed_at: float | None = None

    @property
    def link_s(self) -> float | None:
        """arrival - pts of the fastest recent frame (s), None before the first; safe to read
        from another thread than the one pushing."""
        return self._fastest

    def _slew(self, now_s: float) -> None:
        target = self.link_s
        if target is None or self._link is None or self._slewed_at is None:
            return
        step = CATCH_UP * max(now_s - self._slewed_at, 0.0)
        self._link = min(max(target, self._link - step), self._link + step)
        self._slewed_at = now_s

    def push(self, frame: Arrival) -> None:
        link = frame.arrival_s - frame.pts_s
        if self._links and abs(link - min(self._links)) > RESYNC_S:
            self._links.clear()  # the sender's clock jumped: its times start afresh
            self.shown_pts = float("-inf")
            self._link = None
            self.resyncs += 1
        self._links.append(link)
        self._fastest = min(self._links)
        if self._link is None:
            self._link, self._slewed_at = link, frame.arrival_s
        if frame.pts_s <= self.shown_pts:
            self.late += 1
            return
        keys = [f.pts_s for f in self.pending]
        i = bisect.bisect_right(keys, frame.pts_s)
        if i and keys[i - 1] == frame.pts_s:
            return  # the same frame twice
        self.pending.insert(i, frame)
        while len(self.pending) > self.capacity:
            self.pending.pop(0)
            self.overflow += 1

    def due_at(self, frame: Arrival) -> float:
        """When a frame is due on the arrival clock (s)."""
        link = self._link
        return (
            frame.pts_s + (frame.arrival_s - frame.pts_s if link is None else link) + self.delay_s
        )

    def media_now(self, now_s: float) -> float | None:
        """The media time due at now (s), None before the first frame."""
        return None if self._link is None else now_s - self._link - self.delay_s

    def take(self, now_s: float) -> Arrival | None:
        """The newest frame due at now_s (None: none is due yet); older due ones are skipped."""
        self._slew(now_s)
        due = [f for f in self.pending if self.due_at(f) <= now_s]
        if not due:
            return None
        newest = due[-1]
        self.skipped += len(due) - 1
        self.pending = self.pending[len(due) :]
        self.shown_pts = newest.pts_s
        return newest

    def discard_due(self, now_s: float) -> int:
        """Frames due at now_s taken away unshown and uncounted (the display is elsewhere on
        purpose: a viewer reviewing what was recorded); returns how many."""
        self._slew(now_s)
        n = sum(1 for f in self.pending if self.due_at(f) <= now_s)
        if n:
            self.shown_pts = self.pending[n - 1].pts_s
            self.pending = self.pending[n:]
        return n

    def newest_pts(self) -> float:
        """The newest frame's presentation time (media s) pushed and kept, -inf before any."""
        return self.pending[-1].pts_s if self.pending else self.shown_pts

    def next_due(self) -> float | None:
        """When the next pending frame is due (s), None when none waits."""
        return self.due_at(self.pending[0]) if self.pending else None
