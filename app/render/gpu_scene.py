"""The scene's arrays on the GPU: static primitives uploaded once, and streamed 3D Tiles layers
(app.render.tiles) whose tiles come and go with the camera. Passes ask `drawables(camera)` for
what to draw from a camera and take each primitive's vertex array for their program.

A scene memory (app.export.memory on an app.export.atlas) is one more primitive: the static
triangles again, textured by the atlas; while it is shown it is drawn instead of the static
primitives (same surfaces, so depth maps and picking are unchanged). Over streamed 3D Tiles it
also holds the tiles the clips needed (frozen): it is then drawn over the scene as an overlay
(below), the streamed layers staying where the clips never looked. A memory in pages
(app.export.paged) is a primitive a page, only for the pages the view needs (`put_memory_page`,
`keep_memory_pages`): while shown they are drawn over the model in the view pass alone (overlays:
their depth offset toward the camera), the model showing where no page is held.

The static primitives can be replaced while drawing (a world built in the background, its
coarse level then its full one: app.ui.world): `stage` hands over primitives laid out by
app.render.staging.prepare, `update` uploads them in pieces within its budget and swaps them in
whole once complete, so no frame draws half a scene nor waits for the upload."""

from __future__ import annotations

import time

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.render.primitives import GpuPrimitive, default_anisotropy, interleave, upload
from app.render.staging import PreparedPrimitive, StagedScene
from app.render.tiles import DEFAULT_CACHE_BYTES, GpuTileset
from app.scene.mesh import MeshData, Primitive

SETTLE_POLL_S = 0.05  # settle() waits at most this long on one tileset before looking at all again


