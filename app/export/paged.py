"""A surface memory in pages: what the video saw, at the texel size its pixels cover on each
surface (app.export.sampling), in bounded memory whatever the scene's size. Pure numpy.

The scene's triangles are cut (at the middle of their longest edge) until each one's chart
fits a quarter of a page's side at its own texel size, then grouped by place (halving the
longer side of their centres' box at the median) into pages of at most `page_texels` chart
texels. A page is an atlas of its triangles (app.export.atlas.packed) and a SurfaceMemory of its
samples (app.export.memory), made when a frame's frustum first meets its box. At most
`resident_bytes` of pages are held: past that, the least recently used pages are evicted,
written to a spill directory of their own (a temporary one, removed on close) and read back
when a frame or an export needs them again; each eviction and reload is counted (`stats`) and
logged once at the end. A frame that meets more pages than fit evicts some of them while it
paints (correct, slower: the reloads say so).
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.camera.pinhole import Camera
from app.export.atlas import Atlas, Triangles, chart_sizes, packed, triangles_of
from app.export.memory import RULES, SurfaceMemory, boxes_in_frustum
from app.scene.mesh import MeshData

log = logging.getLogger("geofuse.export")

PAGE_TEXELS = 1 << 18  # a page's charts at most: 512 x 512 texels
DEFAULT_RESIDENT_MB = 256.0
FILL = 0.8  # the share of a page's texels its charts may take (the rest: the shelves' gaps)
_STATE = ("rgb", "seen", "time", "quality")
_HISTORY = ("history_rgb", "history_dt")
_ATLAS = ("pixels", "points", "normals", "base", "triangle", "corners", "sizes", "uvs")


def spatial_groups(centres: np.ndarray, weights: np.ndarray, max_weight: float) -> list[np.ndarray]:
    """Indices of the items (centres (T, 2+) m, weights (T,)) in each group: split at the
    median of the longer horizontal side of their centres' box until each group weighs at most
    max_weight (or is one item)."""
    todo, out = [np.arange(len(centres))], []
    while todo:
        idx = todo.pop()
        if len(idx) <= 1 or weights[idx].sum() <= max_weight:
            out.append(idx)
            continue
        c = centres[idx, :2]
        axis = int(np.argmax(np.ptp(c, axis=0)))
        order = idx[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        todo += [order[:half], order[half:]]
    return out


def pages_in_view(camera: Camera, lo: np.ndarray, hi: np.ndarray, limit: int) -> tuple[int, ...]:
    """The pages (boxes lo, hi (P, 3) ENU m) a camera's frustum meets, nearest first (the
    distance from its centre to each box), at most `limit` of them."""
    inside = np.flatnonzero(boxes_in_frustum(camera, lo, hi))
    eye = np.asarray(camera.position, np.float64)
    gap = np.linalg.norm(np.clip(eye, lo[inside], hi[inside]) - eye, axis=1)
    return tuple(int(k) for k in inside[np.argsort(gap, kind="stable")][:limit])


@dataclass(frozen=True)
class Page:
    """triangles: indices (of PagedMemory.triangles) on the page; lo, hi (3,) ENU m their box;
    texels: their charts' texels."""

    triangles: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    texels: int


@dataclass
class PageStats:
    """What paging did: pages laid out, made (a frame or an export needed them), evicted to the
    spill directory, read back; the most bytes held at once and the most pages; bytes
    written to the spill directory in all (a page's layout once, its memory when painted since
    last written); frames that met more pages than the bound holds (each evicting its own)."""

    pages: int = 0
    made: int = 0
    evicted: int = 0
    reloaded: int = 0
    peak_bytes: int = 0
    peak_pages: int = 0
    spilled_bytes: int = 0
    overfull: int = 0

    def said(self) -> str:
        said = (
            f"{self.pages:,} pages ({self.made:,} made), at most {self.peak_pages} held "
            f"({self.peak_bytes / 1e6:.0f} MB), {self.evicted:,} evicted least recently used "
            f"to disk ({self.spilled_bytes / 1e6:.0f} MB written), {self.reloaded:,} read back"
        )
        if self.overfull:
            said += (
                f"; {self.overfull:,} frames met more pages than fit (more memory would be faster)"
            )
        return said


