"""A streamed 3D Tiles layer on the GPU: uploads what the workers decoded, keeps a byte-capped
least-recently-used cache, and answers each camera's selection with ready primitives.

Uploading happens on the render thread within a time budget per frame, so a frame never waits
for a tile; a tile drawn in the current frame is never evicted (the cap may be exceeded for one
frame rather than drop a visible tile)."""

from __future__ import annotations

import time
from collections import OrderedDict

import moderngl

from app.camera.pinhole import Camera
from app.render.primitives import GpuPrimitive, upload
from app.scene.tiles.stream import TileStream, TileView
from app.scene.tiles.tileset import Tile, Tileset

DEFAULT_CACHE_BYTES = 1 << 30  # 1 GiB of tile buffers and textures


class GpuTileset:
    """One tileset's tiles on the GPU (see the module docstring)."""

    def __init__(
        self,
        ctx: moderngl.Context,
        tileset: Tileset,
        anisotropy: float,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
    ) -> None:
        self.ctx = ctx
        self.tileset = tileset
        self.anisotropy = anisotropy
        self.cache_bytes = int(cache_bytes)
        self.stream = TileStream(tileset)
        self.resident: OrderedDict[int, tuple[Tile, list[GpuPrimitive]]] = (
            OrderedDict()
        )  # LRU order, oldest first
        self.bytes_held = 0
        self.frame = 0
        self._used_frame: dict[int, int] = {}
        self.evictions = 0

    @property
    def max_sse_px(self) -> float:
        return self.stream.max_sse_px

    @max_sse_px.setter
    def max_sse_px(self, value: float) -> None:
        self.stream.max_sse_px = float(value)

    def update(self, budget_s: float) -> bool:
        """Upload finished tiles for up to budget_s seconds, then evict over the cap."""
        self.frame += 1
        changed = False
        start = time.perf_counter()
        while time.perf_counter() - start <= budget_s and (taken := self.stream.take_loaded(1)):
            item = taken[0]
            changed = True
            if item.mesh is None:
                continue
            prims: list[GpuPrimitive] = []
            try:
                for p in item.mesh.primitives:
                    if len(p.indices):
                        prims.append(upload(self.ctx, p, self.anisotropy))
            except Exception as exc:  # e.g. a texture larger than this GL allows: that tile only
                for done in prims:
                    done.release()
                self.stream.failures += 1
                self.stream.errors.append(
                    f"{item.tile.contents[0] if item.tile.contents else self.tileset.location}: cannot upload to the GPU: {exc}"
                )
                prims = []
            self._drop(item.tile.id)
            self.resident[item.tile.id] = (item.tile, prims)
            self.bytes_held += sum(p.nbytes for p in prims)
            self.stream.mark_ready(item.tile)
        changed |= self._evict()
        return changed

    def _drop(self, tile_id: int) -> None:
        if tile_id in self.resident:
            self._used_frame.pop(tile_id, None)
            tile, prims = self.resident.pop(tile_id)
            for p in prims:
                self.bytes_held -= p.nbytes
                p.release()
            self.stream.release_content(tile)

    def _evict(self) -> bool:
        changed = False
        while self.bytes_held > self.cache_bytes and self.resident:
            tile_id = next(iter(self.resident))
            if self._used_frame.get(tile_id, -1) >= self.frame - 1:
                break  # everything older is in use
            self._drop(tile_id)
            self.evictions += 1
            changed = True
        return changed

    def _selection(self, camera: Camera, focal_px: float | None, key: str):
        return self.stream.select(TileView.of(camera, focal_px), key)

    def drawables(self, camera: Camera, focal_px: float | None, key: str) -> list[GpuPrimitive]:
        """The ready primitives chosen for `camera` (marks them most recently used)."""
        out: list[GpuPrimitive] = []
        for tile in self._selection(camera, focal_px, key).tiles:
            entry = self.resident.get(tile.id)
            if entry is None:
                continue  # failed or empty content
            self.resident.move_to_end(tile.id)
            self._used_frame[tile.id] = self.frame
            out += entry[1]
        return out

    def complete(self, camera: Camera, focal_px: float | None, key: str) -> bool:
        """Whether the selection for `camera` lacks nothing (queues what it lacks)."""
        return self._selection(camera, focal_px, key).complete

    def release(self) -> None:
        self.stream.close()
        for tile_id in list(self.resident):
            self._drop(tile_id)
