"""Load glTF/GLB, OBJ and PLY scenes through trimesh and place them in the session's ENU frame.

Placement (applied in this order to the model's own coordinates, float64):
1. up axis: a Y-up model (glTF's convention) becomes Z-up: (x, y, z) -> (x, -z, y);
2. scale (unitless factor, model units -> metres);
3. heading: a rotation about Up by `heading_deg`, clockwise seen from above (model north -> east);
4. the model's origin (lat, lon, h) -> the session frame through ECEF, so a model anchored
   elsewhere than the session origin lands exactly (curvature included).
A model whose coordinates are already ECEF (as in exported 3D Tiles content; detected by their
distance from the Earth's centre) skips 2-4 and goes ECEF -> session ENU directly. A glTF's ECEF
may be Z-up as stored (a root node that turns Y-up to Z-up, or Z-up vertices) or still Y-up (the
offset in a node translation, the Y-up -> Z-up turn left to the 3D Tiles runtime, as the official
3D Tiles tools write it): both readings are tried and the one nearer the session's origin is taken.
ECEF stored as float32 (as some PLY writers do) is only good to ~0.5 m at the Earth's radius:
prefer float64 or a node translation carrying the large offset, as 3D Tiles content does.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from app.core.constants import ECEF_MIN_RADIUS_M
from app.core.errors import SceneError
from app.geodesy.enu import LocalFrame
from app.scene.mesh import MeshData, Primitive, merge_untextured

SUPPORTED_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")
DEFAULT_COLOR = np.array([0.75, 0.75, 0.72, 1.0], np.float32)


@dataclass(frozen=True)
class Placement:
    """Where a model sits in the world.

    origin: (lat deg, lon deg, ellipsoidal h m) of the model's (0, 0, 0), or None for the session
    origin; up_axis: "Y" or "Z" (None: "Y" for glTF/GLB, "Z" otherwise); heading_deg: rotation
    about Up, clockwise from above; scale: model units -> metres.
    """

    origin: tuple[float, float, float] | None = None
    up_axis: str | None = None
    heading_deg: float = 0.0
    scale: float = 1.0


def _up_axis(path: Path, placement: Placement) -> str:
    up = placement.up_axis or ("Y" if path.suffix.lower() in (".glb", ".gltf") else "Z")
    up = up.upper()
    if up not in ("Y", "Z"):
        raise SceneError(
            path, f"up axis must be 'Y' or 'Z', got {placement.up_axis!r}", field="up_axis"
        )
    return up


def _y_up_to_z_up(p: np.ndarray) -> np.ndarray:
    """glTF's Y-up -> Z-up (the 3D Tiles rule): (x, y, z) -> (x, -z, y)."""
    return np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)


