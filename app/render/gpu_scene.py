"""The scene's arrays on the GPU: static primitives uploaded once, and streamed 3D Tiles layers
(app.render.tiles) whose tiles come and go with the camera. Passes ask `drawables(camera)` for
what to draw from a camera and take each primitive's vertex array for their program."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import moderngl
import numpy as np

from app.scene.mesh import MeshData, Primitive

VERTEX_FORMAT = ("3f 2f 4f", "in_position", "in_uv", "in_color")


@dataclass(eq=False)
class GpuPrimitive:
    vbo: moderngl.Buffer  # interleaved position (3f), uv (2f), colour (4f)
    ibo: moderngl.Buffer
    texture: moderngl.Texture | None
    count: int
    nbytes: int = 0  # GPU memory held: buffers and texture with its mipmaps
    vaos: dict = field(default_factory=dict)

    def vao(
        self, ctx: moderngl.Context, program: moderngl.Program, attributes: tuple[str, ...]
    ) -> moderngl.VertexArray:
        """This primitive's vertex array for `program` (made once), binding only `attributes`."""
        key = (program.glo, attributes)
        if key not in self.vaos:
            fmt = VERTEX_FORMAT[0].split()
            names = VERTEX_FORMAT[1:]
            layout = " ".join(
                f if name in attributes else f.replace("f", "x4") for f, name in zip(fmt, names)
            )
            used = [name for name in names if name in attributes]
            self.vaos[key] = ctx.vertex_array(
                program, [(self.vbo, layout, *used)], index_buffer=self.ibo, index_element_size=4
            )
        return self.vaos[key]

    def release(self) -> None:
        for vao in self.vaos.values():
            vao.release()
        self.vaos.clear()
        self.vbo.release()
        self.ibo.release()
        if self.texture is not None:
            self.texture.release()


def interleave(prim: Primitive) -> np.ndarray:
    """(N, 9) float32 rows of position, uv, colour: the vertex buffer layout (VERTEX_FORMAT)."""
    n = len(prim.positions)
    data = np.empty((n, 9), np.float32)
    data[:, 0:3] = prim.positions
    data[:, 3:5] = prim.uvs if prim.uvs is not None else 0.0
    data[:, 5:9] = prim.colors
    return data


def default_anisotropy(ctx: moderngl.Context) -> float:
    """8 on a GPU, 1 on a software rasteriser (on Mesa llvmpipe 8x more than doubles the frame time)."""
    return 1.0 if "llvmpipe" in ctx.info.get("GL_RENDERER", "") else 8.0


def upload(ctx: moderngl.Context, prim: Primitive, anisotropy: float) -> GpuPrimitive:
    """One primitive's buffers (and mipmapped texture) on the GPU."""
    data = interleave(prim)
    texture = None
    nbytes = data.nbytes + prim.indices.size * 4
    if prim.textured:
        img = np.ascontiguousarray(prim.texture)
        texture = ctx.texture((img.shape[1], img.shape[0]), img.shape[2], img.tobytes())
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.anisotropy = anisotropy
        nbytes += img.nbytes * 4 // 3
    return GpuPrimitive(
        ctx.buffer(data.tobytes()),
        ctx.buffer(prim.indices.astype(np.uint32).tobytes()),
        texture,
        prim.indices.size,
        nbytes,
    )


class GpuScene:
    """Static primitives uploaded once, plus one streamed layer per tileset of the MeshData."""

    def __init__(
        self,
        ctx: moderngl.Context,
        mesh: MeshData,
        anisotropy: float | None = None,
        tile_cache_bytes: int | None = None,
    ) -> None:
        from app.render.tiles import DEFAULT_CACHE_BYTES, GpuTileset

        self.ctx = ctx
        self.mesh = mesh
        anisotropy = default_anisotropy(ctx) if anisotropy is None else anisotropy
        self.sources = [p for p in mesh.primitives if len(p.indices)]
        self.primitives = [upload(ctx, p, anisotropy) for p in self.sources]
        cap = DEFAULT_CACHE_BYTES if tile_cache_bytes is None else tile_cache_bytes
        self.tilesets = [GpuTileset(ctx, t, anisotropy, cap) for t in mesh.tilesets]
        self.version = 0  # bumps when streamed tiles arrive or leave

    def update(self, budget_s: float = 0.008) -> bool:
        """Upload what the tile workers finished, within about budget_s seconds, and evict least
        recently used tiles over the cache cap. True when anything changed. Never waits."""
        changed = False
        for layer in self.tilesets:
            changed |= layer.update(budget_s / max(1, len(self.tilesets)))
        if changed:
            self.version += 1
        return changed

    def drawables(
        self, camera: object | None = None, focal_px: float | None = None, key: str = "view"
    ) -> list[GpuPrimitive]:
        """What to draw from `camera` (an app.camera.Camera): every static primitive, and each
        tileset's ready tiles chosen for it (focal_px: the focal length in pixels of the target
        drawn into, default the camera's). Without a camera: static primitives only."""
        out = list(self.primitives)
        if camera is not None:
            for layer in self.tilesets:
                out += layer.drawables(camera, focal_px, key)
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
            if not busy:
                time.sleep(0.005)

    def forget(self, program: moderngl.Program) -> None:
        """Release every vertex array made for `program` (call before releasing the program, so a
        later program given the same GL name never inherits them)."""
        prims = list(self.primitives)
        for layer in self.tilesets:
            prims += [p for _, ps in layer.resident.values() for p in ps]
        for prim in prims:
            for key in [k for k in prim.vaos if k[0] == program.glo]:
                prim.vaos.pop(key).release()

    def update_positions(self, index: int, positions: np.ndarray) -> None:
        """Replace primitive `index`'s vertex positions (same vertex count), keeping uv and colour:
        moving objects without re-creating GL objects."""
        prim = self.sources[index]
        if positions.shape != prim.positions.shape:
            raise ValueError(f"positions shape {positions.shape}, expected {prim.positions.shape}")
        prim.positions = np.asarray(positions, np.float32)
        self.primitives[index].vbo.write(interleave(prim).tobytes())

    def release(self) -> None:
        for p in self.primitives:
            p.release()
        self.primitives = []
        for layer in self.tilesets:
            layer.release()
        self.tilesets = []
