"""The scene memory in the viewer: what the open clip and the further clips on its timeline saw,
painted onto the scene's surfaces in the background, and shown as the Model, the Memory, when
each part was seen ("seen at") or what changed since the model, as it was at the timeline's
moment. The live drape (the Projection panel's "project the video") draws over any of them.

A MemoryPainter thread lays out the atlas (app.export.atlas, at most max_texels texels, each
triangle's texels in proportion to what the painting cameras' pixels cover there,
app.export.sampling, scaled up alike to fit), then
paints the clips' frames in timeline order (a frame every `every_s` s of each clip's video, its
camera under the source chosen when painting began; app.export.painting) into one SurfaceMemory
with a history of HISTORY_EPOCHS epochs over the clips' span, on an EGL context of its own; its
time is timeline seconds. On a scene of 3D Tiles it paints the tiles the clips' cameras need,
frozen (app.scene.tiles.freeze), and while the memory is shown it stands for the streamed layers,
which are not drawn. Between frames, and once done whenever the view or the timeline moves, it
composes the atlas texture the frame loop asks for (app.export.memory_view); the frame loop only
uploads it (`update`). The memory's size is fixed by the atlas, whatever the clips' length.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from app.core.worker import Worker
from app.export.atlas import Atlas, layout, triangles_of
from app.export.memory import RULES, SurfaceMemory
from app.export.memory_view import VIEWS, as_at, seen_range, snapshot_colours
from app.export.painting import (
    DECODE_LONG_SIDE,
    DEFAULT_EVERY_S,
    ClipToPaint,
    paint_frame_indices,
    paint_frames,
    planned_cameras,
    scene_to_paint,
)
from app.export.sampling import texel_targets
from app.render.views import ModelViews
from app.scene.mesh import MeshData

DEFAULT_MAX_TEXELS = 2_000_000  # the viewer's atlas (GPU and CPU memory bounded by it)
HISTORY_EPOCHS = 16  # the time slider's memory of the past: the newest sighting in each 16th
COMPOSE_EVERY_S = 0.25  # while painting, a new texture at most this often (real seconds)


class _Stopped(Exception):
    """The painting was asked to stop (the session closed, painting began again)."""


class MemoryPainter(Worker):
    """See the module docstring. Call request/take/stop from the frame loop's thread."""

    def __init__(
        self,
        mesh: MeshData,
        clips: list[ClipToPaint],
        rule: str = "newest",
        every_s: float = DEFAULT_EVERY_S,
        max_texels: int = DEFAULT_MAX_TEXELS,
    ) -> None:
        if rule not in RULES:
            raise ValueError(f"rule {rule!r}: expected one of {', '.join(RULES)}")
        self.mesh, self.clips, self.rule = mesh, clips, rule
        self.every_s, self.max_texels = every_s, max_texels
        self.atlas: Atlas | None = None  # set once laid out (read-only after)
        self.memory: SurfaceMemory | None = None  # the painter thread's only
        self.frames_total = 0
        self.frames_painted = 0
        self.done = False
        self.error: str | None = None
        self.range_s: tuple[float, float] | None = None  # the sightings the last texture shows
        self._lock = threading.Lock()
        self._finished = threading.Event()
        self._request: tuple[str, float | None] = ("memory", None)
        self._texture: np.ndarray | None = None
        self._texture_for: tuple[str, float | None] | None = None
        self._composed_for: tuple[tuple[str, float | None], int] | None = None
        self._composed_at = -np.inf  # when the painting last composed (monotonic s)
        self.shown_for: tuple[str, float | None] | None = None  # the request of the last taken
        super().__init__("geofuse-memory")

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until painting is done (or failed); True when it is."""
        return self._finished.wait(timeout_s)

    @property
    def covers_tiles(self) -> bool:
        """The atlas holds the 3D Tiles the clips' cameras needed (frozen), standing for them."""
        return bool(self.mesh.tilesets)

    @property
    def nbytes(self) -> int:
        """Bytes the memory and its atlas's samples hold (0 before the layout)."""
        if self.memory is None or self.atlas is None:
            return 0
        return self.memory.nbytes + self.atlas.base.nbytes + self.atlas.pixels.nbytes

    @property
    def progress(self) -> float:
        return 1.0 if self.done else self.frames_painted / max(1, self.frames_total)

    def request(self, view: str, at_s: float | None) -> None:
        """The texture wanted: `view` (app.export.memory_view.VIEWS, not model) of the memory as
        it was at at_s (timeline s; None: as it is)."""
        if view not in VIEWS or view == "model":
            raise ValueError(f"view {view!r}: expected one of {', '.join(VIEWS[1:])}")
        with self._lock:
            if self._request != (view, at_s):
                self._request = (view, at_s)
                self._wake.set()

    def take(self) -> np.ndarray | None:
        """The texture composed since the last take ((H, W, 4) uint8, bottom row first), or None."""
        with self._lock:
            tex, self._texture = self._texture, None
            if tex is not None:
                self.shown_for = self._texture_for
            return tex

    def current(self) -> bool:
        """Painting is done and the last texture taken is the one last requested."""
        with self._lock:
            return self.done and self.shown_for == self._request and self._texture is None

    # --- the painter thread ----------------------------------------------------------------------

    def _run(self) -> None:
        views = None
        try:
            plan = [paint_frame_indices(c.track, self.every_s) for c in self.clips]
            cameras = planned_cameras(self.clips, plan)
            scene = scene_to_paint(self.mesh, cameras)
            texels = texel_targets(triangles_of(scene).corners, cameras, DECODE_LONG_SIDE)
            atlas = layout(scene, self.max_texels, texels)
            self.frames_total = int(sum(len(p) for p in plan))
            if not self.frames_total:
                raise ValueError("the clips have no frames to paint")
            times = np.concatenate([c.times[p] for c, p in zip(self.clips, plan, strict=True)])
            span = (float(times.min()), float(times.max()), HISTORY_EPOCHS)
            self.memory = SurfaceMemory(atlas.points, atlas.normals, self.rule, span)
            self.atlas = atlas
            views = ModelViews(scene)
            paint_frames(self.memory, views, self.clips, plan, progress=self._painted)
            self._compose()
            self.done = True
        except _Stopped:
            return
        except Exception as exc:  # shown by the viewer, which goes on without a memory
            self.error = f"scene memory: {exc}"
            self.done = True
            return
        finally:
            if views is not None:
                views.release()
            self._finished.set()
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            self._compose()

    def _painted(self, fraction: float) -> None:
        """After each frame (paint_frames' progress): counted, a texture now and then; stops
        the painting when asked to."""
        self.frames_painted += 1
        if self._stop.is_set():
            raise _Stopped
        if time.monotonic() - self._composed_at >= COMPOSE_EVERY_S:
            self._compose()
            self._composed_at = time.monotonic()

    def _compose(self) -> None:
        """The texture for the current request, unless the last one composed is it and nothing
        was painted since."""
        with self._lock:
            request = self._request
        key = (request, self.frames_painted)
        if key == self._composed_for or self.memory is None:
            return
        view, at_s = request
        snap = as_at(self.memory, at_s)  # once: the colours and the range shown both need it
        texture = self.atlas.texture(
            snapshot_colours(snap, self.atlas.base, view, at_s, self.atlas.triangle)
        )
        span = seen_range(snap)
        with self._lock:
            self._texture, self._texture_for, self.range_s = texture, request, span
        self._composed_for = key


