"""Which tiles to draw for a camera, and loading them on worker threads. No GL here.

Selection (per camera, every frame): a tile outside the camera's frustum is culled; its
screen-space error is geometricError x focal length (px) / distance to its bounding sphere. A
tile whose error exceeds `max_sse` (16 px by default, as CesiumJS) is refined: REPLACE draws its
children instead once every visible child is ready, and keeps drawing itself until then; ADD
draws itself and its children. Tiles are loaded level by level (a child is only asked for once
its parent is ready), nearest and coarsest first. `select` never waits: what is not ready is
queued for the workers and the best ready tiles are drawn meanwhile.

Workers read and decode content into MeshData in the session's ENU frame (float32 positions,
float64 arithmetic until then), expand external tilesets and implicit subtrees, and hand the
results over through `take_loaded()`. A tile that fails, for whatever reason, is counted and its
error kept (the first few), and it is drawn as empty so that refinement goes on around it: a
worker never dies on bad data.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from app.camera.pinhole import Camera
from app.scene.mesh import MeshData, Primitive, merge_untextured
from app.scene.tiles import fetch
from app.scene.tiles.content import ContentError, read_content
from app.scene.tiles.gltf import GltfError, Skipped
from app.scene.tiles.implicit import Availability, Subtree, SubtreeError
from app.scene.tiles.tileset import Tile, Tileset, TilesetError

DEFAULT_MAX_SSE_PX = 16.0  # CesiumJS's maximumScreenSpaceError
DEFAULT_WORKERS = 4
EMPTY_SUBTREE = Subtree(Availability(0), (), Availability(0))
LOAD_ERRORS = (fetch.FetchError, ContentError, GltfError, SubtreeError, TilesetError, ValueError)


@dataclass(frozen=True)
class TileView:
    """What selection needs of a camera: ENU position (m), the six frustum planes (a, b, c, d)
    with inward normals, and the focal length in pixels of the target it draws into."""

    position: np.ndarray
    planes: np.ndarray
    focal_px: float

    @classmethod
    def of(cls, camera: Camera, focal_px: float | None = None) -> TileView:
        """From an app.camera.pinhole.Camera; focal_px defaults to its intrinsics' fy."""
        m = np.asarray(camera.view_projection, np.float64)  # row-major, clip = m @ [x, y, z, 1]
        planes = np.stack(
            [m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]]
        )
        planes /= np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
        return cls(
            np.asarray(camera.position, np.float64), planes, float(focal_px or camera.intrinsics.fy)
        )

    def visible(self, tile: Tile) -> bool:
        return bool(np.all(self.planes[:, :3] @ tile.center + self.planes[:, 3] >= -tile.radius))

    def screen_error(self, tile: Tile) -> float:
        d = float(np.linalg.norm(tile.center - self.position)) - tile.radius
        return float("inf") if d <= 1e-6 else tile.geometric_error * self.focal_px / d


@dataclass
class Selection:
    """Tiles to draw (ready ones only); complete: nothing better is still loading for this view."""

    tiles: list[Tile] = field(default_factory=list)
    complete: bool = True


def decode_tile(tileset: Tileset, tile: Tile, skipped: Skipped) -> MeshData:
    """Read and decode every content of `tile` into MeshData in the tileset's ENU frame."""
    frame = tileset.frame
    prims: list[Primitive] = []
    for location in tile.contents:
        data = fetch.read(location)
        try:
            raws = read_content(
                data,
                lambda u, base=location: fetch.read(fetch.resolve(base, u)),
                skipped,
                tile.transform,
            )
        except (ContentError, GltfError) as exc:
            raise ContentError(f"{location}: {exc}") from exc
        for raw in raws:
            enu = frame.ecef_to_enu(raw.positions).astype(np.float32)
            prims.append(
                Primitive(
                    enu,
                    raw.colors.astype(np.float32),
                    raw.indices,
                    raw.uvs,
                    raw.texture,
                    name=f"tile {tile.id}",
                )
            )
    return MeshData(
        merge_untextured(prims, f"tile {tile.id}")
    )  # one draw call for the untextured ones


@dataclass
class Loaded:
    """A worker's result: decoded content (mesh), a failed content load (failed), or an
    expansion (neither: the tile's children or contents changed)."""

    tile: Tile
    mesh: MeshData | None = None
    failed: bool = False


