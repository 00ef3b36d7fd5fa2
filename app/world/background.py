"""A world built in the background, as a 3D Tiles layer streams: a coarse level first, then
the full one, each handed over as soon as it is had, so that whoever shows it (the viewer:
app.ui.world) keeps drawing meanwhile and never waits on the network.

The coarse level reads each source COARSE_LEVELS levels coarser than its full level (about 1/64
of the tiles); the full level, at the clip's ground sampling, is what a command that writes
files builds (app.world.build.resolve_worlds), buildings included. Both go through the same tile
cache, so a warm cache hands both over at once. Faults are said once per source (app.world.fetch counts
them; a second level's are the same source's). One daemon thread; `cancel()` returns at once:
tiles not asked for yet are not asked for, the requests under way end within their time-out,
and nothing more is handed over. Pure: no GL, no window.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

from app.core.messages import Messages
from app.core.worker import Worker
from app.scene.layers import Layer
from app.world.build import WorldRequest, build_world

log = logging.getLogger("geofuse.world")
COARSE_LEVELS = 3  # the first level drawn: pixels 8x the size the clip's sampling asks for


@dataclass(frozen=True)
class WorldLevel:
    """One level of one request built: index into the requests, coarse (the first look) or
    full, and its layers (a DEM draped with its orthophoto, buildings; () where none was had)."""

    index: int
    coarse: bool
    layers: tuple[Layer, ...]


@dataclass(frozen=True)
class Progress:
    """Where the build stands: the level under way ('coarse', 'full'; 'done', 'cancelled'),
    its tiles to fetch and done so far, and the levels handed over."""

    level: str
    tiles: int
    done: int
    handed: int


class WorldBuilder(Worker):
    """Builds each request coarse then full on one daemon thread (`start()`), calling
    on_level(WorldLevel) there for each (see the module docstring); what on_level raises is said
    in `messages` and the build goes on."""

    def __init__(
        self,
        requests: list[WorldRequest],
        messages: Messages,
        on_level: Callable[[WorldLevel], None],
        coarse_levels: int = COARSE_LEVELS,
    ) -> None:
        self.requests = list(requests)
        self.messages = messages
        self.on_level = on_level
        self.coarse_levels = int(coarse_levels)
        self._finished = threading.Event()
        self._lock = threading.Lock()
        self._progress = Progress("coarse", 0, 0, 0)
        super().__init__("geofuse-world")

    def cancel(self) -> None:
        """Stop building (the viewer closed, or opened another session); returns at once."""
        self._stop.set()

    @property
    def finished(self) -> bool:
        """Every level handed over (or the build cancelled and its thread ended)."""
        return self._finished.is_set()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until finished, at most timeout_s seconds; True when it is."""
        return self._finished.wait(timeout_s)

    @property
    def progress(self) -> Progress:
        with self._lock:
            return self._progress

    def _set(self, **changes) -> None:
        with self._lock:
            p = self._progress
            self._progress = Progress(**{**p.__dict__, **changes})

    def _run(self) -> None:
        try:
            for index, request in enumerate(self.requests):
                for coarser in (self.coarse_levels, 0) if self.coarse_levels else (0,):
                    if self._stop.is_set():
                        return
                    self._set(level="coarse" if coarser else "full", tiles=0, done=0)
                    layers = build_world(
                        request,
                        self.messages,
                        coarser=coarser,
                        stop=self._stop.is_set,
                        tiles=lambda done, total: self._set(done=done, tiles=total),
                    )
                    if self._stop.is_set():
                        return
                    try:
                        self.on_level(WorldLevel(index, bool(coarser), layers))
                    except Exception as exc:  # a thread boundary: said, and the build goes on
                        log.exception("world level")
                        self.messages.add(
                            f"world {request.world.name}: its {'coarse' if coarser else 'full'} level could not be shown: {type(exc).__name__}: {exc}"
                        )
                    self._set(handed=self.progress.handed + 1)
        except Exception as exc:  # never a crash of the viewer: said once
            log.exception("world build")
            self.messages.add(f"the world could not be built: {type(exc).__name__}: {exc}")
        finally:
            self._set(level="cancelled" if self._stop.is_set() else "done")
            self._finished.set()