# --- the viewer's side (v: app.ui.viewer.Viewer) -------------------------------------------------

PAINT_WAIT_S = 900.0  # a script's `wait painted` gives up after this long (real seconds)


def start(v, rule: str = "newest", every_s: float = DEFAULT_EVERY_S) -> None:
    """Paint the open clip and the further clips shown on its timeline (a frame every every_s s
    of each), each under its source's track as solved now, into a new memory (the previous one
    is dropped)."""
    if not every_s >= 0:
        raise ValueError(f"EVERY_S: expected seconds >= 0, got {every_s}")
    L = v.loaded
    track = L.library.track(L.source)
    if track is None:
        raise ValueError(f"the source {L.source} is not solved yet: paint once it is")
    todo = [ClipToPaint(L.session, track, L.timeline.clips[0].times)]
    for clip, span in zip(L.others, L.timeline.clips[1:], strict=True):
        if not clip.visible:
            continue
        other = clip.library.track(clip.source)
        if other is None:
            v.ui.info.append(f"scene memory: {span.name} is not solved yet and is not painted")
            continue
        todo.append(ClipToPaint(clip.session, other, span.times, clip.move))
    painter = MemoryPainter(L.renderer.scene.mesh, todo, rule, every_s)  # refuses a bad rule
    close(L)
    L.memory = painter.start()
    L.renderer.scene.set_memory(None)
    if v.ui.memory_view == "model":
        v.ui.memory_view = "memory"


def set_view(v, view: str) -> None:
    """Show the scene as `view` (app.export.memory_view.VIEWS); painting starts if not begun."""
    if view not in VIEWS:
        raise ValueError(f"expected one of {', '.join(VIEWS)}, got {view!r}")
    v.ui.memory_view = view
    if view != "model" and v.loaded.memory is None:
        start(v)


def update(v) -> None:
    """Each frame: the memory's primitive once laid out, the texture for the view and the
    timeline's moment asked for, the last one composed uploaded; errors shown once."""
    L = v.loaded
    p = L.memory
    scene = L.renderer.scene
    if p is None:
        scene.show_memory = False
        return
    if p.error:
        v.ui.error(p.error)
    if scene.memory is None and p.atlas is not None:
        scene.set_memory(p.atlas.primitive(p.atlas.base), replaces_tiles=p.covers_tiles)
    view = v.ui.memory_view
    scene.show_memory = view != "model" and scene.memory is not None
    if view != "model":
        k = v.current_index
        p.request(view, float(L.timeline.clips[0].times[k]) if k >= 0 else None)
    texture = p.take()
    if texture is not None and scene.memory is not None:
        scene.write_memory_texture(texture)


def wait_painted(v) -> None:
    """Hold the script until the memory is painted and the view asked for is on screen."""
    p = v.loaded.memory
    if p is None:
        raise ValueError("nothing is being painted: `memory paint` first")
    v.hold_script(lambda: v.loaded is not None and p.current(), "the scene memory", PAINT_WAIT_S)


def close(loaded) -> None:
    if loaded.memory is not None:
        loaded.memory.stop()
        loaded.memory = None


def state(loaded) -> dict | None:
    """What a script's `state` says of the memory."""
    p = loaded.memory
    if p is None:
        return None
    m = p.memory
    return {
        "progress": p.progress,
        "done": p.done,
        "error": p.error,
        "frames": p.frames_painted,
        "clips": len(p.clips),
        "rule": p.rule,
        "texel_m": None if p.atlas is None else p.atlas.texel_m,
        "samples": None if m is None else len(m.points),
        "seen": None if m is None or not p.done else int(m.seen.sum()),
        "mb": None if m is None else p.nbytes / 1e6,
        "range_s": p.range_s,
    }
