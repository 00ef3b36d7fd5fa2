"""Render a video of a scene from given camera poses with the project's own renderer (the sample
session's clip, the simulated drone flight): frames drawn off-screen, encoded by
app.simulate.phone.write_video at the given presentation times."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_FAR_M, VIEW_NEAR_M
from app.core.settings import ProjectionSettings
from app.render.context import create_offscreen_context, keep_current
from app.render.offscreen import OffscreenTarget
from app.render.renderer import FusionRenderer
from app.scene.mesh import MeshData
from app.simulate.phone import write_video


@keep_current()  # its own context, made and released here: the caller's stays current
def render_video(
    path: Path,
    mesh: MeshData,
    intr: Intrinsics,
    positions: np.ndarray,
    attitudes: np.ndarray,
    pts: np.ndarray,
    rotation_cw: int = 0,
    crf: int = 18,
    creation_time: str | None = None,
    before_frame: Callable[[object, int], None] | None = None,
    light_dir: np.ndarray | None = None,
    after_frame: Callable[[np.ndarray, int], np.ndarray] | None = None,
    klv: Sequence[tuple[float, bytes]] = (),
) -> Path:
    """An H.264 MP4 of `mesh` (ENU metres) seen through `intr` (the displayed image's pinhole)
        from positions (N, 3) ENU m and camera -> ENU quaternions (N, 4) at presentation times pts
        (N,) s; stored turned back by rotation_cw as a phone would. before_frame(renderer, k) may move
        things in the scene before frame k is drawn; light_dir (ENU, toward the light) lights the scene
    otherwise than the viewer does; after_frame(rgb, k) -> rgb applies the camera's own effects
    (blur, noise) to the drawn frame; klv: (time s, payload) packets muxed beside it (a .ts)."""

    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, mesh)
    target = OffscreenTarget(ctx, intr.width, intr.height)
    off = ProjectionSettings(enabled=False)
    if light_dir is not None:
        renderer.scene_pass.set_light(light_dir)

    def frame_at(k: int) -> np.ndarray:
        if before_frame is not None:
            before_frame(renderer, k)
        cam = Camera.create(intr, positions[k], attitudes[k], near=VIEW_NEAR_M, far=DEFAULT_FAR_M)
        renderer.draw(cam, target.fbo, off)
        rgb = target.read()
        return rgb if after_frame is None else after_frame(rgb, k)

    stored = (intr.height, intr.width) if rotation_cw % 180 else (intr.width, intr.height)
    try:
        write_video(
            path,
            pts,
            stored,
            rotation_cw,
            creation_time=creation_time,
            frame=frame_at,
            crf=crf,
            klv=klv,
        )
    finally:
        target.release()
        renderer.release()
        ctx.release()
    return path
