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

__all__ = ["plan_footprint"]

POLYGONAL = ("Polygon", "MultiPolygon")
MIN_PART_DEG2 = 1e-12  # pieces smaller than this (about 0.01 m2) are slivers of the union: dropped
GRID_DEG = 1e-9  # coordinates are snapped to this grid (0.1 mm), keeping the polygon valid


def plan_footprint(ground_lat_lon: np.ndarray) -> BaseGeometry | None:
    """The union of the grid's cells (ground_lat_lon: (rows, cols, 2) lat, lon degrees) in plan
    view, as a valid Polygon or MultiPolygon in (lon, lat); None when no cell has an area."""
    lon_lat = np.asarray(ground_lat_lon, np.float64)[..., ::-1]
    cells = np.stack(
        [
            lon_lat[:-1, :-1],
            lon_lat[:-1, 1:],
            lon_lat[1:, 1:],
            lon_lat[1:, :-1],
            lon_lat[:-1, :-1],
        ],
        axis=2,
    ).reshape(-1, 5, 2)
    cells = cells[np.isfinite(cells).all(axis=(1, 2))]
    polygons = shapely.polygons(cells)
    bad = ~shapely.is_valid(polygons)
    if bad.any():
        parts = shapely.get_parts(shapely.make_valid(polygons[bad]))
        polygons = np.concatenate(
            [polygons[~bad], parts[np.isin(shapely.get_type_id(parts), (3, 6))]]
        )
    polygons = polygons[shapely.area(polygons) > 0.0]
    if len(polygons) == 0:
        return None
    union = shapely.union_all(polygons)
    if union.geom_type not in POLYGONAL:  # a collection: keep its polygons
        union = shapely.union_all([g for g in shapely.get_parts(union) if g.geom_type in POLYGONAL])
    if union.is_empty:
        return None
    # On a grid of 1e-9 degrees (0.1 mm), which GEOS keeps valid; JSON then holds it exactly.
    snapped = shapely.set_precision(union, GRID_DEG)
    parts = [
        p for p in shapely.get_parts(snapped) if p.geom_type == "Polygon" and p.area > MIN_PART_DEG2
    ]
    if not parts:
        return None
    shape = parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
    return shapely.orient_polygons(shape, exterior_cw=False)
