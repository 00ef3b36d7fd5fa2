"""Tile grids in any CRS: the tile matrices of an OGC WMTS TileMatrixSet or of a GeoPackage's
tile pyramid (the Web Mercator XYZ scheme is app.world.tiles).

A grid is a list of matrices, coarsest first; level z is its index there. Matrix z has
`cols` x `rows` tiles of `tile_w` x `tile_h` pixels, each pixel `res` CRS units a side, tile
(col, row) starting at the grid's top-left corner (left, top) and counting columns east and
rows south (WMTS TileCol/TileRow, GeoPackage tile_column/tile_row). Coordinates are always
(x, y) = (easting, northing) or (longitude, latitude), whatever the CRS's own axis order: the
WMTS reader swaps a latitude-first TopLeftCorner once, where it reads it. Pure: pyproj for the
projections and the ellipsoid's distances, numpy for the arithmetic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pyproj

from app.world.tiles import TileSpan

EDGE_SAMPLES = 21  # points along each edge of a lat/lon box when it is projected into a grid's CRS
WGS84_GEOD = pyproj.Geod(ellps="WGS84")
M_PER_DEG_LAT = 111_320.0  # ground metres of a degree of latitude (for a reach, not a measure)


@functools.lru_cache(maxsize=32)
def crs_of(text: str) -> pyproj.CRS:
    """The CRS a grid names (EPSG:n, an OGC URN, WKT), read once."""
    return pyproj.CRS.from_user_input(text)


@functools.lru_cache(maxsize=32)
def _transformer(src: str, dst: str) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(crs_of(src), crs_of(dst), always_xy=True)


def from_lonlat(crs: str, lon: npt.ArrayLike, lat: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 longitude, latitude (deg) -> (x, y) in `crs` (x east, y north)."""
    x, y = _transformer("EPSG:4326", crs).transform(
        np.asarray(lon, np.float64), np.asarray(lat, np.float64)
    )
    return np.asarray(x, np.float64), np.asarray(y, np.float64)


def to_lonlat(crs: str, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) in `crs` -> WGS84 longitude, latitude (deg)."""
    lon, lat = _transformer(crs, "EPSG:4326").transform(
        np.asarray(x, np.float64), np.asarray(y, np.float64)
    )
    return np.asarray(lon, np.float64), np.asarray(lat, np.float64)


def metres_per_unit(crs: pyproj.CRS) -> float:
    """Metres of one unit of the CRS's first axis; a degree as OGC WMTS counts it (2 pi a / 360,
    a: the ellipsoid's semi-major axis) for a geographic CRS."""
    if crs.is_geographic:
        return 2.0 * math.pi * crs.ellipsoid.semi_major_metre / 360.0
    return float(crs.axis_info[0].unit_conversion_factor)


def lonlat_box(
    lat: npt.ArrayLike, lon: npt.ArrayLike, reach_m: float
) -> tuple[float, float, float, float]:
    """(west, south, east, north) deg of a track (lat, lon deg) plus reach_m on the ground."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    dlat = reach_m / M_PER_DEG_LAT
    dlon = reach_m / (M_PER_DEG_LAT * max(math.cos(math.radians(float(np.mean(lat)))), 0.05))
    return (
        float(lon.min()) - dlon,
        float(lat.min()) - dlat,
        float(lon.max()) + dlon,
        float(lat.max()) + dlat,
    )


def box_in(crs: str, box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) in `crs` of a (west, south, east, north) deg box: its edges
    sampled (a projected box's edges curve)."""
    west, south, east, north = box
    t = np.linspace(0.0, 1.0, EDGE_SAMPLES)
    lon = np.concatenate([west + (east - west) * t, np.full_like(t, east)])
    lon = np.concatenate([lon, east - (east - west) * t, np.full_like(t, west)])
    lat = np.concatenate([np.full_like(t, south), south + (north - south) * t])
    lat = np.concatenate([lat, np.full_like(t, north), north - (north - south) * t])
    x, y = from_lonlat(crs, lon, lat)
    ok = np.isfinite(x) & np.isfinite(y)
    return float(x[ok].min()), float(y[ok].min()), float(x[ok].max()), float(y[ok].max())


def ground_m_per_unit(
    crs: str, x: float, y: float, step: float, step_y: float | None = None
) -> float:
    """Ground metres (on the WGS84 ellipsoid) of `step` CRS units east and `step_y` (default
    step) north of (x, y), averaged: what a pixel of those units covers there."""
    step_y = step if step_y is None else step_y
    lon, lat = to_lonlat(crs, [x, x + step, x], [y, y, y + step_y])
    _, _, dx = WGS84_GEOD.inv(lon[0], lat[0], lon[1], lat[1])
    _, _, dy = WGS84_GEOD.inv(lon[0], lat[0], lon[2], lat[2])
    return float(abs(dx) + abs(dy)) / 2.0


