"""The render thread's side of playback, without GL: the clock, the decoder's queue, which frame
is due, and the playback latency of each frame as the paper defines it (due time -> first
display). The viewer and the off-screen playback benchmark both drive this.

The frame due is chosen for the moment it will appear, not the moment the loop starts: the loop
looks ahead by its own recent render time (an exponential average), the way a player schedules a
frame for its presentation time. Latencies are recorded signed: a frame shown early counts as
negative, not as zero.

Nothing here reads a clock: every call takes `now` (seconds) from the caller. A scripted run on a
fixed-step clock passes `wait_s` to `tick`, which then waits for the decoder to deliver the frame
due, so that each tick shows exactly the frame due whatever the machine's speed; the viewer on
the wall clock never waits (wait_s = 0) and drops frames instead.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass, field

import numpy as np

from app.io.video import VideoInfo
from app.playback.clock import FrameSchedule, PlaybackClock
from app.playback.decoder import DecodedFrame, Decoder

LOOKAHEAD_SMOOTHING = 0.1  # weight of the newest render time in the look-ahead average


@dataclass
class PlayerStats:
    latencies: list[float] = field(default_factory=list)  # seconds, signed
    dropped: int = 0

    def summary(self) -> tuple[float, float, float]:
        """(current, mean, 95th percentile) latency in milliseconds over the last 2000 frames."""
        if not self.latencies:
            return 0.0, 0.0, 0.0
        a = np.asarray(self.latencies[-2000:]) * 1000.0
        return float(a[-1]), float(a.mean()), float(np.percentile(a, 95))


class Player:
    """Plays one video: its frames' media times (video.pts_s, display order) on a PlaybackClock."""

    def __init__(self, video: VideoInfo, loop: bool = True) -> None:
        pts = np.asarray(video.pts_s, np.float64)
        self.schedule = FrameSchedule(pts)
        self.clock = PlaybackClock(duration=float(pts[-1]), loop=loop, paused=True)
        self.decoder = Decoder(video.path, video.origin_s)
        self.current: DecodedFrame | None = None
        self.index = -1
        self.stats = PlayerStats()
        self.lookahead_s = 0.0
        self._pending: DecodedFrame | None = None
        self._fresh: tuple[int, float] | None = None  # (frame index, due wall time) not yet shown
        self._last_shown = -1
        self._serial_seen = 0

    # --- control --------------------------------------------------------------------------------

    def seek(self, media_time: float, now: float) -> None:
        self.clock.seek(media_time, now)
        self._restart(now)

    def step(self, frames: int, now: float) -> None:
        self.clock.set_paused(True, now)
        self.seek(float(self.schedule.pts[self.schedule.step(max(self.index, 0), frames)]), now)

    def _restart(self, now: float) -> None:
        self.decoder.seek(self.clock.time(now), self.clock.serial)
        self._pending = None
        self._last_shown = -1
        self._serial_seen = self.clock.serial

    def close(self) -> None:
        self.decoder.close()

    # --- the frame loop -------------------------------------------------------------------------

    def due_index(self, now: float) -> int:
        """The frame due at `now` (media time plus the look-ahead while playing)."""
        return self.schedule.due(self._target(now))

    def _target(self, now: float) -> float:
        return self.clock.time(now) + (
            0.0 if self.clock.paused else self.lookahead_s * self.clock.speed
        )

    def tick(self, now: float, wait_s: float = 0.0) -> bool:
        """Advance to the frame due when this tick's image will appear; True if it changed.
        wait_s > 0: wait up to that long (real seconds) for the decoder to deliver it."""
        self.clock.time(now)
        if self.clock.serial != self._serial_seen:  # the clock looped: decode from the start again
            self._restart(now)
        target = self._target(now)
        self.decoder.due_s = target
        due_index = self.schedule.due(target)
        changed = False
        while True:
            if self._pending is None:
                try:
                    behind = (
                        self.current is None
                        or self.current.serial != self.clock.serial
                        or self.schedule.due(self.current.pts_s) < due_index
                    )
                    waiting = (
                        wait_s > 0
                        and behind
                        and self.decoder.error is None
                        and not (self.decoder.at_end and self.decoder.frames.empty())
                    )
                    item = (
                        self.decoder.frames.get(timeout=wait_s)
                        if waiting
                        else self.decoder.frames.get_nowait()
                    )
                except queue.Empty:
                    return changed
                if item is None or item.serial != self.clock.serial:
                    continue  # decoded before the last seek
                self._pending = item
            first_after_seek = self.current is None or self.current.serial != self.clock.serial
            if self._pending.pts_s > target + 1e-6 and not first_after_seek:
                return changed
            self.current, self._pending = self._pending, None
            index = self.schedule.due(self.current.pts_s)
            if index != self.index:
                self.index = index
                due = (
                    now
                    if self.clock.paused
                    else self.clock.wall_time_of(float(self.schedule.pts[index]), now)
                )
                self._fresh = (index, due)
                changed = True

    def next_due_wall(self, now: float) -> float | None:
        """Wall time at which the frame after the current one becomes due (None when paused or
        at the end): a loop with nothing else to draw can sleep until then, less its look-ahead."""
        if self.clock.paused or self.index < 0 or self.index + 1 >= len(self.schedule.pts):
            return None
        return self.clock.wall_time_of(float(self.schedule.pts[self.index + 1]), now)

    def shown(self, now: float, render_s: float) -> None:
        """The tick's image appeared at `now`; render_s: how long the tick took to draw."""
        self.lookahead_s += LOOKAHEAD_SMOOTHING * (render_s - self.lookahead_s)
        if self._fresh is None:
            return
        index, due = self._fresh
        if not self.clock.paused:
            if self._last_shown >= 0 and index > self._last_shown + 1:
                self.stats.dropped += index - self._last_shown - 1
            self.stats.latencies.append(now - due)
        self._last_shown = index
        self._fresh = None