class PagedMemory:
    """See the module docstring. texels: a function giving the texel size (T,) m of triangles
    (T, 3, 3) ENU m (app.export.sampling.texel_targets with the painting cameras), asked for the
    scene's triangles (unless given as scene_texels, already worked out for triangles_of(mesh))
    and for the pieces cut from them; rule and history as SurfaceMemory's. Paint it as a
    SurfaceMemory; close it (or use it in a with)."""

    def __init__(
        self,
        mesh: MeshData,
        texels: Callable[[np.ndarray], np.ndarray],
        rule: str = "newest",
        history: tuple[float, float, int] | None = None,
        page_texels: int = PAGE_TEXELS,
        resident_bytes: float = DEFAULT_RESIDENT_MB * 1e6,
        spill_dir: Path | None = None,
        scene_texels: np.ndarray | None = None,
    ) -> None:
        if rule not in RULES:
            raise ValueError(f"rule {rule!r}: expected one of {', '.join(RULES)}")
        self.mesh, self.rule, self.history = mesh, rule, history
        self.resident_bytes = float(resident_bytes)
        self.triangles, self.texels = _fitted(triangles_of(mesh), texels, page_texels, scene_texels)
        sizes = chart_sizes(self.triangles, self.texels)
        area = (sizes[:, 0] * sizes[:, 1]).astype(np.float64)
        corners = self.triangles.corners
        self.pages = []
        for idx in spatial_groups(corners.mean(axis=1), area, FILL * page_texels):
            pts = corners[idx].reshape(-1, 3)
            self.pages.append(Page(idx, pts.min(axis=0), pts.max(axis=0), int(area[idx].sum())))
        self._lo = np.array([p.lo for p in self.pages])
        self._hi = np.array([p.hi for p in self.pages])
        self._resident: OrderedDict[int, tuple[Atlas, SurfaceMemory]] = OrderedDict()
        self._bytes: dict[int, int] = {}
        self._spilled: set[int] = set()
        self._painted_at: dict[int, int] = {}  # frames a page had when last written or read
        self._touching: set[int] = set()  # the pages the frame being painted meets
        self._overfull_at = -1
        self._own_dir = spill_dir is None
        self.spill_dir = (
            Path(tempfile.mkdtemp(prefix="geofuse-pages-")) if spill_dir is None else spill_dir
        )
        self.spill_dir.mkdir(parents=True, exist_ok=True)
        self.stats = PageStats(pages=len(self.pages))
        self.frames = 0

    # --- painting --------------------------------------------------------------------------------

    def paint(
        self,
        rgb: np.ndarray,
        camera: Camera,
        distances: np.ndarray,
        time_s: float,
        agreement: np.ndarray | None = None,
        sigmas: tuple[float, float] = (0.0, 0.0),
    ) -> int:
        """One frame painted into every page its frustum meets (SurfaceMemory.paint's
        arguments and return)."""
        n = 0
        self._touching = set()
        for k in np.flatnonzero(boxes_in_frustum(camera, self._lo, self._hi)):
            self._touching.add(int(k))
            n += self.page(int(k))[1].paint(rgb, camera, distances, time_s, agreement, sigmas)
        self._touching = set()
        self.frames += n > 0
        return n

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """The pages' boxes: lo, hi (P, 3) ENU m (fixed once laid out)."""
        return self._lo, self._hi

    def made(self, k: int) -> bool:
        """Whether page k was made (a frame met it): held, or evicted to the spill directory."""
        return k in self._resident or k in self._spilled

    @property
    def nbytes(self) -> int:
        """Bytes the pages held now take (at most resident_bytes, or one page where one alone
        is larger)."""
        return sum(self._bytes.values())

    @property
    def texel_m(self) -> float:
        """The finest texel (m)."""
        return float(self.texels.min())

    @property
    def samples(self) -> int:
        """The texels of every page's charts (an upper bound on its samples)."""
        return sum(p.texels for p in self.pages)

    def seen_count(self) -> tuple[int, int]:
        """(samples seen, samples) over the pages made, read back where evicted."""
        seen = total = 0
        for k in range(len(self.pages)):
            if k in self._resident:
                m = self._resident[k][1]
                seen, total = seen + int(m.seen.sum()), total + len(m.seen)
            elif k in self._spilled:
                with np.load(self._path(k)) as z:
                    seen, total = seen + int(z["seen"].sum()), total + len(z["seen"])
        return seen, total

    def each_page(self) -> Iterator[tuple[Page, Atlas, SurfaceMemory]]:
        """Every page in turn (made or read back as needed, within the memory's bound)."""
        for k, page in enumerate(self.pages):
            atlas, memory = self.page(k)
            yield page, atlas, memory

    def page(self, k: int) -> tuple[Atlas, SurfaceMemory]:
        """Page k's atlas and memory, held: made, or read back from the spill directory; the
        least recently used pages evicted past the bound."""
        if k in self._resident:
            self._resident.move_to_end(k)
            return self._resident[k]
        page = self.pages[k]
        tris = self.triangles.subset(page.triangles)
        if k in self._spilled:
            held = self._read(k, tris)
            self.stats.reloaded += 1
        else:
            atlas = packed(self.mesh, tris, self.texels[page.triangles])
            held = (atlas, SurfaceMemory(atlas.points, atlas.normals, self.rule, self.history))
            self.stats.made += 1
        self._resident[k] = held
        self._bytes[k] = _held_bytes(*held)
        self._evict(keep=k)
        self.stats.peak_bytes = max(self.stats.peak_bytes, self.nbytes)
        self.stats.peak_pages = max(self.stats.peak_pages, len(self._resident))
        return held

    # --- paging ----------------------------------------------------------------------------------

    def _path(self, k: int, part: str = "memory") -> Path:
        return self.spill_dir / f"page_{k}_{part}.npz"

    def _evict(self, keep: int) -> None:
        while self.nbytes > self.resident_bytes and len(self._resident) > 1:
            k = next(iter(self._resident))
            if k == keep:
                self._resident.move_to_end(k)
                continue
            atlas, memory = self._resident.pop(k)
            del self._bytes[k]
            self.stats.evicted += 1
            if k in self._touching and self._overfull_at != self.frames:
                self.stats.overfull += 1  # this frame's own pages did not fit
                self._overfull_at = self.frames
            if k not in self._spilled:  # the layout never changes: written once
                arrays = {name: getattr(atlas, name) for name in _ATLAS}
                np.savez(self._path(k, "atlas"), size=np.array(atlas.size), **arrays)
                self.stats.spilled_bytes += self._path(k, "atlas").stat().st_size
            if self._painted_at.get(k) != memory.frames:  # painted since it was last written
                names = _STATE + (_HISTORY if memory.history is not None else ())
                arrays = {name: getattr(memory, name) for name in names}
                np.savez(self._path(k), frames=memory.frames, **arrays)
                self.stats.spilled_bytes += self._path(k).stat().st_size
                self._painted_at[k] = memory.frames
            self._spilled.add(k)

    def _read(self, k: int, tris: Triangles) -> tuple[Atlas, SurfaceMemory]:
        with np.load(self._path(k, "atlas")) as z:
            a = {name: z[name] for name in (*_ATLAS, "size")}
        texels = self.texels[self.pages[k].triangles]
        atlas = Atlas(float(texels.min()), tuple(int(x) for x in a["size"]), tris.corners, a["uvs"],
                      a["pixels"], a["points"], a["normals"], a["base"], a["triangle"], a["corners"],
                      a["sizes"], texels)  # fmt: skip
        memory = SurfaceMemory(atlas.points, atlas.normals, self.rule, self.history)
        with np.load(self._path(k)) as z:
            for name in _STATE + (_HISTORY if self.history is not None else ()):
                setattr(memory, name, z[name].copy())
            memory.frames = int(z["frames"])
        self._painted_at[k] = memory.frames
        return atlas, memory

    def close(self) -> None:
        """Drop the pages and remove the spill directory (where it made one); logs `stats`."""
        log.info("paged memory: %s", self.stats.said())
        self._resident.clear()
        self._bytes.clear()
        if self._own_dir:
            shutil.rmtree(self.spill_dir, ignore_errors=True)
        else:
            for k in self._spilled:
                self._path(k).unlink(missing_ok=True)
                self._path(k, "atlas").unlink(missing_ok=True)
        self._spilled.clear()

    def __enter__(self) -> PagedMemory:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _held_bytes(atlas: Atlas, memory: SurfaceMemory) -> int:
    """A page's bytes, the arrays its atlas and memory share counted once."""
    shared = sum(
        a.nbytes
        for a, b in ((atlas.points, memory.points), (atlas.normals, memory.normals))
        if a is b
    )
    return atlas.nbytes + memory.nbytes - shared


def _fitted(
    tris: Triangles,
    texels: Callable[[np.ndarray], np.ndarray],
    page_texels: int,
    known: np.ndarray | None = None,
) -> tuple[Triangles, np.ndarray]:
    """The triangles cut until each chart fits a quarter of a page's side at its texel size
    (known for `tris`, else asked; asked again for the pieces), and those sizes (T,) m."""
    side = int(np.sqrt(page_texels)) // 4
    size = np.asarray(texels(tris.corners) if known is None else known, np.float64)
    while True:
        big = chart_sizes(tris, size).max(axis=1) > side
        if not big.any():
            return tris, size
        tris, old = tris.split(big)
        size = size[old]
        cut = np.zeros(len(tris), bool)
        cut[len(tris) - 2 * int(big.sum()) :] = True  # split() puts the pieces last
        size[cut] = texels(tris.corners[cut])
