"""The scene's arrays on the GPU: one vertex buffer, index buffer and texture per primitive."""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from app.scene.mesh import MeshData, Primitive


@dataclass
class GpuPrimitive:
    vbo: moderngl.Buffer  # interleaved position (3f), uv (2f), colour (4f)
    ibo: moderngl.Buffer
    texture: moderngl.Texture | None
    count: int

    def release(self) -> None:
        self.vbo.release()
        self.ibo.release()
        if self.texture is not None:
            self.texture.release()


VERTEX_FORMAT = ("3f 2f 4f", "in_position", "in_uv", "in_color")


def interleave(prim: Primitive) -> np.ndarray:
    """(N, 9) float32 rows of position, uv, colour: the vertex buffer layout (VERTEX_FORMAT)."""
    n = len(prim.positions)
    data = np.empty((n, 9), np.float32)
    data[:, 0:3] = prim.positions
    data[:, 3:5] = prim.uvs if prim.uvs is not None else 0.0
    data[:, 5:9] = prim.colors
    return data


def _upload(ctx: moderngl.Context, prim: Primitive, anisotropy: float) -> GpuPrimitive:
    data = interleave(prim)
    texture = None
    if prim.textured:
        img = np.ascontiguousarray(prim.texture)
        texture = ctx.texture((img.shape[1], img.shape[0]), img.shape[2], img.tobytes())
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.anisotropy = anisotropy
    return GpuPrimitive(ctx.buffer(data.tobytes()), ctx.buffer(prim.indices.astype(np.uint32).tobytes()), texture, prim.indices.size)


class GpuScene:
    """Uploads MeshData once; passes build their vertex arrays from `primitives`."""

    def __init__(self, ctx: moderngl.Context, mesh: MeshData, anisotropy: float | None = None) -> None:
        """anisotropy: texture anisotropic filtering; None picks 8 on a GPU and 1 on a software
        rasteriser (on Mesa llvmpipe 8x more than doubles the frame time)."""
        self.ctx = ctx
        self.mesh = mesh
        if anisotropy is None:
            anisotropy = 1.0 if "llvmpipe" in ctx.info.get("GL_RENDERER", "") else 8.0
        self.sources = [p for p in mesh.primitives if len(p.indices)]
        self.primitives = [_upload(ctx, p, anisotropy) for p in self.sources]

    def update_positions(self, index: int, positions: np.ndarray) -> None:
        """Replace primitive `index`'s vertex positions (same vertex count), keeping uv and colour:
        moving objects without re-creating GL objects."""
        prim = self.sources[index]
        if positions.shape != prim.positions.shape:
            raise ValueError(f"positions shape {positions.shape}, expected {prim.positions.shape}")
        prim.positions = np.asarray(positions, np.float32)
        self.primitives[index].vbo.write(interleave(prim).tobytes())

    def vertex_arrays(self, program: moderngl.Program, attributes: tuple[str, ...]) -> list[moderngl.VertexArray]:
        """One VAO per primitive for `program`, binding only the attributes it uses."""
        fmt = VERTEX_FORMAT[0].split()
        names = VERTEX_FORMAT[1:]
        layout = " ".join(f if name in attributes else f.replace("f", "x4") for f, name in zip(fmt, names))
        used = [name for name in names if name in attributes]
        return [
            self.ctx.vertex_array(program, [(p.vbo, layout, *used)], index_buffer=p.ibo, index_element_size=4)
            for p in self.primitives
        ]

    def release(self) -> None:
        for p in self.primitives:
            p.release()
        self.primitives = []
