"""Where each pixel of a camera lands on the model: world positions read back from the GPU."""

from __future__ import annotations

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.render.context import wait_for_gpu
from app.render.gpu_scene import GpuScene
from app.render.programs import Uniforms, load_program


class PositionPass:
    """Renders world positions (float32 ENU) of the nearest surface per pixel of a camera."""

    def __init__(self, ctx: moderngl.Context, scene: GpuScene) -> None:
        self.ctx = ctx
        self.scene = scene
        self.program = load_program(ctx, "scene.vert", "position.frag", {"PROJECTION": 0})
        self._targets: dict[tuple, tuple] = {}

    def render_texture(self, camera: Camera) -> moderngl.Texture:
        """The position map of `camera` in a float texture (row 0 = bottom, as GL samples it;
        w = 1 where a surface was hit, 0 elsewhere), for shaders that look positions up."""
        size = (camera.intrinsics.width, camera.intrinsics.height)
        key = ("texture", size)
        if key not in self._targets:
            tex = self.ctx.texture(size, 4, dtype="f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)  # never blend across depth edges
            tex.repeat_x = tex.repeat_y = False
            depth = self.ctx.depth_renderbuffer(size)
            self._targets[key] = (self.ctx.framebuffer([tex], depth), tex, depth)
        fbo, tex, _ = self._targets[key]
        self._draw(fbo, camera)
        return tex

    def _draw(self, fbo: moderngl.Framebuffer, camera: Camera) -> None:
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        Uniforms(self.program).matrices("u_view_proj", [camera.view_projection])
        for prim in self.scene.drawables(camera, None, "positions"):
            prim.vao(self.ctx, self.program, ("in_position",)).render(moderngl.TRIANGLES)

    def _target(self, size: tuple[int, int]) -> moderngl.Framebuffer:
        if size not in self._targets:
            color = self.ctx.renderbuffer(size, 4, dtype="f4")
            depth = self.ctx.depth_renderbuffer(size)
            self._targets[size] = (self.ctx.framebuffer([color], depth), color, depth)
        return self._targets[size][0]

    def render(self, camera: Camera) -> np.ndarray:
        """(H, W, 3) ENU metres of the surface seen at each pixel centre (row 0 = top); NaN where
        the pixel sees no surface."""
        w, h = camera.intrinsics.width, camera.intrinsics.height
        fbo = self._target((w, h))
        self._draw(fbo, camera)
        wait_for_gpu(self.ctx)  # the GIL released while the rasteriser works (other threads run)
        data = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)[::-1]
        out = data[:, :, :3].astype(np.float64)
        out[data[:, :, 3] < 0.5] = np.nan
        return out

    def release(self) -> None:
        for fbo, color, depth in self._targets.values():
            fbo.release()
            color.release()
            depth.release()
        self.scene.forget(self.program)
        self.program.release()
