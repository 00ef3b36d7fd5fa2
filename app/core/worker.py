"""A background worker: one daemon thread running the subclass's `_run` until `stop()`, with the
two events such loops wait on (`_wake`: something to do; `_stop`: finish). Used by the live
registration and lag estimator (app.live) and the viewer's scene memory (app.ui.memory)."""

from __future__ import annotations

import threading
from typing import Self


class Worker:
    """Subclasses call `super().__init__(name)` once their state is set, and define `_run`."""

    def __init__(self, name: str) -> None:
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def start(self) -> Self:
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        """Ask the loop to finish and wait for it, at most timeout_s seconds."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout_s)
