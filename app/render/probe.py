"""Where a camera's pixels land on the model, off-screen: an EGL context, the scene on the GPU and
the position pass, for analyses and exports that need model points (accuracy in metres, frame
footprints). Owns its GL objects; `release()` frees them."""

from __future__ import annotations

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.render.context import create_offscreen_context, keep_current, made_current
from app.render.gpu_scene import GpuScene
from app.render.positions import PositionPass
from app.scene.mesh import MeshData


def border_sampling(intrinsics: Intrinsics, columns: int, rows: int) -> Intrinsics:
    """Intrinsics of a columns x rows grid whose pixel centres fall on u = i * width / (columns - 1)
    and v = j * height / (rows - 1) of the original image: the first and last rows and columns
    sample the image's border exactly (corners included)."""
    if columns < 2 or rows < 2:
        raise ValueError(f"need at least a 2 x 2 grid, got {columns} x {rows}")
    sx = (columns - 1) / intrinsics.width
    sy = (rows - 1) / intrinsics.height
    return Intrinsics(
        columns,
        rows,
        intrinsics.fx * sx,
        intrinsics.fy * sy,
        intrinsics.cx * sx + 0.5,
        intrinsics.cy * sy + 0.5,
    )


class SurfaceProbe:
    """Model points (ENU m) seen at the pixels of cameras of one grid size."""

    def __init__(self, mesh: MeshData) -> None:
        with keep_current():  # its own context current only inside its methods
            self.ctx = create_offscreen_context()
            self.scene = GpuScene(self.ctx, mesh)
            self.pass_ = PositionPass(self.ctx, self.scene)

    def points(self, camera: Camera) -> np.ndarray:
        """(H, W, 3) ENU metres at each pixel centre of `camera` (row 0 = top); NaN: no surface.
        Streamed tiles are loaded to full detail for the camera first."""
        with made_current(self.ctx):
            self.scene.settle([(camera, None, "positions")])
            return self.pass_.render(camera)

    def release(self) -> None:
        with made_current(self.ctx):
            self.pass_.release()
            self.scene.release()
        self.ctx.release()
