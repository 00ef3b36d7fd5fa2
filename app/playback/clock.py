"""The playback clock: pts + speed + serial, driven by the wall time the caller passes in.

Media time advances as accumulated wall time times the playback speed; pause holds it; a seek
sets it and bumps the serial so stale decoded frames can be recognised and dropped (ffplay's
design). Nothing here reads a clock: tests drive time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.camera.frame_time import frame_at

SPEEDS = (0.25, 0.5, 1.0, 1.5, 2.0, 4.0)


@dataclass
class PlaybackClock:
    """Media time in seconds from the first frame, over [0, duration]."""

    duration: float
    speed: float = 1.0
    paused: bool = False
    loop: bool = True
    serial: int = 0
    _media: float = 0.0
    _wall: float | None = None

    def time(self, now: float) -> float:
        """Media time at wall time `now` (seconds), advancing the clock to `now`."""
        if self._wall is None:
            self._wall = now
        if not self.paused:
            self._media += max(0.0, now - self._wall) * self.speed
            if self._media > self.duration:
                if self.loop and self.duration > 0:
                    self._media %= self.duration
                    self.serial += 1
                else:
                    self._media = self.duration
                    self.paused = True
        self._wall = now
        return self._media

    def wall_time_of(self, media_time: float, now: float) -> float:
        """The wall time at which media time `media_time` is (or was) due, at the current speed."""
        current = self.time(now)
        return now + (media_time - current) / self.speed

    def seek(self, media_time: float, now: float) -> None:
        self.time(now)
        self._media = float(np.clip(media_time, 0.0, self.duration))
        self.serial += 1

    def set_paused(self, paused: bool, now: float) -> None:
        self.time(now)
        self.paused = paused

    def set_speed(self, speed: float, now: float) -> None:
        if not 0.25 <= speed <= 4.0:
            raise ValueError(f"speed must be in [0.25, 4], got {speed}")
        self.time(now)
        self.speed = speed


@dataclass
class FrameSchedule:
    """Which frame is due at a media time, from the frames' media times (sorted, seconds)."""

    pts: np.ndarray
    shown: set[int] = field(default_factory=set)

    def due(self, media_time: float) -> int:
        """Index of the last frame whose time is <= media_time (0 before the first)."""
        return frame_at(self.pts, media_time)

    def step(self, index: int, frames: int) -> int:
        return int(np.clip(index + frames, 0, len(self.pts) - 1))
