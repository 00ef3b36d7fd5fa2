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
frozen (app.scene.tiles.freeze), and while the memory is shown it is drawn over the streamed
layers, which stay where the clips never looked. Between frames, and once done whenever the view or the timeline moves, it
composes the atlas texture the frame loop asks for (app.export.memory_view); the frame loop only
uploads it (`update`). The memory's size is fixed by the atlas, whatever the clips' length.

Where the video's ground sampling asks for more than PAGE_ABOVE times max_texels (a district,
a long survey: one atlas would be more than 4 times coarser a side than the video), the memory is
paged instead (app.export.paged: each triangle at the texel its pixels cover, pages of
512 x 512 texels made when a frame first meets them, at most resident_mb held in CPU memory, the
least recently used spilled to disk and read back): the frame loop names the pages the window's
view meets, nearest first (`pages_in_view`), and the painter composes those that were painted,
the nearest fine_pages at full detail and the farther ones COARSE times coarser, at most
gpu_mb of page textures on the GPU; they are drawn over the model (app.render.gpu_scene), which
shows wherever no page is held (never painted, out of view).
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import cv2
import numpy as np

from app.core.worker import Worker
from app.export.atlas import Atlas, chart_sizes, layout, triangles_of
from app.export.memory import RULES, SurfaceMemory
from app.export.memory_view import VIEWS, as_at, seen_range, snapshot_colours
from app.export.paged import DEFAULT_RESIDENT_MB, PAGE_TEXELS, PagedMemory, pages_in_view
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
from app.scene.mesh import MeshData, Primitive

