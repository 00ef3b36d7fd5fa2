"""The plan-view footprint of a frame: the ground the video sees, seen from above, as a polygon
that OGC simple features (GEOS `is_valid`) accept, by construction.

The image border ray-cast onto the scene is a 3D ring; seen from above it folds back where it
runs up a wall or meets the sky clip, and a polygon made from it self-intersects. Instead, every
cell of the sampling grid (FOOTPRINT_SAMPLES rays across and down the image, app.export.records)
becomes a small quadrilateral between the four rays' landing points in plan view; a cell that
folds (a bow tie, where the surface turns away) is split into its valid parts by GEOS, a cell
with no area (on a vertical wall) is dropped; the cells' union is the footprint: a Polygon, or a
MultiPolygon where the ground seen is in pieces, each exterior ring counter-clockwise (RFC 7946).
Coordinates are longitude, latitude (degrees, WGS84)."""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from app.geodesy.enu import METRES_PER_DEGREE

__all__ = ["cell_rings", "plan_footprint"]

POLYGONAL = ("Polygon", "MultiPolygon")
MIN_PIECE_M2 = 0.01  # cells smaller than this in plan view (rays up a wall) stay out of the union
MIN_PART_DEG2 = 1e-12  # pieces smaller than this (about 0.01 m2) are slivers of the union: dropped
GRID_DEG = 1e-9  # coordinates are snapped to this grid (0.1 mm), keeping the polygon valid


def _cell_signs(lon_lat: np.ndarray) -> np.ndarray:
    """(rows - 1, cols - 1) the orientation of each cell in plan view: +1 or -1 where its four
    corners all turn that way, 0 where it folds (a bow tie), is flat or is not finite."""
    corners = np.stack(
        [lon_lat[:-1, :-1], lon_lat[:-1, 1:], lon_lat[1:, 1:], lon_lat[1:, :-1]], axis=2
    )
    corners = corners - lon_lat[0, 0]  # about one point: no cancellation at 100 degrees
    edges = np.roll(corners, -1, axis=2) - corners
    turns = edges[..., 0] * np.roll(edges[..., 1], -1, axis=2) - edges[..., 1] * np.roll(
        edges[..., 0], -1, axis=2
    )
    signs = np.sign(turns)
    same = np.all(signs == signs[..., :1], axis=2) & np.isfinite(turns).all(axis=2)
    return np.where(same, signs[..., 0], 0.0)


def _outline(lon_lat: np.ndarray) -> BaseGeometry | None:
    """The polygon of a block of the grid's outline when the block is one to one in plan view
    (its cells all of one orientation, checked by the caller) and the outline is a simple ring:
    then the union of its cells is exactly that polygon. None otherwise."""
    outline = np.concatenate(
        [lon_lat[0, :], lon_lat[1:, -1], lon_lat[-1, -2::-1], lon_lat[-2:0:-1, 0]]
    )
    polygon = shapely.Polygon(outline)
    return polygon if polygon.is_valid and polygon.area > 0.0 else None


def cell_rings(block: np.ndarray) -> np.ndarray:
    """(n, 5, 2) the closed rings of a block's cells."""
    return np.stack(
        [block[:-1, :-1], block[:-1, 1:], block[1:, 1:], block[1:, :-1], block[:-1, :-1]], axis=2
    ).reshape(-1, 5, 2)


def _cells(quads: np.ndarray) -> list[BaseGeometry]:
    """Cells (n, 5, 2) as polygons: those whose bounding box is below MIN_PIECE_M2 dropped (no
    part of them can be larger), each folded one split into its valid parts by GEOS."""
    quads = quads[np.isfinite(quads).all(axis=(1, 2))]
    extent = np.ptp(quads, axis=1)
    quads = quads[extent[:, 0] * extent[:, 1] > MIN_PIECE_M2]
    if len(quads) == 0:
        return []
    polygons = shapely.polygons(quads)
    bad = ~shapely.is_valid(polygons)
    if bad.any():
        parts = shapely.get_parts(shapely.make_valid(polygons[bad]))
        polygons = np.concatenate(
            [polygons[~bad], parts[np.isin(shapely.get_type_id(parts), (3, 6))]]
        )
    return list(polygons)


def _pieces(lon_lat: np.ndarray, signs: np.ndarray) -> list[BaseGeometry]:
    """The grid as few polygons as its folds allow: the whole grid's outline where it is one to
    one; else, row by row, each run of cells of one orientation as one strip (when its outline
    is a simple ring), and the other cells (folded, flat) one by one."""
    if np.all(signs == signs[0, 0]) and signs[0, 0] != 0:
        whole = _outline(lon_lat)
        if whole is not None:
            return [whole]
    out: list[BaseGeometry] = []
    loose = []
    for r in range(signs.shape[0]):
        row = signs[r]
        c = 0
        while c < len(row):
            end = c + 1
            while end < len(row) and row[end] == row[c]:
                end += 1
            block = lon_lat[r : r + 2, c : end + 1]
            strip = _outline(block) if row[c] != 0 and end - c > 1 else None
            if strip is not None:
                out.append(strip)
            else:
                loose.append(cell_rings(block))
            c = end
    return out + (_cells(np.concatenate(loose)) if loose else [])


def plan_footprint(ground_lat_lon: np.ndarray) -> BaseGeometry | None:
    """The union of the grid's cells (ground_lat_lon: (rows, cols, 2) lat, lon degrees) in plan
    view, as a valid Polygon or MultiPolygon in (lon, lat); None when no cell has an area.

    The union is taken in metres (a local plane through the grid's middle: an affine map of
    longitude and latitude, undone after), blocks of cells that are one to one in plan view
    enter it as their outline (the same area, far fewer polygons), and pieces smaller than
    MIN_PIECE_M2 (the slivers where rays climb a wall) are left out of it."""
    lon_lat = np.asarray(ground_lat_lon, np.float64)[..., ::-1]
    finite = lon_lat[np.isfinite(lon_lat).all(axis=-1)]
    if len(finite) < 3:
        return None
    o = finite[len(finite) // 2]
    scale = np.array([np.cos(np.radians(o[1])) * METRES_PER_DEGREE, METRES_PER_DEGREE])
    metres = (lon_lat - o) * scale
    polygons = np.array(_pieces(metres, _cell_signs(metres)), dtype=object)
    polygons = polygons[shapely.area(polygons) > MIN_PIECE_M2] if len(polygons) else polygons
    if len(polygons) == 0:
        return None
    union = shapely.union_all(polygons)
    if union.geom_type not in POLYGONAL:  # a collection: keep its polygons
        union = shapely.union_all([g for g in shapely.get_parts(union) if g.geom_type in POLYGONAL])
    if union.is_empty:
        return None
    union = shapely.transform(union, lambda xy: xy / scale + o)
    # On a grid of 1e-9 degrees (0.1 mm), which GEOS keeps valid; JSON then holds it exactly.
    snapped = shapely.set_precision(union, GRID_DEG)
    parts = [
        p for p in shapely.get_parts(snapped) if p.geom_type == "Polygon" and p.area > MIN_PART_DEG2
    ]
    if not parts:
        return None
    shape = parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
    return shapely.orient_polygons(shape, exterior_cw=False)
