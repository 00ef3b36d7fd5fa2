"""`geofuse export model`: the scene with what the clip saw baked into it, as a GLB any glTF viewer
opens: every static triangle (models, terrain, city models) textured by what the frames saw
there (app.export.memory: occlusion, rule newest/best/first), else the model's own colour. By
default the memory is paged (app.export.paged): each surface's texels as fine as the video's
pixels there (app.export.sampling), at most `resident_mb` held, one mesh and image a page (a
GLB holds them all while it is written; a 3D Tiles tileset, app.export.painted_tiles, one page
at a time). With max_texels, one atlas (app.export.atlas) within that many texels.

The GLB is in the session's local frame (east, north, up metres from its origin, turned to
glTF's Y-up: X east, Y up, Z south) and says that origin in its scene's extras
(`geofuse_origin`: lat, lon, ellipsoidal h); to place it elsewhere give that origin (and
up_axis Y) as a model's placement. Where the scene's imagery or heights came from providers
that must be credited (a world's tiles: app.scene.layers.scene_credit), the GLB's
`asset.copyright` says so, as glTF viewers (CesiumJS among them) show it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from app.core.outputs import check_output, write_atomically
from app.export.atlas import Atlas, layout, triangles_of
from app.export.memory import SurfaceMemory
from app.export.paged import DEFAULT_RESIDENT_MB, PagedMemory
from app.export.painting import (
    DECODE_LONG_SIDE,
    DEFAULT_EVERY_S,
    ClipToPaint,
    clips_on_a_timeline,
    paint_frame_indices,
    paint_frames,
    planned_cameras,
    scene_to_paint,
)
from app.export.sampling import FINEST_M, texel_targets
from app.render.views import ModelViews
from app.scene.mesh import MeshData
from app.session.camera_track import CameraTrack
from app.session.model import Session

DEFAULT_MAX_TEXELS = 4_000_000  # one atlas's texels, where one is asked for


@dataclass(frozen=True)
class ModelOptions:
    """rule: newest, best or first; every_s: seconds of video between frames painted;
    max_texels: one atlas of at most this many texels (its texels from the video's ground
    sampling, scaled up alike to fit), or None: a paged memory (app.export.paged) at the
    video's ground sampling, no texel finer than finest_m, holding at most resident_mb."""

    rule: str = "newest"
    every_s: float = DEFAULT_EVERY_S
    max_texels: int | None = None
    finest_m: float = FINEST_M
    resident_mb: float = DEFAULT_RESIDENT_MB


@dataclass
class _Setup:
    clips: list[ClipToPaint]
    plans: list[np.ndarray]
    utc0: float | None
    scene: MeshData
    texels: Callable[[np.ndarray], np.ndarray]


def _setup(session, track, options, further) -> _Setup:
    clips, utc0 = clips_on_a_timeline([(session, track), *further])
    plans = [paint_frame_indices(c.track, options.every_s) for c in clips]
    cameras = planned_cameras(clips, plans)
    scene = scene_to_paint(session.scene(), cameras)

    def texels(triangles: np.ndarray) -> np.ndarray:
        return texel_targets(triangles, cameras, DECODE_LONG_SIDE, options.finest_m)

    return _Setup(clips, plans, utc0, scene, texels)


def _painted(setup: _Setup, memory, progress) -> None:
    views = ModelViews(setup.scene)
    try:
        paint_frames(memory, views, setup.clips, setup.plans, setup.utc0, progress)
    finally:
        views.release()


def paint_model(
    session: Session,
    track: CameraTrack,
    options: ModelOptions = ModelOptions(max_texels=DEFAULT_MAX_TEXELS),
    progress: Callable[[float], None] | None = None,
    further: list[tuple[Session, CameraTrack]] = (),
) -> tuple[Atlas, SurfaceMemory]:
    """The scene's atlas (options.max_texels at most) and what the clip painted on it under
    one solved track, with the further clips (session, solved track) on its timeline
    (app.export.painting)."""
    setup = _setup(session, track, options, further)
    atlas = layout(setup.scene, options.max_texels or DEFAULT_MAX_TEXELS,
                   setup.texels(triangles_of(setup.scene).corners))  # fmt: skip
    memory = SurfaceMemory(atlas.points, atlas.normals, options.rule)
    _painted(setup, memory, progress)
    return atlas, memory


def paint_model_paged(
    session: Session,
    track: CameraTrack,
    options: ModelOptions = ModelOptions(),
    progress: Callable[[float], None] | None = None,
    further: list[tuple[Session, CameraTrack]] = (),
) -> PagedMemory:
    """As paint_model, into a paged memory at the video's ground sampling (close it once
    written)."""
    setup = _setup(session, track, options, further)
    paged = PagedMemory(setup.scene, setup.texels, options.rule,
                        resident_bytes=options.resident_mb * 1e6)  # fmt: skip
    try:
        _painted(setup, paged, progress)
    except BaseException:
        paged.close()
        raise
    return paged


def glb_bytes(
    triangles: np.ndarray, uvs: np.ndarray, image: np.ndarray, copyright: str = ""
) -> bytes:
    """Triangles (T, 3, 3) ENU m with their uvs (T, 3, 2, v up) on an (H, W, 3) image (top row
    first) as one textured glTF mesh, Y-up (X east, Y up, Z south), as GLB bytes; copyright:
    its asset.copyright (what its imagery must be credited with; '' none)."""
    return _glb(trimesh.Scene(_mesh(triangles, uvs, image)), copyright)


def _glb(scene: trimesh.Scene, copyright: str) -> bytes:
    """The scene as GLB bytes, `copyright` (where given) in its asset."""

    def credit(tree: dict) -> None:
        tree.setdefault("asset", {})["copyright"] = copyright

    return scene.export(file_type="glb", tree_postprocessor=credit if copyright else None)


def _mesh(triangles: np.ndarray, uvs: np.ndarray, image: np.ndarray) -> trimesh.Trimesh:
    v = triangles.reshape(-1, 3)
    material = trimesh.visual.material.PBRMaterial(
        name="painted",
        baseColorTexture=Image.fromarray(image),
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    return trimesh.Trimesh(
        vertices=np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]),
        faces=np.arange(len(v)).reshape(-1, 3),
        visual=trimesh.visual.TextureVisuals(uv=uvs.reshape(-1, 2), material=material),
        process=False,
    )


def painted_glb(
    parts: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
    origin: tuple[float, float, float],
    copyright: str = "",
) -> bytes:
    """The painted scene as GLB bytes (see the module docstring): one mesh a part (triangles
    (n, 3, 3) ENU m, uvs (n, 3, 2), RGB image top row first: one atlas, or a paged memory's
    pages, app.export.painted_tiles); copyright: its asset.copyright ('' none)."""
    scene = trimesh.Scene([_mesh(*part) for part in parts])
    scene.metadata["geofuse_origin"] = [float(x) for x in origin]
    return _glb(scene, copyright)


def atlas_part(atlas: Atlas, memory: SurfaceMemory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One atlas painted, as painted_glb's part."""
    return atlas.triangles, atlas.uvs, atlas.image(memory.rgb, memory.seen)


def write_painted(
    parts: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
    origin: tuple[float, float, float],
    out: Path,
    inputs: list[Path],
    credit: str = "",
) -> Path:
    """The painted GLB at `out`, atomically, never over an input; credit: its scene's
    (scene_credit), written as its asset.copyright."""
    out = check_output(out, "--out", (".glb",), inputs)
    data = painted_glb(parts, origin, credit)
    return write_atomically(out, "--out", lambda f: f.write(data), binary=True)