DEFAULT_MAX_TEXELS = 2_000_000  # the viewer's atlas (GPU and CPU memory bounded by it)
HISTORY_EPOCHS = 16  # the time slider's memory of the past: the newest sighting in each 16th
COMPOSE_EVERY_S = 0.25  # while painting, a new texture at most this often (real seconds)
DEFAULT_GPU_MB = 96.0  # a paged memory's page textures on the GPU at most (mipmaps included)
COARSE = 8  # a page beyond the nearest fine_pages: its texture this many times coarser a side
PAGES_WHILE_PAINTING = 4  # pages composed at most between two painted frames
# pages where one atlas within max_texels would be more than this many times the texels the
# video's sampling asks for (4 times coarser a side); below it, one atlas scaled up alike
PAGE_ABOVE = 16
PagesTaken = tuple[dict[int, Primitive], set[int]]


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
        resident_mb: float = DEFAULT_RESIDENT_MB,
        gpu_mb: float = DEFAULT_GPU_MB,
    ) -> None:
        if rule not in RULES:
            raise ValueError(f"rule {rule!r}: expected one of {', '.join(RULES)}")
        self.mesh, self.clips, self.rule = mesh, clips, rule
        self.every_s, self.max_texels = every_s, max_texels
        self.resident_bytes = resident_mb * 1e6
        page_gpu_bytes = PAGE_TEXELS * 4 * 4 / 3  # a full page's texture with its mipmaps
        self.fine_pages = max(1, int(gpu_mb * 1e6 / (page_gpu_bytes * (1 + 3 / COARSE**2))))
        self.max_pages = 4 * self.fine_pages  # the rest coarse: within gpu_mb all together
        self.atlas: Atlas | None = None  # set once laid out (read-only after)
        self.memory: SurfaceMemory | PagedMemory | None = None  # the painter thread's only
        # a paged memory's page boxes (lo, hi (P, 3) ENU m), set once laid out; None: one atlas
        self.boxes: tuple[np.ndarray, np.ndarray] | None = None
        self.page_stats = None  # a paged memory's PageStats (the painter thread's; read to say)
        self.frames_total = 0
        self.frames_painted = 0
        self.done = False
        self.error: str | None = None
        self.range_s: tuple[float, float] | None = None  # the sightings the last texture shows
        self._lock = threading.Lock()
        self._finished = threading.Event()
        self._request: tuple[str, float | None] = ("memory", None)
        self._wanted: tuple[int, ...] = ()  # the pages the view meets, nearest first
        self._pages: dict[int, Primitive] = {}  # composed since the last take_pages
        self._keep: set[int] | None = None  # the pages the view shows, composed or held
        self._sent: dict[int, tuple] = {}  # what each page last composed was composed for
        self._ranges: dict[int, tuple[float, float] | None] = {}  # each page's sightings shown
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
        """The atlas holds the 3D Tiles the clips' cameras needed (frozen): drawn over the
        streamed ones (app.render.gpu_scene)."""
        return bool(self.mesh.tilesets)

    @property
    def nbytes(self) -> int:
        """Bytes the memory and its atlas's samples hold (0 before the layout; paged: the pages
        held)."""
        if isinstance(self.memory, PagedMemory):
            return self.memory.nbytes
        if self.memory is None or self.atlas is None:
            return 0
        return self.memory.nbytes + self.atlas.base.nbytes + self.atlas.pixels.nbytes

    @property
    def progress(self) -> float:
        return 1.0 if self.done else self.frames_painted / max(1, self.frames_total)

    def request(self, view: str, at_s: float | None, wanted: tuple[int, ...] = ()) -> None:
        """The texture wanted: `view` (app.export.memory_view.VIEWS, not model) of the memory as
        it was at at_s (timeline s; None: as it is); paged: of the pages `wanted` (those the
        view meets, nearest first)."""
        if view not in VIEWS or view == "model":
            raise ValueError(f"view {view!r}: expected one of {', '.join(VIEWS[1:])}")
        with self._lock:
            if self._request != (view, at_s) or self._wanted != wanted:
                self._request, self._wanted = (view, at_s), wanted
                self._wake.set()

    def take_pages(self) -> PagesTaken | None:
        """A paged memory's pages composed since the last take (index -> its primitive, the
        texture at the detail its rank asks for) and the pages to hold (the others held are let
        go), or None when nothing changed."""
        with self._lock:
            if self._keep is None:
                return None
            pages, keep = self._pages, self._keep
            self._pages, self._keep = {}, None
            self.shown_for = (self._request, self._wanted)
            return pages, keep

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
            if self.boxes is not None:
                return (
                    self.done
                    and self.shown_for == (self._request, self._wanted)
                    and self._keep is None
                    and self._composed_for == ((self._request, self._wanted), self.frames_painted)
                )
            return self.done and self.shown_for == self._request and self._texture is None

    # --- the painter thread ----------------------------------------------------------------------

    def _run(self) -> None:
        try:
            if self._paint():
                while not self._stop.is_set():
                    self._wake.wait(0.5)
                    self._wake.clear()
                    self._compose()
        finally:
            if isinstance(self.memory, PagedMemory):
                self.memory.close()  # its spill directory removed

    def _paint(self) -> bool:
        """Lay the memory out and paint every planned frame into it; False where it stopped
        or failed (the error kept for the viewer)."""
        views = None
        try:
            plan = [paint_frame_indices(c.track, self.every_s) for c in self.clips]
            cameras = planned_cameras(self.clips, plan)
            scene = scene_to_paint(self.mesh, cameras)
            tris = triangles_of(scene)
            texels = texel_targets(tris.corners, cameras, DECODE_LONG_SIDE)
            asked = int(np.prod(chart_sizes(tris, texels), axis=1).sum())
            self.frames_total = int(sum(len(p) for p in plan))
            if not self.frames_total:
                raise ValueError("the clips have no frames to paint")
            times = np.concatenate([c.times[p] for c, p in zip(self.clips, plan, strict=True)])
            span = (float(times.min()), float(times.max()), HISTORY_EPOCHS)
            if asked <= PAGE_ABOVE * self.max_texels:  # one atlas, texels scaled up alike
                self.atlas = layout(scene, self.max_texels, texels)
                self.memory = SurfaceMemory(self.atlas.points, self.atlas.normals, self.rule, span)
            else:  # the video asks for more: pages at the texels it asks for
                self.memory = PagedMemory(
                    scene,
                    lambda corners: texel_targets(corners, cameras, DECODE_LONG_SIDE),
                    self.rule,
                    span,
                    resident_bytes=self.resident_bytes,
                    scene_texels=texels,  # worked out above: not again
                )
                self.page_stats = self.memory.stats
                self.boxes = self.memory.boxes
            views = ModelViews(scene)
            paint_frames(self.memory, views, self.clips, plan, progress=self._painted)
            if self.boxes is None:
                self._compose()  # the last texture before `done` (current() trusts it)
            self.done = True
            if self.boxes is not None:
                self._compose()  # every page wanted, now without a budget
            return True
        except _Stopped:
            return False
        except Exception as exc:  # shown by the viewer, which goes on without a memory
            self.error = f"scene memory: {exc}"
            self.done = True
            return False
        finally:
            if views is not None:
                views.release()
            self._finished.set()

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
        if isinstance(self.memory, PagedMemory):
            self._compose_pages()
            return
        with self._lock:
            request = self._request
        key = (request, self.frames_painted)
        if key == self._composed_for or self.memory is None:
            return
        colours, span = _view_of(self.atlas, self.memory, *request)
        texture = self.atlas.texture(colours)
        with self._lock:
            self._texture, self._texture_for, self.range_s = texture, request, span
        self._composed_for = key

    def _compose_pages(self) -> None:
        """The wanted pages that were painted, each composed unless it was for this request,
        detail and painting (while painting, at most PAGES_WHILE_PAINTING of them a call; the
        rest at the next); the pages to hold named once all are."""
        with self._lock:
            request, wanted = self._request, self._wanted
        key = ((request, wanted), self.frames_painted)
        if key == self._composed_for:
            return
        memory = self.memory
        done, budget = {}, PAGES_WHILE_PAINTING if not self.done else len(wanted)
        keep = set()
        for rank, k in enumerate(wanted):
            if not memory.made(k):
                continue
            keep.add(k)
            coarse = 1 if rank < self.fine_pages else COARSE
            sent_for = (request, coarse, self.frames_painted)
            if self._sent.get(k) == sent_for:
                continue
            if len(done) >= budget or self._stop.is_set():
                break
            atlas, page = memory.page(k)
            colours, self._ranges[k] = _view_of(atlas, page, *request)
            done[k] = _at_detail(atlas.primitive(colours, f"memory page {k}"), coarse)
            self._sent[k] = sent_for
        else:
            self._composed_for = key
        spans = [self._ranges[k] for k in keep if self._ranges.get(k) is not None]
        span = (min(s[0] for s in spans), max(s[1] for s in spans)) if spans else None
        with self._lock:
            self._pages.update(done)
            if done or key == self._composed_for:
                self._keep = keep | set(self._pages)
            self.range_s = span
        for k in [k for k in self._sent if k not in keep]:
            del self._sent[k]  # let go by the view: composed again when it comes back


