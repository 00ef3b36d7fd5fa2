"""Roofs draped with the imagery under them (issue 48): buildings extruded from footprints
(app.scene.city.footprints: OpenStreetMap, Overture) carry no texture, while the orthophoto
draped on the terrain (a DEM layer's `ortho`, a world's imagery) shows their roofs from above.
Left grey, the roofs hide that imagery from the camera, and a view from above (a drone's
survey) has nothing left to match but grass; draped, the roofs show what the imagery shows
there, as a 3D city viewer drapes its basemap.

Each face of the buildings that faces up (its normal at least ROOF_MIN_UP upward: a flat or
pitched roof) takes, at each corner, the texture coordinate the terrain has under that corner
(straight down: interpolated linearly over the terrain's vertices, as the terrain itself is
drawn), and is drawn with the terrain's texture, cropped to what the roofs use. Walls, floors
and roofs with no textured terrain under every corner stay as they were (the geometry path of
registration aligns their lines). Imagery that is not a true orthophoto shows a tall building's
roof displaced along its lean: it is draped where the imagery has it under the footprint.

Positions are ENU metres of the scene's frame; textures bottom row first (app.scene.mesh)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.interpolate import LinearNDInterpolator

from app.scene.mesh import MeshData, Primitive

ROOF_MIN_UP = 0.5  # a face whose unit normal rises at least this much is a roof (up to 60 deg)
NEAR_M = 50.0  # the terrain's vertices within this of the roofs' extent are interpolated over


def roof_faces(prim: Primitive) -> npt.NDArray[np.bool_]:
    """(M,) which triangles of `prim` face up (a roof: the unit normal's up component at least
    ROOF_MIN_UP, by the triangles' counter-clockwise winding)."""
    tri = prim.positions[prim.indices].astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    return (length > 0) & (n[:, 2] >= ROOF_MIN_UP * np.where(length > 0, length, 1.0))


def uv_under(ground: Primitive, xy: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(N, 2) the texture coordinates a textured terrain `ground` has straight under each point
    (N, 2) ENU east, north m; NaN where the terrain does not reach."""
    xy = np.atleast_2d(np.asarray(xy, np.float64))
    out = np.full((len(xy), 2), np.nan)
    if not len(xy) or len(ground.positions) < 3:
        return out
    gxy = ground.positions[:, :2].astype(np.float64)
    lo, hi = xy.min(axis=0) - NEAR_M, xy.max(axis=0) + NEAR_M
    near = np.flatnonzero(((gxy >= lo) & (gxy <= hi)).all(axis=1))
    if len(near) < 3:  # a terrain coarser than the margin: its corners around the points
        near = np.arange(len(gxy))
    try:
        interp = LinearNDInterpolator(gxy[near], ground.uvs[near].astype(np.float64))
    except Exception:  # noqa: BLE001 (qhull: the points lie on a line, no surface to drape)
        return out
    return np.asarray(interp(xy), np.float64)


def _cropped(texture: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the texture cut to the texels uv (N, 2) reach, a texel of margin; uv in it)."""
    h, w = texture.shape[:2]
    px = uv * [w, h]
    c0, r0 = np.maximum(np.floor(px.min(axis=0)).astype(int) - 1, 0)
    c1, r1 = np.minimum(np.ceil(px.max(axis=0)).astype(int) + 1, [w, h])
    part = np.ascontiguousarray(texture[r0:r1, c0:c1])
    return part, (px - [c0, r0]) / [c1 - c0, r1 - r0]


def draped_roofs(city: MeshData, terrain: list[Primitive]) -> tuple[MeshData, int]:
    """(`city` with its untextured primitives' roofs (roof_faces) drawn with the texture of
    the textured primitive of `terrain` under them, the number of roof triangles draped)."""
    grounds = [p for p in terrain if p.textured]
    if not grounds:
        return city, 0
    prims, draped = [], 0
    for prim in city.primitives:
        roof = roof_faces(prim) if not prim.textured and len(prim.indices) else None
        if roof is None or not roof.any():
            prims.append(prim)
            continue
        corners = prim.indices[roof].reshape(-1)
        best, best_uv, best_ok = None, None, np.zeros(roof.sum(), bool)
        for g in grounds:  # the terrain under most of the roofs
            uv = uv_under(g, prim.positions[corners, :2]).reshape(-1, 3, 2)
            ok = np.isfinite(uv).all(axis=(1, 2))
            if ok.sum() > best_ok.sum():
                best, best_uv, best_ok = g, uv, ok
        if best is None:
            prims.append(prim)
            continue
        faces = np.flatnonzero(roof)[best_ok]
        keep = np.ones(len(prim.indices), bool)
        keep[faces] = False
        if keep.any():
            prims.append(Primitive(prim.positions, prim.colors, prim.indices[keep], name=prim.name))
        texture, uv = _cropped(best.texture, best_uv[best_ok].reshape(-1, 2))
        n = len(uv)
        prims.append(
            Primitive(
                prim.positions[prim.indices[faces].reshape(-1)].copy(),
                np.ones((n, 4), np.float32),
                np.arange(n, dtype=np.uint32).reshape(-1, 3),
                uv.astype(np.float32),
                texture,
                name=f"{prim.name} roofs",
            )
        )
        draped += len(faces)
    return MeshData(prims, city.tilesets, city.features), draped