@dataclass(frozen=True)
class Matrix:
    """One level of a grid. ident: how requests name it (a WMTS TileMatrix identifier, a
    GeoPackage zoom_level); res: CRS units a pixel; left, top: the (x, y) CRS position of the
    matrix's top-left corner; tile_w, tile_h: pixels a tile; cols, rows: tiles across and down."""

    ident: str
    res: float
    left: float
    top: float
    tile_w: int
    tile_h: int
    cols: int
    rows: int

    @property
    def span(self) -> tuple[float, float]:
        """A tile's (width, height) in CRS units."""
        return self.tile_w * self.res, self.tile_h * self.res

    def tile_bounds(self, x: int, y: int) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) CRS units of tile column x, row y."""
        w, h = self.span
        return (
            self.left + x * w,
            self.top - (y + 1) * h,
            self.left + (x + 1) * w,
            self.top - y * h,
        )


@dataclass(frozen=True)
class TileGrid:
    """Matrices coarsest first (level z: index z), in `crs` (EPSG:n, a URN or WKT); name: the
    tile matrix set's (or the GeoPackage table's) identifier, for messages."""

    crs: str
    matrices: tuple[Matrix, ...]
    name: str = ""

    def covering(self, bounds: tuple[float, float, float, float], z: int) -> GridRange:
        """The tiles of level z covering (xmin, ymin, xmax, ymax) CRS units (clamped to the
        matrix)."""
        m = self.matrices[z]
        w, h = m.span
        xmin, ymin, xmax, ymax = bounds

        def col(v: float) -> int:
            return min(max(int(math.floor((v - m.left) / w)), 0), m.cols - 1)

        def row(v: float) -> int:
            return min(max(int(math.floor((m.top - v) / h)), 0), m.rows - 1)

        return GridRange(z, col(xmin), row(ymax), col(xmax), row(ymin), grid=self)

    def pixel_m(self, z: int, x: float, y: float) -> float:
        """Ground size (m) of a pixel of level z near (x, y) CRS units."""
        return ground_m_per_unit(self.crs, x, y, self.matrices[z].res)

    def choose_level(
        self, bounds: tuple[float, float, float, float], needed_m: float, max_tiles: int
    ) -> int:
        """The coarsest level whose pixels are at most needed_m on the ground (m) over bounds,
        no finer than max_tiles tiles over bounds allow (level 0 at least)."""
        cx, cy = (bounds[0] + bounds[2]) / 2.0, (bounds[1] + bounds[3]) / 2.0
        z = 0
        while z + 1 < len(self.matrices) and self.pixel_m(z, cx, cy) > needed_m:
            if self.covering(bounds, z + 1).count > max_tiles:
                break
            z += 1
        return z

    def parent(
        self, z: int, x: int, y: int, levels: int
    ) -> tuple[int, int, int, tuple[float, float, float, float]] | None:
        """(z', x', y', (row0, col0, height, width)) of the tile `levels` levels up that holds
        tile (z, x, y) whole, with where the child lies in it as fractions (0..1) of its height
        and width; None when no single tile holds it (grids that do not nest) or z' < 0."""
        if z - levels < 0:
            return None
        xmin, ymin, xmax, ymax = self.matrices[z].tile_bounds(x, y)
        p = self.matrices[z - levels]
        pw, ph = p.span
        eps = 1e-9 * max(pw, ph)
        px = int(math.floor(((xmin + xmax) / 2.0 - p.left) / pw))
        py = int(math.floor((p.top - (ymin + ymax) / 2.0) / ph))
        if not (0 <= px < p.cols and 0 <= py < p.rows):
            return None
        bx0, by0, bx1, by1 = p.tile_bounds(px, py)
        if xmin < bx0 - eps or xmax > bx1 + eps or ymin < by0 - eps or ymax > by1 + eps:
            return None
        return (
            z - levels,
            px,
            py,
            ((by1 - ymax) / ph, (xmin - bx0) / pw, (ymax - ymin) / ph, (xmax - xmin) / pw),
        )


@dataclass(frozen=True)
class GridRange(TileSpan):
    """Tiles x0..x1 (columns), y0..y1 (rows from the top), inclusive, of level z of `grid`: the
    same questions answered as app.world.tiles.TileRange, in the grid's CRS."""

    grid: TileGrid

    @property
    def matrix(self) -> Matrix:
        return self.grid.matrices[self.z]

    @property
    def tile_aspect(self) -> float:
        """A tile's height over its width (pixels)."""
        return self.matrix.tile_h / self.matrix.tile_w

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) CRS units of the rectangle's outer edges."""
        m = self.matrix
        xmin, _, _, ymax = m.tile_bounds(self.x0, self.y0)
        _, ymin, xmax, _ = m.tile_bounds(self.x1, self.y1)
        return xmin, ymin, xmax, ymax

    def transform(self, tile_px: int) -> tuple[float, float, float, float, float, float]:
        """The mosaic's GDAL affine (a, b, c, d, e, f): pixel (col, row) -> (x, y) CRS units of
        its corner, tiles tile_px pixels wide (perhaps not the matrix's own: a 512-px tile)."""
        xmin, _, _, ymax = self.bounds()
        w, h = self.matrix.span
        rows_px = max(1, int(round(tile_px * self.tile_aspect)))
        return (w / tile_px, 0.0, xmin, 0.0, -h / rows_px, ymax)

    def parent(self, z: int, x: int, y: int, levels: int):
        """TileGrid.parent of this range's grid."""
        return self.grid.parent(z, x, y, levels)