def model_to_enu(
    points: np.ndarray, path: Path, placement: Placement, frame: LocalFrame
) -> np.ndarray:
    """Model coordinates (N, 3) -> session ENU (N, 3) float64 metres, per the module docstring."""
    p = np.asarray(points, np.float64)
    y_up = _up_axis(path, placement) == "Y"
    if len(p) and np.linalg.norm(p.mean(axis=0)) > ECEF_MIN_RADIUS_M:
        if not y_up:
            return frame.ecef_to_enu(p)
        candidates = [frame.ecef_to_enu(p), frame.ecef_to_enu(_y_up_to_z_up(p))]
        return min(candidates, key=lambda e: float(np.linalg.norm(e.mean(axis=0))))
    if y_up:
        p = _y_up_to_z_up(p)
    p = p * float(placement.scale)
    if placement.heading_deg:
        a = np.radians(placement.heading_deg)
        c, s = np.cos(a), np.sin(a)
        p = p @ np.array(
            [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        )  # x' = c x + s y, y' = -s x + c y
    if placement.origin is not None:
        model_frame = LocalFrame(*placement.origin)
        if model_frame != frame:
            p = frame.ecef_to_enu(model_frame.enu_to_ecef(p))
    return p


def _material(visual: object) -> tuple[np.ndarray, np.ndarray | None]:
    """(base colour RGBA float [0,1], texture image uint8 RGBA top row first or None)."""
    material = getattr(visual, "material", None)
    if material is None:
        return DEFAULT_COLOR.copy(), None
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is None:
        factor = getattr(material, "diffuse", None)
    if factor is None:
        color = DEFAULT_COLOR.astype(np.float64)
    else:
        raw = np.asarray(factor)
        color = (
            raw / 255.0
            if np.issubdtype(raw.dtype, np.integer) or raw.max() > 1.0
            else raw.astype(np.float64)
        )
    if len(color) == 3:
        color = np.append(color, 1.0)
    tex = None
    if image is not None:
        tex = np.asarray(image.convert("RGBA"), np.uint8)
    return color.astype(np.float32), tex


def _primitive(
    mesh: trimesh.Trimesh, name: str, path: Path, placement: Placement, frame: LocalFrame
) -> Primitive:
    positions = model_to_enu(np.asarray(mesh.vertices), path, placement, frame).astype(np.float32)
    faces = np.asarray(mesh.faces, np.uint32)
    n = len(positions)
    visual = mesh.visual
    uvs = None
    texture = None
    colors = np.tile(DEFAULT_COLOR, (n, 1))
    if visual is not None and visual.kind == "texture":
        base, image = _material(visual)
        colors = np.tile(base, (n, 1))
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == n:
            uvs = np.asarray(uv, np.float32)
            texture = np.ascontiguousarray(image[::-1])
    elif visual is not None and visual.kind in ("vertex", "face"):
        vc = np.asarray(visual.vertex_colors, np.float32)
        if vc.shape == (n, 4):
            colors = vc / 255.0
    return Primitive(
        positions=positions,
        colors=colors.astype(np.float32),
        indices=faces,
        uvs=uvs,
        texture=texture,
        name=name,
    )


MAX_COORDINATE = 1e8  # model units: beyond any ECEF (6.4e6 m) or projected coordinate in use


def _drawable(mesh: trimesh.Trimesh, path: Path) -> trimesh.Trimesh | None:
    """The mesh with its zero-area faces dropped (None when none is left); SceneError for
    coordinates that are not finite or lie beyond MAX_COORDINATE (a broken export, not a model)."""
    v = np.asarray(mesh.vertices, np.float64)
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise SceneError(
            path, f"{int(bad.sum())} vertices are not finite numbers (NaN or infinite)"
        )
    far = np.abs(v).max(axis=1) > MAX_COORDINATE
    if far.any():
        raise SceneError(
            path,
            f"{int(far.sum())} vertices lie {float(np.abs(v).max()):.3g} units from the origin "
            f"(expected at most {MAX_COORDINATE:g}: a model's or ECEF coordinates)",
        )
    f = np.asarray(mesh.faces, np.int64)
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    extent = max(
        1.0, float(np.ptp(v, axis=0).max())
    )  # the mesh's size, not its distance from 0 (ECEF)
    keep = area2 > 1e-12 * extent**2
    if keep.all():
        return mesh
    if not keep.any():
        return None
    return mesh.submesh([np.flatnonzero(keep)], append=True)


def load_scene(path: str | Path, frame: LocalFrame, placement: Placement | None = None) -> MeshData:
    """Load a scene file and place it in `frame` (see the module docstring for the placement).

    Every mesh instance of the scene graph is included with its node transform. Raises
    SceneError naming the file for a missing file, an unknown format or a scene with no faces.
    """
    path = Path(path)
    placement = placement or Placement()
    if not path.is_file():
        raise SceneError(path, "scene file does not exist")
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise SceneError(
            path,
            f"unknown scene format {path.suffix!r} (expected one of {', '.join(SUPPORTED_SUFFIXES)})",
        )
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many kinds on a broken file
        raise SceneError(path, f"cannot read scene: {exc}") from exc
    meshes = [
        g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh) and len(g.faces)
    ]
    if not meshes:
        raise SceneError(path, "the scene holds no mesh with faces (expected triangles to draw)")
    meshes = [m for m in (_drawable(m, path) for m in meshes) if m is not None]
    if not meshes:
        raise SceneError(path, "every face of the scene is degenerate (zero area): nothing to draw")
    prims = [
        _primitive(m, str(m.metadata.get("name", i)), path, placement, frame)
        for i, m in enumerate(meshes)
    ]
    return MeshData(merge_untextured(prims))
