"""The hub between the drawing loop and the sinks (issue 53): the loop offers each frame's posed
camera (`offer`, never waits), a worker thread with its own off-screen GL context casts the
newest one onto the scene (app.export.records.FootprintCaster: point of interest, footprint) at
most `max_hz` times a second, makes it a SharedFrame (app.share.frames) and hands it to every
sink; the marks go the same way (`set_marks`). A frame offered while the worker is busy replaces
the one waiting: the sinks get the newest, never a backlog.

A sink is anything with `name`, `send_frame(SharedFrame)`, `send_marks(dict)` (a GeoJSON
FeatureCollection, lon/lat) and `close()`; it should hand the work to its own thread or socket
buffer and return. A sink that raises is said once (named) and kept: a receiver that comes back
gets the next frames."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens
from app.camera.pinhole import Camera
from app.core.messages import Messages
from app.core.worker import Worker
from app.export.records import FOOTPRINT_MAX_RANGE_M, FootprintCaster
from app.geodesy.enu import LocalFrame
from app.playback.decoder import planes_to_rgb
from app.scene.mesh import MeshData
from app.share.frames import SharedFrame, shared_frame, thumbnail_jpeg

__all__ = ["Offer", "Share", "Sink"]

DEFAULT_MAX_HZ = 5.0


class Sink(Protocol):
    name: str

    def send_frame(self, frame: SharedFrame) -> None: ...

    def send_marks(self, marks: dict) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Offer:
    """One drawn frame as the loop knows it: its camera (ENU of the hub's frame), video frame
    index, media time (s), UTC (Unix s) or None, clip name, pose source, GNSS status, and its
    picture or None: (H, W, 3) uint8 RGB, or yuv420p planes (y, u, v), converted in the worker
    (the caller hands over arrays it will not write again)."""

    camera: Camera
    index: int
    media_s: float
    utc_s: float | None = None
    clip: str = ""
    source: str = ""
    gnss: str | None = None
    picture: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


class Share(Worker):
    """See the module docstring. mesh and frame: the scene drawn and its local frame; intrinsics
    and lens: the video's camera; clock: monotonic seconds (injected in tests)."""

    def __init__(
        self,
        mesh: MeshData,
        frame: LocalFrame,
        intrinsics: Intrinsics,
        sinks: Sequence[Sink],
        messages: Messages | None = None,
        lens: Lens | None = None,
        max_hz: float = DEFAULT_MAX_HZ,
        max_range_m: float = FOOTPRINT_MAX_RANGE_M,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.sinks = list(sinks)
        self.messages = messages if messages is not None else Messages()
        self.max_hz, self.clock = max_hz, clock
        self.shared = 0  # frames handed to the sinks
        self.offered = 0
        self.last: SharedFrame | None = None
        self._scene = (mesh, frame, intrinsics, lens, max_range_m)
        self._lock = threading.Lock()
        self._pending: Offer | None = None
        self._marks: dict | None = None
        self._last_marks: dict | None = None
        self._busy = False
        self._last_s: float | None = None
        self._failed: set[str] = set()
        super().__init__("share")

    def offer(self, offer: Offer) -> None:
        """Hand the worker a drawn frame; returns at once."""
        with self._lock:
            self._pending = offer
            self.offered += 1
        self._wake.set()

    def due(self) -> bool:
        """Whether a frame offered now would be shared without waiting on the rate limit: a
        caller skips making a frame's picture when it would not."""
        with self._lock:
            return (
                self._last_s is None
                or self.max_hz <= 0
                or self.clock() >= self._last_s + 1.0 / self.max_hz
            )

    def set_marks(self, marks: dict) -> None:
        """Hand the worker the marks (a GeoJSON FeatureCollection, lon/lat); returns at once."""
        with self._lock:
            self._marks = self._last_marks = marks
        self._wake.set()

    def idle(self) -> bool:
        """Nothing waiting and nothing being cast (for tests' waits and for closing)."""
        with self._lock:
            return self._pending is None and self._marks is None and not self._busy

    def add_sink(self, sink: Sink) -> None:
        """Share with one more sink from the next frame on (its marks sent at once)."""
        self.sinks = [*self.sinks, sink]  # a new list: the worker may be walking the old one
        if self._last_marks is not None:
            self.set_marks(self._last_marks)

    def remove_sink(self, sink: Sink) -> None:
        """Stop sharing with a sink, and close it."""
        self.sinks = [s for s in self.sinks if s is not sink]
        self._each(sink, "close", lambda s: s.close())

    def close(self) -> None:
        """Stop the worker, then close every sink."""
        self.stop()
        for sink in self.sinks:
            self._each(sink, "close", lambda s: s.close())

    def _each(self, sink: Sink, what: str, call: Callable[[Sink], None]) -> None:
        try:
            call(sink)
        except Exception as exc:  # a sink's fault is said, never the loop's end
            key = f"{sink.name}:{what}"
            if key not in self._failed:
                self._failed.add(key)
                self.messages.add(f"sharing to {sink.name}: {what} failed: {exc}")

    def _take(self) -> tuple[Offer | None, dict | None, float]:
        """The offer due now (None while the rate limit holds it), the marks, and how long to
        sleep before the held offer is due."""
        with self._lock:
            marks, self._marks = self._marks, None
            offer, wait = None, 0.0
            if self._pending is not None:
                now = self.clock()
                due = (
                    now
                    if self._last_s is None or self.max_hz <= 0
                    else self._last_s + 1.0 / self.max_hz
                )
                if now >= due:
                    offer, self._pending, self._last_s = self._pending, None, now
                else:
                    wait = due - now
            self._busy = offer is not None or marks is not None
            return offer, marks, wait

    def _run(self) -> None:
        mesh, frame, intrinsics, lens, max_range_m = self._scene
        caster = FootprintCaster(mesh, frame, intrinsics, max_range_m, lens)
        try:
            while not self._stop.is_set():
                offer, marks, wait = self._take()
                if marks is not None:
                    for sink in self.sinks:
                        self._each(sink, "marks", lambda s, m=marks: s.send_marks(m))
                if offer is not None:
                    self._share(caster, offer)
                with self._lock:
                    self._busy = False
                if offer is None and marks is None:
                    self._wake.wait(min(wait, 0.05) if wait > 0 else None)
                    self._wake.clear()
        finally:
            caster.release()

    def _share(self, caster: FootprintCaster, offer: Offer) -> None:
        record = caster.record(
            offer.camera, offer.index, offer.media_s, offer.media_s, offer.utc_s, offer.clip
        )
        if offer.gnss is not None:
            record = replace(record, gnss=offer.gnss)
        picture = offer.picture
        if isinstance(picture, tuple):
            picture = planes_to_rgb(picture)
        thumb = thumbnail_jpeg(picture) if picture is not None else None
        shared = shared_frame(record, offer.source, thumb)
        self.last = shared
        self.shared += 1
        for sink in self.sinks:
            self._each(sink, "frame", lambda s: s.send_frame(shared))