class TileStream:
    """Selection and loading for one tileset (see the module docstring).

    The render thread calls `select()` for each camera it draws, `take_loaded()` to collect what
    the workers finished (then `mark_ready` once uploaded), and `release_content(tile)` when it
    evicts a tile. `close()` stops the workers."""

    def __init__(
        self,
        tileset: Tileset,
        max_sse_px: float = DEFAULT_MAX_SSE_PX,
        workers: int = DEFAULT_WORKERS,
        decode: Callable[[Tileset, Tile, Skipped], MeshData] = decode_tile,
    ) -> None:
        self.tileset = tileset
        self.max_sse_px = float(max_sse_px)
        self.decode = decode
        self.skipped = tileset.skipped  # one record per tileset, whichever stream reads it
        self.ready: set[int] = set()  # content on the GPU (or empty, or failed): drawable
        self._cond = threading.Condition()
        self._wants: dict[str, list[tuple[tuple, Tile]]] = {}
        self._busy: set[int] = set()  # in a worker, or finished and not yet taken
        self._done: list[Loaded] = []
        self._closed = False
        self._threads = [
            threading.Thread(target=self._work, name=f"tiles-{i}", daemon=True)
            for i in range(max(1, workers))
        ]
        for t in self._threads:
            t.start()

    # -- selection (render thread) ---------------------------------------------------------
    @staticmethod
    def _unread(tile: Tile) -> bool:
        """An implicit subtree root whose subtree (so its contents) is not read yet."""
        return tile.implicit is not None and tile.implicit.subtree is None

    def _content_missing(self, tile: Tile) -> bool:
        return bool(tile.contents) and tile.id not in self.ready

    def select(self, view: TileView, key: str = "view") -> Selection:
        """The ready tiles to draw for `view`; queues what it lacks under `key` (one list of
        wants per camera, replaced at each call)."""
        wants: list[tuple[tuple, Tile]] = []
        lacking = False

        def want(tile: Tile) -> None:
            nonlocal lacking
            lacking = True
            if tile.id not in self._busy:
                wants.append(
                    ((tile.depth, float(np.linalg.norm(tile.center - view.position))), tile)
                )

        def visit(tile: Tile) -> tuple[list[Tile], bool]:
            """(tiles to draw, whether they cover the tile fully)."""
            if not view.visible(tile) or not tile.requested_from(view.position):
                return [], True
            if self._unread(tile) or self._content_missing(tile):
                want(tile)
                return [], False
            own = [tile] if tile.contents else []
            if view.screen_error(tile) <= self.max_sse_px:
                return own, True
            if tile.children is None:
                want(tile)  # expand: an external tileset or a subtree
                return own, bool(own)
            if not tile.children:  # a leaf: nothing finer exists
                return own, True
            drawn, ready = [], True
            for child in tile.children:
                d, r = visit(child)
                drawn += d
                ready &= r
            if tile.refine == "ADD":
                return own + drawn, ready or bool(own)
            if ready:
                return drawn, True
            return (own, True) if own else (drawn, False)

        tiles, _ = visit(self.tileset.root)
        with self._cond:
            self._wants[key] = sorted(wants, key=lambda w: w[0])
            self._cond.notify_all()
        return Selection(tiles, not lacking)

    def take_loaded(self, limit: int | None = None) -> list[Loaded]:
        """Up to `limit` (None: all) results the workers finished, oldest first. A failed load
        counts as ready (drawn empty); decoded meshes become ready when the caller calls
        `mark_ready` after uploading."""
        with self._cond:
            n = len(self._done) if limit is None else limit
            done, self._done = self._done[:n], self._done[n:]
        for item in done:
            self._busy.discard(item.tile.id)
            if item.failed:
                self.ready.add(item.tile.id)
        return done

    def wait_loaded(self, timeout_s: float) -> bool:
        """Block until a worker has finished a tile not taken yet (or the stream closed), at most
        timeout_s seconds; True when one is there. Callers wait on this, never on a sleep."""
        with self._cond:
            return self._cond.wait_for(lambda: bool(self._done) or self._closed, timeout_s)

    def mark_ready(self, tile: Tile) -> None:
        self.ready.add(tile.id)

    def release_content(self, tile: Tile) -> None:
        """The render thread evicted the tile's content: it is loaded again when next wanted."""
        self.ready.discard(tile.id)

    @property
    def pending(self) -> int:
        """Tiles queued or loading."""
        with self._cond:
            return len(self._busy) + sum(len(w) for w in self._wants.values())

    # -- workers ---------------------------------------------------------------------------
    def _next(self) -> Tile | None:
        with self._cond:
            while not self._closed:
                best = None
                for key, wants in self._wants.items():
                    while wants and wants[0][1].id in self._busy:
                        wants.pop(0)
                    if wants and (best is None or wants[0][0] < best[0][0]):
                        best = (wants[0], key)
                if best is not None:
                    (_, tile), key = best
                    self._wants[key].pop(0)
                    self._busy.add(tile.id)
                    return tile
                self._cond.wait()
            return None

    def _work(self) -> None:
        while (tile := self._next()) is not None:
            item = Loaded(tile)
            content_job = not self._unread(tile) and self._content_missing(tile)
            try:
                if content_job:
                    item.mesh = self.decode(self.tileset, tile, self.skipped)
                else:
                    self.tileset.expand(tile)
            except Exception as exc:  # a thread boundary: any failure of one tile is that tile's
                message = (
                    str(exc)
                    if isinstance(exc, LOAD_ERRORS)
                    else f"{tile.contents[0] if tile.contents else tile.document}: {type(exc).__name__}: {exc}"
                )
                self.tileset.add_failure(message)
                if content_job:
                    item.failed = True
                else:  # nothing below this tile can be read: stop refining it
                    if tile.implicit is not None and tile.implicit.subtree is None:
                        tile.contents = ()
                        tile.implicit.subtree = EMPTY_SUBTREE
                    tile.children = []
            with self._cond:
                self._done.append(item)
                self._cond.notify_all()

    @property
    def failures(self) -> int:
        """Tiles of the tileset that could not be read (by any stream)."""
        return self.tileset.failures

    @property
    def errors(self) -> list[str]:
        """The first of them, named."""
        return list(self.tileset.errors)

    def close(self, wait_s: float = 1.0) -> None:
        """Stop the workers: idle ones at once; one still reading a slow URL finishes that read on
        its own (daemon threads touch no GL), so closing a session never hangs on the network."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        for t in self._threads:
            t.join(timeout=wait_s / len(self._threads))
