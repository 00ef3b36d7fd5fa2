"""One primitive's arrays on the GPU: the interleaved vertex buffer, the index buffer and its
mipmapped texture (app.scene.mesh.Primitive uploaded), with its vertex arrays per program. Used
by the static scene (app.render.gpu_scene) and streamed tiles (app.render.tiles) alike."""

from __future__ import annotations

from dataclasses import dataclass, field

import moderngl
import numpy as np

from app.scene.mesh import Primitive

VERTEX_FORMAT = ("3f 2f 4f", "in_position", "in_uv", "in_color")


@dataclass(eq=False)
class GpuPrimitive:
    vbo: moderngl.Buffer  # interleaved position (3f), uv (2f), colour (4f)
    ibo: moderngl.Buffer
    texture: moderngl.Texture | None
    count: int
    nbytes: int = 0  # GPU memory held: buffers and texture with its mipmaps
    vaos: dict = field(default_factory=dict)
    # drawn over coincident surfaces (a scene memory's page over the model's own triangles):
    # the view pass offsets its depth toward the camera (OVERLAY_OFFSET)
    overlay: bool = False

    def vao(
        self, ctx: moderngl.Context, program: moderngl.Program, attributes: tuple[str, ...]
    ) -> moderngl.VertexArray:
        """This primitive's vertex array for `program` (made once), binding only `attributes`."""
        key = (program.glo, attributes)
        if key not in self.vaos:
            fmt = VERTEX_FORMAT[0].split()
            names = VERTEX_FORMAT[1:]
            layout = " ".join(
                f if name in attributes else f.replace("f", "x4")
                for f, name in zip(fmt, names, strict=True)
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