def _at_detail(prim: Primitive, coarse: int) -> Primitive:
    """The primitive with its texture `coarse` times smaller a side (area-averaged)."""
    if coarse <= 1:
        return prim
    h, w = prim.texture.shape[:2]
    size = (max(1, w // coarse), max(1, h // coarse))
    return replace(prim, texture=cv2.resize(prim.texture, size, interpolation=cv2.INTER_AREA))


def _view_of(
    atlas: Atlas, memory: SurfaceMemory, view: str, at_s: float | None
) -> tuple[np.ndarray, tuple[float, float] | None]:
    """A memory laid on `atlas` as `view` shows it at at_s: its samples' colours, and the span
    (timeline s) of the sightings they show (seen_range; one snapshot serves both)."""
    snap = as_at(memory, at_s)
    return snapshot_colours(snap, atlas.base, view, at_s, atlas.triangle), seen_range(snap)


# --- the viewer's side (v: app.ui.viewer.Viewer) -------------------------------------------------

PAINT_WAIT_S = 900.0  # a script's `wait painted` gives up after this long (real seconds)


def start(
    v, rule: str = "newest", every_s: float = DEFAULT_EVERY_S, max_texels: int = DEFAULT_MAX_TEXELS
) -> None:
    """Paint the open clip and the further clips shown on its timeline (a frame every every_s s
    of each), each under its source's track as solved now, into a new memory (the previous one
    is dropped): one atlas of at most max_texels, or pages where the video asks for more."""
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
    if not max_texels >= 1000:
        raise ValueError(f"MAX_TEXELS: expected at least 1000, got {max_texels}")
    painter = MemoryPainter(L.renderer.scene.mesh, todo, rule, every_s, max_texels)
    close(L)
    L.memory = painter.start()
    L.renderer.scene.set_memory(None)
    L.renderer.scene.keep_memory_pages(set())
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
    if p.boxes is not None:
        _update_pages(v, p, scene)
        return
    if scene.memory is None and p.atlas is not None:
        scene.set_memory(p.atlas.primitive(p.atlas.base), overlay=p.covers_tiles)
    view = v.ui.memory_view
    scene.show_memory = view != "model" and scene.memory is not None
    if view != "model":
        k = v.current_index
        p.request(view, float(L.timeline.clips[0].times[k]) if k >= 0 else None)
    texture = p.take()
    if texture is not None and scene.memory is not None:
        scene.write_memory_texture(texture)


def _update_pages(v, p: MemoryPainter, scene) -> None:
    """Each frame, a paged memory: the pages the window's view meets asked for, those composed
    uploaded, the others let go."""
    view = v.ui.memory_view
    scene.show_memory = view != "model"
    if view != "model":
        k = v.current_index
        cam = v.window_camera
        wanted = () if cam is None else pages_in_view(cam, *p.boxes, p.max_pages)
        p.request(view, float(v.loaded.timeline.clips[0].times[k]) if k >= 0 else None, wanted)
    taken = p.take_pages()
    if taken is not None:
        pages, keep = taken
        for k, prim in pages.items():
            scene.put_memory_page(k, prim)
        scene.keep_memory_pages(keep)


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
        "texel_m": None if m is None else (m if p.atlas is None else p.atlas).texel_m,
        "samples": None if m is None or p.boxes is not None else len(m.points),
        "seen": None if m is None or not p.done or p.boxes is not None else int(m.seen.sum()),
        "mb": None if m is None else p.nbytes / 1e6,
        "range_s": p.range_s,
        "pages": None if p.boxes is None else _pages_state(p, loaded.renderer.scene),
    }


def _pages_state(p: MemoryPainter, scene) -> dict:
    """A paged memory's pages: laid out, made, evicted and read back (CPU), held on the GPU."""
    s = p.page_stats
    return {
        "pages": s.pages,
        "made": s.made,
        "evicted": s.evicted,
        "reloaded": s.reloaded,
        "gpu_pages": len(scene.memory_pages),
        "gpu_mb": scene.memory_pages_bytes / 1e6,
    }
