"""A scene's static primitives uploaded in pieces, a few each frame, so that a large scene (a
world's terrain draped with a 3072 px orthophoto, built in the background) reaches the GPU
without a frame that waits for it: on Mesa llvmpipe one 3072 x 3072 texture takes about 0.4 s
to upload whole and as long again to mipmap, against a frame of tens of ms.

`prepare` (pure numpy, any thread) lays out each primitive's vertex buffer and its texture's
whole mipmap chain (2 x 2 box filter, each level floor(w / 2) x floor(h / 2) as GL sizes them),
so the GL thread computes nothing. `StagedScene.step(budget_s)` (GL thread) writes pieces of at
most PIECE_BYTES until the budget is spent (one piece at least, so it always advances) and
says when every primitive is complete. Mip levels are allocated with glTexImage2D and written
with glTexSubImage2D through PyOpenGL (moderngl writes a level only after building the chain
on the GPU, which is the stall avoided here).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import moderngl
import numpy as np
from OpenGL import GL

from app.render.primitives import GpuPrimitive, interleave
from app.scene.mesh import MeshData

PIECE_BYTES = 1 << 20  # at most this much is written by one GL call


def mip_chain(texture: np.ndarray) -> list[np.ndarray]:
    """(H, W, C) uint8 -> [level 0, level 1, ...] down to 1 x 1, each level floor(H / 2) x
    floor(W / 2) (at least 1) of the one before by a 2 x 2 box filter, contiguous."""
    levels = [np.ascontiguousarray(texture)]
    while max(levels[-1].shape[:2]) > 1:
        a = levels[-1]
        h, w = a.shape[:2]
        rows = (0, 1) if h > 1 else (0, 0)  # a side of 1 texel stays 1: its texel counts twice
        cols = (0, 1) if w > 1 else (0, 0)
        h2, w2 = max(1, h // 2), max(1, w // 2)
        q = np.full((h2, w2) + a.shape[2:], 2, np.uint16)  # 2: rounds the quarter to nearest
        for r in rows:
            for c in cols:
                q += a[r : r + 2 * h2 : 2, c : c + 2 * w2 : 2]
        levels.append((q >> 2).astype(np.uint8))
    return levels


@dataclass
class PreparedPrimitive:
    """One primitive laid out for the GPU: interleaved vertices, uint32 indices, mip chain."""

    vertices: np.ndarray
    indices: np.ndarray
    levels: list[np.ndarray] = field(default_factory=list)

    @property
    def nbytes(self) -> int:
        return self.vertices.nbytes + self.indices.nbytes + sum(lv.nbytes for lv in self.levels)


def prepare(mesh: MeshData) -> list[PreparedPrimitive]:
    """The static primitives of `mesh` (with triangles) laid out for StagedScene (any thread)."""
    out = []
    for p in mesh.primitives:
        if not len(p.indices):
            continue
        levels = mip_chain(p.texture) if p.textured else []
        out.append(
            PreparedPrimitive(
                np.ascontiguousarray(interleave(p)),
                np.ascontiguousarray(p.indices, np.uint32).reshape(-1),
                levels,
            )
        )
    return out


def _pieces(array: np.ndarray, rows_of: int) -> list[tuple[int, int]]:
    """(first row, rows) pieces of at most PIECE_BYTES, rows_of bytes a row."""
    step = max(1, PIECE_BYTES // max(1, rows_of))
    return [(r, min(step, len(array) - r)) for r in range(0, len(array), step)]


class StagedScene:
    """Uploads prepared primitives piece by piece on the GL thread (see the module docstring);
    `primitives` once `step` returned True. `release()` frees what was made if abandoned."""

    def __init__(
        self, ctx: moderngl.Context, prepared: list[PreparedPrimitive], anisotropy: float
    ) -> None:
        self.ctx = ctx
        self.anisotropy = anisotropy
        self.prepared = prepared
        self.primitives: list[GpuPrimitive] = []
        self.pieces = 0  # GL writes made so far
        self._jobs = self._plan()

    def _plan(self) -> list:
        """The writes to make, in order: each a callable doing one piece."""
        jobs: list = []
        for k, p in enumerate(self.prepared):
            jobs.append(lambda k=k, p=p: self._make(k, p))
            flat = p.vertices.reshape(-1).view(np.uint8)
            idx = p.indices.view(np.uint8)
            for name, data in (("vbo", flat), ("ibo", idx)):
                for start, n in _pieces(data, 1):
                    jobs.append(
                        lambda k=k, name=name, d=data, s=start, n=n: self._write(k, name, d, s, n)
                    )
            for level, img in enumerate(p.levels):
                for row, n in _pieces(img, img.shape[1] * img.shape[2]):
                    jobs.append(
                        lambda k=k, lv=level, img=img, r=row, n=n: self._rows(k, lv, img, r, n)
                    )
            if p.levels:
                jobs.append(lambda k=k: self._finish_texture(k))
        return jobs

    def _make(self, k: int, p: PreparedPrimitive) -> None:
        texture = None
        if p.levels:
            base = p.levels[0]
            texture = self.ctx.texture((base.shape[1], base.shape[0]), base.shape[2])
            texture.use(0)
            self._clear_errors()
            fmt = _FORMATS[base.shape[2]]
            for level, img in enumerate(p.levels[1:], 1):
                GL.glTexImage2D(
                    GL.GL_TEXTURE_2D, level, fmt[0], img.shape[1], img.shape[0], 0, fmt[1],
                    GL.GL_UNSIGNED_BYTE, None,
                )  # fmt: skip
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, len(p.levels) - 1)
        prim = GpuPrimitive(
            self.ctx.buffer(reserve=max(4, p.vertices.nbytes)),
            self.ctx.buffer(reserve=max(4, p.indices.nbytes)),
            texture,
            p.indices.size,
            p.vertices.nbytes + p.indices.nbytes + sum(lv.nbytes for lv in p.levels),
        )
        self.primitives.append(prim)

    def _write(self, k: int, name: str, data: np.ndarray, start: int, n: int) -> None:
        getattr(self.primitives[k], name).write(data[start : start + n].tobytes(), offset=start)

    def _rows(self, k: int, level: int, img: np.ndarray, row: int, n: int) -> None:
        texture = self.primitives[k].texture
        if level == 0:
            texture.write(img[row : row + n].tobytes(), viewport=(0, row, img.shape[1], n))
            return
        texture.use(0)
        self._clear_errors()
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glTexSubImage2D(
            GL.GL_TEXTURE_2D, level, 0, row, img.shape[1], n, _FORMATS[img.shape[2]][1],
            GL.GL_UNSIGNED_BYTE, np.ascontiguousarray(img[row : row + n]),
        )  # fmt: skip

    def _clear_errors(self) -> None:
        """Read away GL errors others left pending (moderngl does not look at them), so that
        PyOpenGL's check after each call of ours speaks of that call alone."""
        for _ in range(8):
            if self.ctx.error == "GL_NO_ERROR":
                return

    def _finish_texture(self, k: int) -> None:
        texture = self.primitives[k].texture
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.anisotropy = self.anisotropy

    @property
    def left(self) -> int:
        """GL writes still to make."""
        return len(self._jobs)

    def step(self, budget_s: float) -> bool:
        """Write pieces for up to budget_s seconds (one at least); True once all are written."""
        start = time.perf_counter()
        while self._jobs:
            self._jobs.pop(0)()
            self.pieces += 1
            if time.perf_counter() - start >= budget_s:
                break
        return not self._jobs

    def release(self) -> None:
        for p in self.primitives:
            p.release()
        self.primitives = []
        self._jobs = []


_FORMATS = {
    1: (GL.GL_R8, GL.GL_RED),
    2: (GL.GL_RG8, GL.GL_RG),
    3: (GL.GL_RGB8, GL.GL_RGB),
    4: (GL.GL_RGBA8, GL.GL_RGBA),
}
