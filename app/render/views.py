"""The model as a camera sees it, off-screen: its colours (the model's textures and shading, no
video) and the surface position under each pixel, for registration's render-and-compare. Owns its
GL objects, and an EGL context of its own unless given one; call from one thread; `release()`
frees them. Its own context is current only inside its calls: whatever the calling thread had
current before stays current after (app.render.context.keep_current)."""

from __future__ import annotations

import contextlib

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.core.settings import ProjectionSettings
from app.render.context import create_offscreen_context, keep_current, made_current, wait_for_gpu
from app.render.offscreen import OffscreenTarget
from app.render.renderer import FusionRenderer
from app.scene.mesh import MeshData

MODEL_ONLY = ProjectionSettings(enabled=False)


class ModelViews:
    """Colour and position renderings of one scene from any pinhole camera."""

    def __init__(self, mesh: MeshData, ctx: moderngl.Context | None = None) -> None:
        self._own = ctx is None
        with keep_current():  # its own context current only inside _current blocks
            self.ctx = create_offscreen_context() if ctx is None else ctx
        with self._current():
            self.renderer = FusionRenderer(self.ctx, mesh)
        self._targets: dict[tuple[int, int], OffscreenTarget] = {}

    def _current(self) -> contextlib.AbstractContextManager:
        """Its own context made current for a block (the thread may use another between
        blocks); a context it was given is the caller's, already current."""
        return made_current(self.ctx) if self._own else contextlib.nullcontext()

    def render(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """((H, W, 3) uint8 RGB, (H, W, 3) ENU metres of the surface at each pixel centre, NaN
        where none) of `camera`'s pinhole intrinsics (with a lens: the pinhole enclosing its
        image), row 0 = the top; streamed tiles loaded to full detail first."""
        size = (camera.intrinsics.width, camera.intrinsics.height)
        with self._current():
            if size not in self._targets:
                self._targets[size] = OffscreenTarget(self.ctx, *size)
            target = self._targets[size]
            self.renderer.settle(camera, MODEL_ONLY)
            self.renderer.draw(camera, target.fbo, MODEL_ONLY)
            wait_for_gpu(self.ctx)  # the GIL released while the rasteriser works
            return target.read(), self.renderer.pick_map(camera)

    def release(self) -> None:
        with self._current():
            for target in self._targets.values():
                target.release()
            self.renderer.release()
        if self._own:
            self.ctx.release()
