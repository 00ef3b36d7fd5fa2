"""`geofuse export model`: the scene with what the clip saw baked into it, as a GLB any glTF viewer
opens: every static triangle (models, terrain, city models) in one mesh textured by one atlas
(app.export.atlas), each texel painted by the frames that saw its surface point
(app.export.memory: occlusion, rule newest/best/first), else the model's own colour.

The GLB is in the session's local frame (east, north, up metres from its origin, turned to
glTF's Y-up: X east, Y up, Z south) and says that origin in its scene's extras
(`geofuse_origin`: lat, lon, ellipsoidal h); to place it elsewhere give that origin (and
up_axis Y) as a model's placement.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from app.core.outputs import check_output, write_atomically
from app.export.atlas import Atlas, layout
from app.export.memory import SurfaceMemory
from app.export.painting import (
    DEFAULT_EVERY_S,
    clips_on_a_timeline,
    paint_frame_indices,
    paint_frames,
    scene_to_paint,
)
from app.render.views import ModelViews
from app.session.camera_track import CameraTrack
from app.session.model import Session

DEFAULT_MAX_TEXELS = 4_000_000


@dataclass(frozen=True)
class ModelOptions:
    """rule: newest, best or first; every_s: seconds of video between frames painted;
    max_texels: the atlas's size at most (its texel size follows from it)."""

    rule: str = "newest"
    every_s: float = DEFAULT_EVERY_S
    max_texels: int = DEFAULT_MAX_TEXELS


def paint_model(
    session: Session,
    track: CameraTrack,
    options: ModelOptions = ModelOptions(),
    progress: Callable[[float], None] | None = None,
    further: list[tuple[Session, CameraTrack]] = (),
) -> tuple[Atlas, SurfaceMemory]:
    """The scene's atlas and what the clip painted on it under one solved track, with the
    further clips (session, solved track) on its timeline (app.export.painting)."""
    clips, utc0 = clips_on_a_timeline([(session, track), *further])
    plans = [paint_frame_indices(c.track, options.every_s) for c in clips]
    scene = scene_to_paint(session.scene(), clips, plans)
    atlas = layout(scene, options.max_texels)
    memory = SurfaceMemory(atlas.points, atlas.normals, options.rule)
    views = ModelViews(scene)
    try:
        paint_frames(memory, views, clips, plans, utc0, progress)
    finally:
        views.release()
    return atlas, memory


def glb_bytes(triangles: np.ndarray, uvs: np.ndarray, image: np.ndarray) -> bytes:
    """Triangles (T, 3, 3) ENU m with their uvs (T, 3, 2, v up) on an (H, W, 3) image (top row
    first) as one textured glTF mesh, Y-up (X east, Y up, Z south), as GLB bytes."""
    return _scene(triangles, uvs, image).export(file_type="glb")


def _scene(triangles: np.ndarray, uvs: np.ndarray, image: np.ndarray) -> trimesh.Scene:
    v = triangles.reshape(-1, 3)
    material = trimesh.visual.material.PBRMaterial(
        name="painted",
        baseColorTexture=Image.fromarray(image),
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    mesh = trimesh.Trimesh(
        vertices=np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]),
        faces=np.arange(len(v)).reshape(-1, 3),
        visual=trimesh.visual.TextureVisuals(uv=uvs.reshape(-1, 2), material=material),
        process=False,
    )
    return trimesh.Scene(mesh)


def painted_glb(atlas: Atlas, memory: SurfaceMemory, origin: tuple[float, float, float]) -> bytes:
    """The painted scene as GLB bytes (see the module docstring)."""
    scene = _scene(atlas.triangles, atlas.uvs, atlas.image(memory.rgb, memory.seen))
    scene.metadata["geofuse_origin"] = [float(x) for x in origin]
    return scene.export(file_type="glb")


def write_painted(
    atlas: Atlas,
    memory: SurfaceMemory,
    origin: tuple[float, float, float],
    out: Path,
    inputs: list[Path],
) -> Path:
    """The painted GLB at `out`, atomically, never over an input."""
    out = check_output(out, "--out", (".glb",), inputs)
    data = painted_glb(atlas, memory, origin)
    return write_atomically(out, "--out", lambda f: f.write(data), binary=True)