class GpuScene:
    """Static primitives uploaded once, plus one streamed layer per tileset of the MeshData."""

    def __init__(
        self,
        ctx: moderngl.Context,
        mesh: MeshData,
        anisotropy: float | None = None,
        tile_cache_bytes: int | None = None,
    ) -> None:

        self.ctx = ctx
        self.mesh = mesh
        anisotropy = default_anisotropy(ctx) if anisotropy is None else anisotropy
        self.sources = [p for p in mesh.primitives if len(p.indices)]
        self.primitives = [upload(ctx, p, anisotropy) for p in self.sources]
        cap = DEFAULT_CACHE_BYTES if tile_cache_bytes is None else tile_cache_bytes
        self.tilesets = [GpuTileset(ctx, t, anisotropy, cap) for t in mesh.tilesets]
        self.version = 0  # bumps when streamed tiles arrive or leave
        self.memory: GpuPrimitive | None = None  # the scene memory's atlas-textured triangles
        self.show_memory = False  # draw the memory instead of the static primitives
        self.memory_pages: dict[int, GpuPrimitive] = {}  # a paged memory's pages held, by index
        self._bounds: np.ndarray | None = None
        self._anisotropy = anisotropy
        self.staged: tuple[MeshData, StagedScene] | None = None  # static primitives on their way
        self.swaps = 0  # static primitives replaced (stage) so far
        self.stage_error: str | None = None  # why the last scene staged was dropped

    def update(self, budget_s: float = 0.008) -> bool:
        """Upload what the tile workers finished, within about budget_s seconds, and evict least
        recently used tiles over the cache cap. True when anything changed. Never waits."""
        changed = False
        share = budget_s / max(1, len(self.tilesets) + (self.staged is not None))
        for layer in self.tilesets:
            changed |= layer.update(share)
        if self.staged is not None:
            try:
                done = self.staged[1].step(share)
            except Exception as exc:  # a driver refusing the upload: that scene only, said
                self.unstage()
                self.stage_error = f"the scene could not be uploaded to the GPU: {exc}"
            else:
                if done:
                    self._swap(*self.staged)
                    changed = True
        if changed:
            self.version += 1
        return changed

    def stage(self, mesh: MeshData, prepared: list[PreparedPrimitive]) -> None:
        """Replace the static primitives by `mesh`'s (prepared: app.render.staging.prepare of
        it), uploaded in pieces by update(); what was staged before and not swapped in yet is
        dropped. The streamed layers stay."""
        self.unstage()
        self.stage_error = None
        self.staged = (mesh, StagedScene(self.ctx, prepared, self._anisotropy))

    def unstage(self) -> None:
        """Drop what is staged and not swapped in yet."""
        if self.staged is not None:
            self.staged[1].release()
            self.staged = None

    def _swap(self, mesh: MeshData, staged: StagedScene) -> None:
        for p in self.primitives:
            p.release()
        self.primitives = staged.primitives
        self.sources = [p for p in mesh.primitives if len(p.indices)]
        self.mesh = MeshData(mesh.primitives, self.mesh.tilesets, mesh.features)
        self._bounds = None
        self.staged = None
        self.swaps += 1

    def drawables(
        self, camera: Camera | None = None, focal_px: float | None = None, key: str = "view"
    ) -> list[GpuPrimitive]:
        """What to draw from `camera` (an app.camera.pinhole.Camera): every static primitive, and each
        tileset's ready tiles chosen for it (focal_px: the focal length in pixels of the target
        drawn into, default the camera's). Without a camera: static primitives only."""
        memory = self.memory if self.show_memory else None
        out = [memory] if memory is not None and not memory.overlay else list(self.primitives)
        if camera is not None:
            for layer in self.tilesets:
                out += layer.drawables(camera, focal_px, key)
        if self.show_memory and key == "view":  # overlays: the view pass alone
            out += [memory] if memory is not None and memory.overlay else []
            out += list(self.memory_pages.values())
        return out

    def settle(
        self, cameras: list[tuple[object, float | None, str]], timeout_s: float = 300.0
    ) -> bool:
        """Load and upload until every tileset's selection for each (camera, focal_px, key) is
        complete: full detail for off-screen renders. True when complete within timeout_s."""
        if not self.tilesets:
            return True
        end = time.monotonic() + timeout_s
        while True:
            complete = all(
                layer.complete(cam, f, key) for layer in self.tilesets for cam, f, key in cameras
            )
            busy = self.update(budget_s=1.0)
            if complete and not busy:
                return True
            if time.monotonic() > end:
                return False
            if not busy:  # nothing to upload: wait for a worker to finish a tile
                self.tilesets[0].stream.wait_loaded(
                    min(SETTLE_POLL_S, max(0.0, end - time.monotonic()))
                )

    def forget(self, program: moderngl.Program) -> None:
        """Release every vertex array made for `program` (call before releasing the program, so a
        later program given the same GL name never inherits them)."""
        prims = list(self.primitives) + ([self.memory] if self.memory is not None else [])
        prims += list(self.memory_pages.values())
        for layer in self.tilesets:
            prims += [p for _, ps in layer.resident.values() for p in ps]
        for prim in prims:
            for key in [k for k in prim.vaos if k[0] == program.glo]:
                prim.vaos.pop(key).release()

    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of everything the scene may draw, ENU metres (a tileset's
        by its root volume); kept until positions change."""
        if self._bounds is None:
            self._bounds = self.mesh.bounds()
        return self._bounds

    def update_positions(self, index: int, positions: np.ndarray) -> None:
        """Replace primitive `index`'s vertex positions (same vertex count), keeping uv and colour:
        moving objects without re-creating GL objects."""
        prim = self.sources[index]
        if positions.shape != prim.positions.shape:
            raise ValueError(f"positions shape {positions.shape}, expected {prim.positions.shape}")
        prim.positions = np.asarray(positions, np.float32)
        self._bounds = None
        self.primitives[index].vbo.write(interleave(prim).tobytes())

    def set_memory(self, prim: Primitive | None, overlay: bool = False) -> None:
        """The scene memory's primitive (its static triangles, atlas-textured), uploaded; None
        releases it. overlay: it also holds streamed layers' tiles (frozen: those the clips
        needed), which need not be the ones the view streams, so while shown it is drawn over
        the static primitives and the streamed tiles in the view pass (its depth offset toward
        the camera) instead of in place of the static primitives."""
        if self.memory is not None:
            self.memory.release()
        self.memory = None if prim is None else upload(self.ctx, prim, default_anisotropy(self.ctx))
        if self.memory is not None:
            self.memory.overlay = overlay

    def write_memory_texture(self, texture: np.ndarray) -> None:
        """New texels for the memory's atlas: (H, W, 4) uint8, bottom row first, its size."""
        tex = self.memory.texture
        if texture.shape != (tex.height, tex.width, 4):
            raise ValueError(
                f"memory texture {texture.shape}, expected {(tex.height, tex.width, 4)}"
            )
        tex.write(np.ascontiguousarray(texture).tobytes())
        tex.build_mipmaps()

    def put_memory_page(self, k: int, prim: Primitive) -> None:
        """A paged memory's page k (its triangles, textured by the page's atlas at the detail
        sent), uploaded in place of the one held."""
        old = self.memory_pages.pop(k, None)
        if old is not None:
            old.release()
        page = upload(self.ctx, prim, default_anisotropy(self.ctx))
        page.overlay = True
        self.memory_pages[k] = page

    def keep_memory_pages(self, keep: set[int]) -> None:
        """Release the memory pages held but not in `keep`."""
        for k in [k for k in self.memory_pages if k not in keep]:
            self.memory_pages.pop(k).release()

    @property
    def memory_pages_bytes(self) -> int:
        """GPU bytes the memory pages held take (buffers, textures with their mipmaps)."""
        return sum(p.nbytes for p in self.memory_pages.values())

    def release(self) -> None:
        self.unstage()
        self.keep_memory_pages(set())
        self.set_memory(None)
        for p in self.primitives:
            p.release()
        self.primitives = []
        for layer in self.tilesets:
            layer.release()
        self.tilesets = []
