"""Ground height under points: vertical rays against the scene's triangles (pure numpy).

Used to place a hand-held or body-worn camera at the model's ground plus a mount height, because
phone GNSS heights are off by metres while the model's ground is not.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.scene.mesh import MeshData
from app.scene.tiles.stream import LOAD_ERRORS, decode_tile

CHUNK = 200_000  # triangles per vectorised batch


def tileset_surface(tileset, xy: np.ndarray) -> list:
    """The primitives (ENU) of every tile at full detail whose box lies over any of the points
    (N, 2) ENU m: read and decoded here, on the CPU, once (a tileset's ground under a track).
    Tiles that cannot be read are left out."""

    found, stack = [], [tileset.root]
    while stack:
        tile = stack.pop()
        lo, hi = tile.box[0, :2] - 1.0, tile.box[1, :2] + 1.0
        if not np.any(np.all((xy >= lo) & (xy <= hi), axis=1)):
            continue
        try:
            tileset.expand(tile)
        except LOAD_ERRORS as exc:
            tileset.add_failure(str(exc))
            tile.children = tile.children or []
        if tile.contents and (not tile.children or tile.refine == "ADD"):
            found.append(tile)
        stack.extend(tile.children or [])
    prims = []
    for tile in found:
        try:
            prims += decode_tile(tileset, tile, tileset.skipped).primitives
        except LOAD_ERRORS as exc:
            tileset.add_failure(str(exc))
    return prims


def ground_heights(mesh: MeshData, xy: npt.ArrayLike) -> np.ndarray:
    """(N,) lowest surface height (ENU z, m) under each (x, y); NaN where no triangle lies below.
    Streamed tilesets count with their full-detail tiles under the points.

    The lowest surface is taken so that a position that strays into a building's footprint (GNSS
    error) lands on the street level under it rather than on its roof.
    """
    pts = np.atleast_2d(np.asarray(xy, np.float64))[:, :2]
    best = np.full(len(pts), np.inf)
    prims = list(mesh.primitives)
    for tileset in mesh.tilesets:
        prims += tileset_surface(tileset, pts)
    for prim in prims:
        tri = prim.positions[prim.indices].astype(np.float64)  # (M, 3, 3)
        for start in range(0, len(tri), CHUNK):
            t = tri[start : start + CHUNK]
            lo, hi = t[:, :, :2].min(axis=1), t[:, :, :2].max(axis=1)
            for i, p in enumerate(pts):
                cand = np.flatnonzero(np.all((lo <= p) & (p <= hi), axis=1))
                if not len(cand):
                    continue
                a, b, c = t[cand, 0], t[cand, 1], t[cand, 2]
                v0, v1 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2]
                v2 = p - a[:, :2]
                den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
                ok = np.abs(den) > 1e-12  # vertical faces have no area seen from above
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
                    v = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
                inside = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9)
                if inside.any():
                    z = (
                        a[inside, 2]
                        + u[inside] * (b[inside, 2] - a[inside, 2])
                        + v[inside] * (c[inside, 2] - a[inside, 2])
                    )
                    best[i] = min(best[i], float(z.min()))
    return np.where(np.isfinite(best), best, np.nan)


def ellipsoidal_ground(mesh: MeshData, frame, lat_deg: float, lon_deg: float) -> float | None:
    """The ellipsoidal height (m) of the scene's lowest surface at (lat, lon) degrees in `frame`
    (an app.geodesy.enu.LocalFrame), or None where the scene has no surface there."""
    xy = frame.geodetic_to_enu(lat_deg, lon_deg, 0.0)
    z = ground_heights(mesh, np.atleast_2d(xy)[:, :2])[0]
    if not np.isfinite(z):
        return None
    return float(frame.enu_to_geodetic(np.array([xy[0], xy[1], z]))[2])
