"""Background threads. `Worker`: one daemon thread running the subclass's `_run` until `stop()`,
with the two events such loops wait on (`_wake`: something to do; `_stop`: finish); used by the
live registration and lag estimator (app.live) and the viewer's scene memory (app.ui.memory).
`OneShot`: one job run once on a daemon thread, its failure kept as a line for the viewer; used
by the viewer's opening of a session and its sync (app.ui)."""

from __future__ import annotations

import logging
import threading
from typing import Self

from app.core.errors import GeofuseError

log = logging.getLogger("geofuse.viewer")


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


class OneShot:
    """Subclasses define `_work()` (and may name what failed, `_failed()`); `start()` runs it on a
    daemon thread named `name`, `run()` on the calling thread. A GeofuseError it raises becomes
    `error` (its one line), any other exception "WHAT: TYPE: TEXT" (logged with its traceback):
    the viewer shows it and keeps running. `done` once it returned or failed."""

    def __init__(self, name: str) -> None:
        self.error: str | None = None
        self._name = name
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    def _work(self) -> None:
        raise NotImplementedError

    def _failed(self) -> str:
        """What failed, for an unexpected exception's line."""
        return f"{self._name} failed"

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def start(self) -> Self:
        self._thread = threading.Thread(target=self.run, name=self._name, daemon=True)
        self._thread.start()
        return self

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until done, at most timeout seconds; True when it is."""
        return self._done.wait(timeout)

    def run(self) -> None:
        """Do the work on the calling thread."""
        try:
            self._work()
        except GeofuseError as exc:
            self.error = str(exc)
            log.error("%s", exc)
        except Exception as exc:  # an unexpected failure is still only an error panel entry
            self.error = f"{self._failed()}: {type(exc).__name__}: {exc}"
            log.exception("%s", self._failed())
        finally:
            self._done.set()
