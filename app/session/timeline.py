"""One timeline for several clips (issue 22): where each clip's frames fall on a shared clock.

Timeline seconds count from the earliest clip's first frame. A clip whose clock is absolute
(Session.utc_of: a GoPro's GPS time, a DJI subtitle's dates, a Unix-time log) is placed at its
true time, so two such clips filmed at once play together frame for frame; a clip without one
starts with the earliest. Each clip may be moved by its own offset (seconds, the viewer's or the
manifest's). Outside its span a clip shows nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from app.camera.frame_time import frame_at
from app.session.model import Session

__all__ = ["ClipSpan", "Timeline"]


@dataclass(frozen=True)
class ClipSpan:
    """One clip on the timeline: name; times (F,) timeline seconds of each of its frames;
    absolute: placed by its own UTC clock; offset_s: the move applied on top."""

    name: str
    times: np.ndarray
    absolute: bool
    offset_s: float = 0.0

    @property
    def start_s(self) -> float:
        return float(self.times[0])

    @property
    def end_s(self) -> float:
        return float(self.times[-1])

    def frame_at(self, t: float) -> int | None:
        """The frame shown at timeline time t (the last at or before it), None outside the
        span (before its first frame, or more than one frame interval after its last)."""
        if t < self.times[0] - 1e-6 or t > self.times[-1] + self.step_s:
            return None
        return frame_at(self.times, t)

    @cached_property
    def step_s(self) -> float:
        """The clip's usual frame interval (s): how long its last frame stays shown."""
        return float(np.median(np.diff(self.times))) if len(self.times) > 1 else 0.0


@dataclass(frozen=True)
class Timeline:
    """The clips on one clock; utc0: the UTC (Unix s) of timeline time 0 where any clip has a
    clock, else None."""

    clips: tuple[ClipSpan, ...]
    utc0: float | None

    @classmethod
    def of(cls, sessions: list[Session], offsets_s: list[float] | None = None) -> Timeline:
        """The sessions' clips placed as the module docstring says."""
        offsets = list(offsets_s or [0.0] * len(sessions))
        utc = [
            None
            if s.utc_of(float(s.frame_times[0])) is None
            else np.array([s.utc_of(float(t)) for t in s.frame_times])
            for s in sessions
        ]
        starts = [u[0] for u in utc if u is not None]
        utc0 = min(starts) if starts else None
        clips = []
        for s, u, off in zip(sessions, utc, offsets, strict=True):
            local = np.asarray(s.frame_times, np.float64)
            times = (u - utc0) if u is not None else local - local[0]
            clips.append(ClipSpan(Path(s.video.path).name, times + off, u is not None, off))
        return cls(tuple(clips), utc0)

    @property
    def duration_s(self) -> float:
        return max(c.end_s for c in self.clips) - min(0.0, min(c.start_s for c in self.clips))

    def frames_at(self, t: float) -> list[int | None]:
        """Each clip's frame shown at timeline time t (None: the clip shows nothing then)."""
        return [c.frame_at(t) for c in self.clips]
