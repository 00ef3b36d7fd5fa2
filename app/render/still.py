"""One still: a scene, an image and the image's camera pose, rendered off-screen to an array.

This is what `geofuse render` and the demo call; tests call it too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.camera.pinhole import Camera, look_at_quat
from app.core.constants import DEFAULT_NEAR_M
from app.core.settings import OverlaySettings, ProjectionSettings
from app.geodesy import rotations
from app.render.context import create_offscreen_context, keep_current
from app.render.offscreen import render_to_array
from app.render.renderer import FusionRenderer
from app.scene.mesh import MeshData


@dataclass(frozen=True)
class ThirdPerson:
    """Default window camera: `back_m` behind and `up_m` above the projector, looking at the
    point `ahead_m` along its optical axis."""

    back_m: float = 18.0
    up_m: float = 10.0
    ahead_m: float = 35.0

    def eye_and_target(self, projector: Camera) -> tuple[np.ndarray, np.ndarray]:

        forward = rotations.rotate(projector.orientation, [0.0, 0.0, -1.0])
        flat = np.array([forward[0], forward[1], 0.0])
        flat = flat / max(np.linalg.norm(flat), 1e-9)
        pos = np.asarray(projector.position)
        return pos - flat * self.back_m + [0.0, 0.0, self.up_m], pos + forward * self.ahead_m


def window_camera(
    projector: Camera,
    intrinsics,
    eye: npt.ArrayLike | None,
    target: npt.ArrayLike | None,
    far: float,
) -> Camera:
    """The window camera at eye looking at target, or the third-person default."""
    if eye is None or target is None:
        default_eye, default_target = ThirdPerson().eye_and_target(projector)
        eye = default_eye if eye is None else eye
        target = default_target if target is None else target
    return Camera.create(intrinsics, eye, look_at_quat(eye, target), near=DEFAULT_NEAR_M, far=far)


@dataclass(frozen=True)
class Still:
    """A rendered still: rgb (H, W, 3) uint8; samples: how many of the scene's fragments were
    drawn (an occlusion query; 0: nothing of the scene is in the picture); left_out: what could
    not be drawn (beyond the projectors drawn at once, or for want of texture units), in a
    sentence (None: everything was)."""

    rgb: np.ndarray
    samples: int
    left_out: str | None = None


@keep_current()  # its own context, made and released here: the caller's stays current
def render_still(
    mesh: MeshData,
    image: npt.NDArray[np.uint8] | None,
    projector: Camera,
    view: Camera,
    settings: ProjectionSettings = ProjectionSettings(),
    overlays: OverlaySettings = OverlaySettings(),
    trajectory: npt.ArrayLike | None = None,
    extras: list[tuple[np.ndarray, Camera, float]] | None = None,
    priority: float = 0.0,
    ages_s: list[float] | None = None,
) -> Still:
    """Render `mesh` from `view` with `image` projected from `projector`, and say how much of
    the scene was drawn. extras: further (image, camera, priority) projected at once; priority:
    the first projector's (where several see a surface: app.render.passes.ExtraProjector);
    ages_s: the first's and each further frame's age (s before the moment drawn; ties go to the
    younger), default all 0."""
    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, mesh)
    try:
        if image is not None:
            renderer.set_video_frame(image)
        ages = list(ages_s) if ages_s is not None else [0.0] * (1 + len(extras or []))
        renderer.set_projector(projector, priority, ages[0])
        renderer.set_trajectory(trajectory)
        renderer.set_extra_projectors(
            [(cam, img, prio) for img, cam, prio in extras or []], ages_s=ages[1:]
        )
        renderer.scene_pass.count_samples = True
        rgb = render_to_array(renderer, view, settings, overlays)
        sp = renderer.scene_pass
        said = [m for m in (renderer.extras_left_out_message, sp.left_out_message) if m]
        return Still(rgb, int(sp.samples or 0), "; ".join(said) or None)
    finally:
        renderer.release()
        ctx.release()
