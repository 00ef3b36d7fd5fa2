"""Off-screen rendering to numpy arrays (tests, CLI export, benchmarks)."""

from __future__ import annotations

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.core.settings import OverlaySettings, ProjectionSettings
from app.render.renderer import FusionRenderer


class OffscreenTarget:
    """A colour + depth framebuffer of width x height pixels."""

    def __init__(self, ctx: moderngl.Context, width: int, height: int) -> None:
        self.ctx = ctx
        self.size = (width, height)
        self.color = ctx.renderbuffer(self.size, 4)
        self.depth = ctx.depth_renderbuffer(self.size)
        self.fbo = ctx.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)

    def read(self) -> np.ndarray:
        """The framebuffer as (H, W, 3) uint8 RGB, row 0 = the top of the image."""
        w, h = self.size
        data = np.frombuffer(self.fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)
        return data[::-1].copy()

    def release(self) -> None:
        self.fbo.release()
        self.color.release()
        self.depth.release()


def render_to_array(
    renderer: FusionRenderer,
    view: Camera,
    settings: ProjectionSettings = ProjectionSettings(),
    overlays: OverlaySettings = OverlaySettings(frustum=False, trajectory=False),
    target: OffscreenTarget | None = None,
    settle: bool = True,
) -> np.ndarray:
    """Render one view (the size of `view`'s intrinsics) to (H, W, 3) uint8 RGB, top row first.
    With settle, streamed tiles are loaded to full detail for the view and the projector first."""
    if settle:
        renderer.settle(view, settings)
    own = target is None
    if target is None:
        target = OffscreenTarget(renderer.ctx, view.intrinsics.width, view.intrinsics.height)
    try:
        renderer.draw(view, target.fbo, settings, overlays)
        return target.read()
    finally:
        if own:
            target.release()
