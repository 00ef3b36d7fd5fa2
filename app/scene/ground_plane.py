"""The assumed ground when a clip comes without a model: a flat square at a given height with a
metric grid (1 m lines, darker every 10 m), so that distances can be read off the projection."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from app.scene import shapes
from app.scene.mesh import MeshData

ASSUMED_GROUND_MARGIN_M = 300.0  # the assumed ground reaches this far beyond a hand-held track
FLOWN_ABOVE_M = 10.0  # a track that rises this far above its ground somewhere is flown
FLOWN_GROUND_MARGIN_M = 500.0  # a flown camera's reach: this, plus FLOWN_REACH_PER_M x its height
FLOWN_REACH_PER_M = 10.0  # (a ray 5.7 deg below the horizon meets the ground 10x the height out)
TILE_M = 10.0  # one texture tile covers 10 m x 10 m
TILE_PX = 400


def grid_tile() -> np.ndarray:
    """(H, W, 3) uint8: one 10 m tile, 1 m minor lines, a 10 m major line on its border."""
    img = np.full((TILE_PX, TILE_PX, 3), (150, 152, 145), np.uint8)
    px_per_m = TILE_PX / TILE_M
    for k in range(int(TILE_M)):
        p = int(round(k * px_per_m))
        width = 4 if k == 0 else 1
        colour = (60, 62, 58) if k == 0 else (115, 117, 110)
        img[:, p : p + width] = colour
        img[p : p + width, :] = colour
    return img


def ground_plane(centre_xy: np.ndarray, height_m: float, half_size_m: float) -> MeshData:
    """A (2 half_size)^2 m square at ENU height `height_m`, centred on centre_xy, grid-textured."""
    cx, cy = (float(v) for v in centre_xy)
    h = float(half_size_m)
    quad = shapes.quad([cx - h, cy - h, height_m], [2 * h, 0.0, 0.0], [0.0, 2 * h, 0.0])
    # Texture coordinates in tiles, anchored at the ENU origin so the grid lines fall on whole metres.
    quad.uvs = (quad.vertices[:, :2]) / TILE_M
    plane = quad.primitive((1.0, 1.0, 1.0, 1.0), grid_tile(), name="assumed ground")
    return MeshData([replace(plane, cut=True)])


def ground_reach_m(heights_above_ground_m: npt.ArrayLike) -> float:
    """How far beyond its track (m on the ground) a camera sees the ground, from its heights
    above that ground (m): ASSUMED_GROUND_MARGIN_M for one held or mounted lower than
    FLOWN_ABOVE_M everywhere; FLOWN_GROUND_MARGIN_M + FLOWN_REACH_PER_M x its greatest height
    for one flown higher. The assumed ground and a world's area reach this far."""
    above = np.asarray(heights_above_ground_m, np.float64)
    top = float(np.nanmax(above)) if above.size and np.isfinite(above).any() else 0.0
    if top <= FLOWN_ABOVE_M:
        return ASSUMED_GROUND_MARGIN_M
    return FLOWN_GROUND_MARGIN_M + FLOWN_REACH_PER_M * top


def ground_under_track(
    frame, lat: np.ndarray, lon: np.ndarray, ground_h: float, margin_m: float
) -> MeshData:
    """The assumed ground for sessions without a model: a flat grid at ellipsoidal height
    ground_h (m) under every fix (deg, deg) of a track plus margin_m, in `frame` (a LocalFrame)."""
    enu = frame.geodetic_to_enu(lat, lon, np.full(len(lat), float(ground_h)))
    lo, hi = enu[:, :2].min(axis=0), enu[:, :2].max(axis=0)
    return ground_plane((lo + hi) / 2, float(enu[0, 2]), float(max(hi - lo) / 2 + margin_m))
