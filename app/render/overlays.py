"""Line overlays in world coordinates: the projector's frustum and a trajectory polyline."""

from __future__ import annotations

import moderngl
import numpy as np
import numpy.typing as npt

from app.camera.pinhole import Camera
from app.render.programs import load_program

FRUSTUM_COLOR = (1.0, 0.85, 0.1, 1.0)
TRAJECTORY_COLOR = (0.1, 0.9, 1.0, 1.0)
REFERENCE_COLOR = (0.2, 1.0, 0.3, 1.0)
OUTLINE_COLOR = (1.0, 0.55, 0.0, 1.0)  # exported footprints
FIX_USED_COLOR = (1.0, 1.0, 1.0, 1.0)  # the GNSS fixes the track stands on
FIX_REJECTED_COLOR = (0.92, 0.22, 0.18, 1.0)  # the fixes that lie (the timeline's colour)


def frustum_segments(camera: Camera, length_m: float) -> np.ndarray:
    """(16, 3) ENU endpoints of 8 segments: 4 edges from the camera centre to the corners of the
    image rectangle at `length_m` along the optical axis, and that rectangle's 4 sides."""
    corners = camera.frustum_corners(length_m)[4:]
    centre = np.asarray(camera.position)
    segs = []
    for i in range(4):
        segs += [centre, corners[i], corners[i], corners[(i + 1) % 4]]
    return np.array(segs)


class LineOverlay:
    """Draws line segments or a line strip with one colour, depth-tested against the scene."""

    def __init__(self, ctx: moderngl.Context) -> None:

        self.ctx = ctx
        self.program = load_program(ctx, "lines.vert", "lines.frag")
        self.vbo = ctx.buffer(reserve=4096, dynamic=True)
        self.vao = ctx.vertex_array(self.program, [(self.vbo, "3f", "in_position")])

    def draw(
        self, view_proj: np.ndarray, points: npt.ArrayLike, color: tuple[float, ...], mode: int
    ) -> None:
        pts = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3))
        if len(pts) < 2:
            return
        if pts.nbytes > self.vbo.size:
            self.vbo.orphan(pts.nbytes)
        self.vbo.write(pts.tobytes())
        self.program["u_view_proj"].write(np.asarray(view_proj, np.float32).T.tobytes())
        self.program["u_color"].value = color
        self.vao.render(mode, vertices=len(pts))

    def release(self) -> None:
        self.vao.release()
        self.vbo.release()
        self.program.release()
