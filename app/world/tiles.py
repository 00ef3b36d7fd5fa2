"""Web Mercator (EPSG:3857) tile maths of the XYZ scheme (OSM "slippy map" tiles; TMS counts
rows from the south: row = 2^z - 1 - y).

Tile (x, y) at zoom z covers [x, x + 1] x [y, y + 1] / 2^z of the square world, x growing
east from longitude -180, y growing south from latitude +85.05. Pure: pyproj for the
projection, numpy for the arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pyproj

HALF_WORLD_M = math.pi * 6378137.0  # EPSG:3857 x (and y) of the world's east (north) edge, m
MAX_LATITUDE = 85.0511287798  # Web Mercator's north and south limit, deg
EARTH_CIRCUMFERENCE_M = 2.0 * HALF_WORLD_M

_TO_MERCATOR = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)


def to_mercator(lat: npt.ArrayLike, lon: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 latitude, longitude (deg) -> EPSG:3857 (x, y) m (latitude clamped to the map)."""
    lat = np.clip(np.asarray(lat, np.float64), -MAX_LATITUDE, MAX_LATITUDE)
    x, y = _TO_MERCATOR.transform(np.asarray(lon, np.float64), lat)
    return np.asarray(x, np.float64), np.asarray(y, np.float64)


def tile_span_m(z: int) -> float:
    """A tile's side in EPSG:3857 metres at zoom z (on the ground: times cos(latitude))."""
    return EARTH_CIRCUMFERENCE_M / (1 << z)


def pixel_m(z: int, tile_px: int, lat_deg: float) -> float:
    """Ground size (m) of a pixel of a tile_px-wide tile at zoom z and latitude lat_deg."""
    return tile_span_m(z) / tile_px * math.cos(math.radians(lat_deg))


@dataclass(frozen=True)
class TileSpan:
    """Tiles x0..x1 (columns), y0..y1 (rows from the top), inclusive, at level z of some grid."""

    z: int
    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of tiles."""
        return self.y1 - self.y0 + 1, self.x1 - self.x0 + 1

    @property
    def count(self) -> int:
        rows, cols = self.shape
        return rows * cols

    def tiles(self) -> list[tuple[int, int, int]]:
        """Every (z, x, y), row by row from the north-west."""
        return [
            (self.z, x, y) for y in range(self.y0, self.y1 + 1) for x in range(self.x0, self.x1 + 1)
        ]


@dataclass(frozen=True)
class TileRange(TileSpan):
    """Tiles x0..x1, y0..y1 (inclusive, XYZ rows) at zoom z: a rectangle of the map."""

    def bounds_m(self) -> tuple[float, float, float, float]:
        """(west, south, east, north) EPSG:3857 m of the rectangle's outer edges."""
        s = tile_span_m(self.z)
        return (
            -HALF_WORLD_M + self.x0 * s,
            HALF_WORLD_M - (self.y1 + 1) * s,
            -HALF_WORLD_M + (self.x1 + 1) * s,
            HALF_WORLD_M - self.y0 * s,
        )

    def transform(self, tile_px: int) -> tuple[float, float, float, float, float, float]:
        """The mosaic's GDAL affine (a, b, c, d, e, f): pixel (col, row) -> EPSG:3857 (x, y) of
        its corner, north up, tile_px pixels a tile."""
        west, _, _, north = self.bounds_m()
        res = tile_span_m(self.z) / tile_px
        return (res, 0.0, west, 0.0, -res, north)


def covering(bounds_m: tuple[float, float, float, float], z: int) -> TileRange:
    """The tiles at zoom z covering (west, south, east, north) EPSG:3857 m."""
    west, south, east, north = bounds_m
    s = tile_span_m(z)
    n = (1 << z) - 1

    def col(x: float) -> int:
        return min(max(int(math.floor((x + HALF_WORLD_M) / s)), 0), n)

    def row(y: float) -> int:
        return min(max(int(math.floor((HALF_WORLD_M - y) / s)), 0), n)

    return TileRange(z, col(west), row(north), col(east), row(south))


def choose_zoom(
    bounds_m: tuple[float, float, float, float],
    needed_m: float,
    lat_deg: float,
    tile_px: int,
    max_zoom: int,
    max_tiles: int,
    min_zoom: int = 0,
) -> int:
    """The coarsest zoom whose pixels are at most needed_m on the ground (m) at lat_deg, no finer
    than max_zoom and no finer than max_tiles tiles over bounds_m allow (never below min_zoom)."""
    z = min_zoom
    while z < max_zoom and pixel_m(z, tile_px, lat_deg) > needed_m:
        if covering(bounds_m, z + 1).count > max_tiles:
            break
        z += 1
    return z


def parent(z: int, x: int, y: int, levels: int) -> tuple[int, int, int, int, int]:
    """(z', x', y', col, row) of the tile `levels` zooms up that holds (z, x, y), and where in
    it, in units of the child's size (0 .. 2^levels - 1), the child sits."""
    k = 1 << levels
    return z - levels, x // k, y // k, x % k, y % k
