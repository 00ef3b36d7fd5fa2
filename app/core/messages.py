"""Messages for people: one thread-safe, append-only channel per session, with levels.

- info: what is merely reported (a lens profile chosen, the magnetometer calibrated, a time
  offset applied);
- warning: what lowers the result (no lens profile, a GNSS gap, samples dropped, stabilised
  video, a scene far from the track);
- error: what stops a part of the work (a source that failed to solve).

Readers, assembly and solvers add to it (the solver library from its worker thread); the CLI
prints every message with its level, and the viewer shows each as it comes (`since`), so what a
background solve finds reaches the person. The channel is the one mutable thing a frozen Session
holds.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

INFO, WARNING, ERROR = "info", "warning", "error"
LEVELS = (INFO, WARNING, ERROR)


@dataclass(frozen=True)
class Message:
    level: str
    text: str

    def __str__(self) -> str:
        return f"{'note' if self.level == INFO else self.level}: {self.text}"


@dataclass
class Messages:
    """The channel. `add` (a warning unless a level is given), `info`, `error`; `add_once` adds a
    message under a key only the first time (solving the same source twice must not repeat its
    messages); `since(n)` the messages after the first n; `items` their texts."""

    _messages: list[Message] = field(default_factory=list)
    _keys: set[str] = field(default_factory=set)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, text: str, level: str = WARNING) -> None:
        if level not in LEVELS:
            raise ValueError(f"level must be one of {', '.join(LEVELS)}, got {level!r}")
        with self._lock:
            self._messages.append(Message(level, text))

    def info(self, text: str) -> None:
        self.add(text, INFO)

    def error(self, text: str) -> None:
        self.add(text, ERROR)

    def add_once(self, key: str, text: str, level: str = WARNING) -> None:
        with self._lock:
            if key in self._keys:
                return
            self._keys.add(key)
            self._messages.append(Message(level, text))

    def extend(self, other: Messages) -> None:
        for m in other.since(0):
            self.add(m.text, m.level)

    def since(self, n: int) -> list[Message]:
        """The messages after the first n (a reader keeps its count and asks again)."""
        with self._lock:
            return list(self._messages[n:])

    @property
    def items(self) -> list[str]:
        """Every message's text, in order."""
        return [m.text for m in self.since(0)]

    def of(self, level: str) -> list[str]:
        """The texts of one level."""
        return [m.text for m in self.since(0) if m.level == level]

    def __len__(self) -> int:
        with self._lock:
            return len(self._messages)
