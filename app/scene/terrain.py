"""Terrain from a DEM GeoTIFF (any CRS pyproj knows), optionally draped with an orthophoto.

1. The window: only the part of the raster around the clip's track (plus a margin) is read, by
   rasterio's windowed reads, so a national DEM of gigabytes opens in a second; a window larger
   than MAX_GRID samples a side is read decimated (bilinear).
2. Heights: nodata cells are holes (no triangle touches them). Heights above a geoid (EGM96,
   EGM2008) become ellipsoidal with app.geodesy.geoid; the datum comes from the file's vertical CRS, or
   the caller, or is assumed to be EGM2008 and said so.
3. The mesh: a right-triangulated irregular network (RTIN, as Mapbox's Martini) over the grid,
   whose vertical error against every DEM sample is at most `max_error_m`: flat land gets few
   large triangles, ridges many small ones, with no cracks.
4. Placement: each vertex's CRS coordinates -> WGS84 latitude, longitude (pyproj) -> ECEF ->
   session ENU, so the terrain lands where GNSS positions do, curvature included.
5. The orthophoto (any CRS, RGB or RGBA GeoTIFF) is read over the same area and mapped by each
   vertex's own position in the orthophoto's CRS.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyproj
import rasterio
from numba import njit
from rasterio.enums import Resampling
from rasterio.windows import Window, from_bounds
from rasterio.windows import transform as window_transform
from scipy import ndimage
from scipy.ndimage import map_coordinates

from app.core.errors import SceneError
from app.core.messages import Messages
from app.geodesy import geoid
from app.geodesy.crs import horizontal, of_raster, vertical_datum
from app.geodesy.enu import LocalFrame
from app.scene.mesh import MeshData, Primitive

MAX_GRID = 4097  # samples a side at most (2^12 + 1)
DEFAULT_MAX_ERROR_M = 0.5
DEFAULT_MARGIN_M = 2000.0
MAX_TEXTURE = 8192
TERRAIN_COLOR = (0.72, 0.70, 0.62, 1.0)
DEM_SUFFIXES = (".tif", ".tiff")


@dataclass
class Terrain:
    """A DEM read around a track: the mesh and what was assumed."""

    mesh: MeshData
    datum: str  # 'ellipsoid', 'egm2008' or 'egm96'
    notes: Messages
    grid_shape: tuple[int, int]  # samples read (rows, columns)
    error_m: float  # measured: the mesh's largest vertical distance from a sample read
    cell_m: float  # sample spacing on the ground, m (approx.)


# -- RTIN (right-triangulated irregular network) ------------------------------------------------


@njit(cache=True, nogil=True)
def _rtin_errors(h: np.ndarray) -> np.ndarray:
    """Per grid node, the largest vertical error of the triangles split at that node (with every
    finer level's below it): Martini's error pass over a (2^k + 1)^2 grid."""
    size = h.shape[0]
    tile = size - 1
    errors = np.zeros((size, size), np.float32)
    n_tri = tile * tile * 2 - 2
    n_parent = n_tri - tile * tile
    for i in range(n_tri - 1, -1, -1):
        tid = i + 2
        ax = ay = bx = by = cx = cy = 0
        if tid & 1:
            bx = by = cx = tile
        else:
            ax = ay = cy = tile
        tid >>= 1
        while tid > 1:
            mx = (ax + bx) >> 1
            my = (ay + by) >> 1
            if tid & 1:
                bx, by = ax, ay
                ax, ay = cx, cy
            else:
                ax, ay = bx, by
                bx, by = cx, cy
            cx, cy = mx, my
            tid >>= 1
        mx = (ax + bx) >> 1
        my = (ay + by) >> 1
        cx = mx + my - ay
        cy = my + ax - mx
        interp = (h[ay, ax] + h[by, bx]) / 2.0
        err = abs(interp - h[my, mx])
        if err > errors[my, mx]:
            errors[my, mx] = err
        if i < n_parent:
            lx, ly = (ax + cx) >> 1, (ay + cy) >> 1
            rx, ry = (bx + cx) >> 1, (by + cy) >> 1
            errors[my, mx] = max(errors[my, mx], errors[ly, lx], errors[ry, rx])
    return errors


@njit(cache=True, nogil=True)
def _vertex(index: np.ndarray, verts: np.ndarray, nv: int, x: int, y: int) -> int:
    if index[y, x] < 0:
        verts[nv, 0] = x
        verts[nv, 1] = y
        index[y, x] = nv
        nv += 1
    return nv


@njit(cache=True, nogil=True)
def _push(stack: np.ndarray, sp: int, ax: int, ay: int, bx: int, by: int, cx: int, cy: int) -> int:
    """Push the triangle (a, b, c) (grid column, row of each corner) on `stack` at `sp`; the new
    stack pointer."""
    stack[sp, 0] = ax
    stack[sp, 1] = ay
    stack[sp, 2] = bx
    stack[sp, 3] = by
    stack[sp, 4] = cx
    stack[sp, 5] = cy
    return sp + 1


@njit(cache=True, nogil=True)
def _rtin_mesh(errors: np.ndarray, max_error: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 2) int32 column, row; triangles (M, 3) int32) of the RTIN within max_error."""
    size = errors.shape[0]
    tile = size - 1
    index = np.full((size, size), -1, np.int32)
    # first pass counts, second fills: no growing arrays
    n_tris = 0
    for fill in range(2):
        if fill:
            verts = np.empty((size * size if n_tris * 3 > size * size else n_tris * 3, 2), np.int32)
            tris = np.empty((n_tris, 3), np.int32)
        nv = 0
        nt = 0
        stack = np.empty((4 * 32 + 8, 6), np.int32)
        for root in range(2):
            if root == 0:
                sp = _push(stack, 0, 0, 0, tile, tile, tile, 0)
            else:
                sp = _push(stack, 0, tile, tile, 0, 0, 0, tile)
            while sp > 0:
                sp -= 1
                ax, ay, bx, by = stack[sp, 0], stack[sp, 1], stack[sp, 2], stack[sp, 3]
                cx, cy = stack[sp, 4], stack[sp, 5]
                mx = (ax + bx) >> 1
                my = (ay + by) >> 1
                if abs(ax - cx) + abs(ay - cy) > 1 and errors[my, mx] > max_error:
                    sp = _push(stack, sp, cx, cy, ax, ay, mx, my)
                    sp = _push(stack, sp, bx, by, cx, cy, mx, my)
                    continue
                if fill:
                    nv = _vertex(index, verts, nv, ax, ay)
                    nv = _vertex(index, verts, nv, bx, by)
                    nv = _vertex(index, verts, nv, cx, cy)
                    tris[nt, 0] = index[ay, ax]
                    tris[nt, 1] = index[by, bx]
                    tris[nt, 2] = index[cy, cx]
                nt += 1
        n_tris = nt
    return verts[:nv], tris


@njit(cache=True, nogil=True)
def mesh_error(h: np.ndarray, verts: np.ndarray, tris: np.ndarray) -> float:
    """The largest |mesh - sample| (m) over every grid sample, the mesh interpolated linearly
    within each triangle (vertices as column, row of the grid h)."""
    worst = 0.0
    for t in range(tris.shape[0]):
        x0, y0 = verts[tris[t, 0], 0], verts[tris[t, 0], 1]
        x1, y1 = verts[tris[t, 1], 0], verts[tris[t, 1], 1]
        x2, y2 = verts[tris[t, 2], 0], verts[tris[t, 2], 1]
        z0, z1, z2 = h[y0, x0], h[y1, x1], h[y2, x2]
        den = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if den == 0:
            continue
        for y in range(min(y0, y1, y2), max(y0, y1, y2) + 1):
            for x in range(min(x0, x1, x2), max(x0, x1, x2) + 1):
                a = ((x - x0) * (y2 - y0) - (x2 - x0) * (y - y0)) / den
                b = ((x1 - x0) * (y - y0) - (x - x0) * (y1 - y0)) / den
                if a < -1e-9 or b < -1e-9 or a + b > 1 + 1e-9:
                    continue
                e = abs(z0 + a * (z1 - z0) + b * (z2 - z0) - h[y, x])
                if e > worst:
                    worst = e
    return worst


def rtin(heights: npt.ArrayLike, max_error_m: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Vertices ((N, 2) int column, row), triangles ((M, 3) int) and the measured error (m) of a
    mesh over a (2^k + 1)^2 height grid whose vertical error against every sample is at most
    max_error_m. Martini's split test looks at hypotenuse midpoints only, which can overshoot a
    little; the mesh is measured against every sample and redone tighter until within."""
    h = np.ascontiguousarray(heights, np.float32)
    size = h.shape[0]
    if h.shape != (size, size) or size < 3 or (size - 1) & (size - 2):
        raise ValueError(f"RTIN needs a (2^k + 1)^2 grid, got {h.shape}")
    errors = _rtin_errors(h)
    threshold = float(max_error_m)
    for _ in range(8):
        verts, tris = _rtin_mesh(errors, threshold)
        err = float(mesh_error(h, verts, tris))
        if err <= max_error_m:
            break
        threshold *= 0.9 * max_error_m / err
    return verts, tris, err


# -- reading -------------------------------------------------------------------------------------


def _affine(t: object, col: npt.ArrayLike, row: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """An affine.Affine applied to pixel coordinates (column, row) -> CRS (x, y)."""
    col, row = np.asarray(col, np.float64), np.asarray(row, np.float64)
    return t.a * col + t.b * row + t.c, t.d * col + t.e * row + t.f


def _vertical_datum(crs: object) -> str | None:
    """'egm96', 'egm2008' or 'ellipsoid' from a rasterio CRS with a vertical part; None if silent."""
    try:
        return vertical_datum(of_raster(crs))
    except pyproj.exceptions.CRSError:
        return None


def _horizontal(crs: object) -> pyproj.CRS:
    return horizontal(of_raster(crs))


def _window_around(src, track_ll: np.ndarray | None, margin_m: float):
    """The raster window (rasterio Window) covering the track's bounding box plus margin_m."""

    full = Window(0, 0, src.width, src.height)
    if track_ll is None or not len(track_ll):
        return full
    lat, lon = track_ll[:, 0], track_ll[:, 1]
    dlat = margin_m / 111_000.0
    dlon = margin_m / (111_000.0 * max(np.cos(np.radians(float(np.mean(lat)))), 0.05))
    ring_lon = np.array([lon.min() - dlon, lon.max() + dlon])
    ring_lat = np.array([lat.min() - dlat, lat.max() + dlat])
    glon, glat = np.meshgrid(np.linspace(*ring_lon, 9), np.linspace(*ring_lat, 9))
    to_src = pyproj.Transformer.from_crs("EPSG:4326", _horizontal(src.crs), always_xy=True)
    x, y = to_src.transform(glon.ravel(), glat.ravel())
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return None
    win = from_bounds(
        float(np.min(x[ok])),
        float(np.min(y[ok])),
        float(np.max(x[ok])),
        float(np.max(y[ok])),
        src.transform,
    )
    try:
        win = win.round_offsets().round_lengths().intersection(full)
    except Exception:  # rasterio raises WindowError when they do not overlap
        return None
    return win if win.width >= 2 and win.height >= 2 else None


def _distance_to_raster(src, frame: LocalFrame, track_ll: np.ndarray) -> float:
    """Horizontal distance (m) from the track's nearest fix to the raster's extent (ENU box)."""

    b = src.bounds
    t = np.linspace(0.0, 1.0, 21)
    xs = np.concatenate(
        [
            b.left + (b.right - b.left) * t,
            np.full(21, b.right),
            b.left + (b.right - b.left) * t,
            np.full(21, b.left),
        ]
    )
    ys = np.concatenate(
        [
            np.full(21, b.bottom),
            b.bottom + (b.top - b.bottom) * t,
            np.full(21, b.top),
            b.bottom + (b.top - b.bottom) * t,
        ]
    )
    lon, lat = pyproj.Transformer.from_crs(
        _horizontal(src.crs), "EPSG:4326", always_xy=True
    ).transform(xs, ys)
    edge = frame.geodetic_to_enu(np.asarray(lat), np.asarray(lon), np.zeros(len(xs)))[:, :2]
    pts = frame.geodetic_to_enu(track_ll[:, 0], track_ll[:, 1], np.zeros(len(track_ll)))[:, :2]
    lo, hi = edge.min(axis=0), edge.max(axis=0)
    gap = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
    return float(np.hypot(gap[:, 0], gap[:, 1]).min())


def _grid_size(rows: int, cols: int) -> int:
    n = max(rows, cols, 3)
    k = int(np.ceil(np.log2(n - 1)))
    return min((1 << k) + 1, MAX_GRID)


def read_terrain(
    path: str | Path,
    frame: LocalFrame,
    track_ll: npt.ArrayLike | None = None,
    ortho: str | Path | None = None,
    vertical: str | None = None,
    max_error_m: float = DEFAULT_MAX_ERROR_M,
    margin_m: float = DEFAULT_MARGIN_M,
) -> Terrain:
    """A terrain mesh in `frame` from the DEM at `path` (see the module docstring).

    track_ll: (N, 2) latitude, longitude (deg) of the clip's track; None reads the whole DEM.
    vertical: the heights' datum when the caller knows it ('ellipsoid', 'egm2008', 'egm96');
    None: the file's, else EGM2008 (said in `notes`). Raises SceneError naming the file."""

    path = Path(path)
    notes = Messages()
    if not path.is_file():
        raise SceneError(path, "DEM file does not exist")
    if vertical is not None and vertical not in geoid.VERTICAL_DATUMS:
        raise SceneError(
            path,
            f"vertical datum {vertical!r} unknown (expected one of {', '.join(geoid.VERTICAL_DATUMS)})",
            field="vertical",
        )
    try:
        src = rasterio.open(path)
    except Exception as exc:  # rasterio raises RasterioIOError and others
        raise SceneError(path, f"cannot read as a GeoTIFF: {exc}") from exc
    with src:
        if src.crs is None:
            raise SceneError(
                path, "the raster has no coordinate reference system (expected a GeoTIFF with one)"
            )
        track = None if track_ll is None else np.atleast_2d(np.asarray(track_ll, np.float64))
        win = _window_around(src, track, margin_m)
        if win is None:
            far = _distance_to_raster(src, frame, track)
            raise SceneError(
                path,
                f"the DEM does not cover the clip's track (nor {margin_m / 1000:.1f} km around it): it lies {far / 1000:.1f} km from the track",
            )
        size = _grid_size(int(win.height), int(win.width))
        try:
            band = src.read(
                1, window=win, out_shape=(size, size), resampling=Resampling.bilinear, masked=True
            )
        except Exception as exc:
            raise SceneError(path, f"cannot read the DEM's samples: {exc}") from exc
        # resampled to size x size, grid node (r, c) is the centre of an output pixel: window pixel
        # coordinates ((c + 0.5) W / size, (r + 0.5) H / size)
        wt = window_transform(win, src.transform)
        datum = vertical or _vertical_datum(src.crs)
        if datum is None:
            datum = "egm2008"
            notes.add(
                f"{path.name}: heights taken as above the EGM2008 geoid (the file names no vertical datum; set the DEM's vertical datum to change it)"
            )
        elif datum == "egm96" and vertical is None:
            notes.info(
                f"{path.name}: EGM96 heights converted with EGM2008 undulations (the two differ by under a metre almost everywhere)"
            )
        horizontal = _horizontal(src.crs)
        win_w, win_h = float(win.width), float(win.height)
    heights = np.ma.filled(band.astype(np.float64), np.nan)
    valid = np.isfinite(heights) & (np.abs(heights) < 1e4)
    if not valid.any():
        raise SceneError(path, "every DEM sample in the clip's area is nodata")
    holes = int((~valid).sum())
    if holes:
        _, (ri, ci) = ndimage.distance_transform_edt(~valid, return_indices=True)
        heights = heights[ri, ci]
        notes.add(
            f"{path.name}: {holes} of {valid.size} samples are nodata: left as holes in the terrain"
        )
    to_ll = pyproj.Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)

    def lat_lon(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lon, lat = to_ll.transform(*_affine(wt, (c + 0.5) * win_w / size, (r + 0.5) * win_h / size))
        return np.asarray(lat, np.float64), np.asarray(lon, np.float64)

    # The mesh is drawn in the flat ENU frame: triangulate the heights as ENU sees them (the
    # Earth's curvature, ~8 cm at 1 km from the origin, and the geoid) so that the error bound
    # holds for what is drawn. The offset is smooth: computed on a 33 x 33 lattice, bilinear.
    k = min(size, 33)
    lattice = np.linspace(0.0, size - 1.0, k)
    lc, lr = np.meshgrid(lattice, lattice)
    la, lo = lat_lon(lc.ravel(), lr.ravel())
    offset = (
        frame.geodetic_to_enu(la, lo, geoid.to_ellipsoidal(np.zeros_like(la), la, lo, datum))[:, 2]
    ).reshape(k, k)

    rr, cc = np.mgrid[0:size, 0:size].astype(np.float32) * np.float32((k - 1) / (size - 1))
    enu_heights = heights + map_coordinates(offset, [rr, cc], order=1, mode="nearest")
    verts, tris, error_m = rtin(enu_heights, max_error_m)
    if holes:  # no triangle may touch a nodata sample
        bad = ~valid[verts[:, 1], verts[:, 0]]
        tris = tris[~bad[tris].any(axis=1)]
    lat, lon = lat_lon(verts[:, 0].astype(np.float64), verts[:, 1].astype(np.float64))
    h = geoid.to_ellipsoidal(heights[verts[:, 1], verts[:, 0]], lat, lon, datum)
    enu = frame.geodetic_to_enu(lat, lon, h)
    n = len(enu)
    colors = np.tile(np.asarray(TERRAIN_COLOR, np.float32), (n, 1))
    uvs = texture = None
    if ortho is not None:
        uvs, texture = _orthophoto(Path(ortho), lat, lon)
        if texture is not None:
            colors[:] = 1.0
    prim = Primitive(
        enu.astype(np.float32),
        colors,
        tris.astype(np.uint32),
        uvs,
        texture,
        name=f"terrain {path.name}",
        cut=True,  # read over a window: the land goes on past it
    )
    cell = float(np.hypot(wt.a, wt.d))
    if horizontal.is_geographic:
        cell *= 111_000.0
    cell *= win_w / size
    return Terrain(MeshData([prim]), datum, notes, (size, size), error_m, cell)


def _orthophoto(path: Path, lat: np.ndarray, lon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(uvs (N, 2), texture (H, W, 4) uint8 bottom row first) of an orthophoto over the vertices."""

    if not path.is_file():
        raise SceneError(path, "orthophoto file does not exist")
    try:
        src = rasterio.open(path)
    except Exception as exc:
        raise SceneError(path, f"cannot read as a GeoTIFF: {exc}") from exc
    with src:
        if src.crs is None:
            raise SceneError(path, "the orthophoto has no coordinate reference system")
        if src.count < 3:
            raise SceneError(path, f"the orthophoto has {src.count} band(s) (expected RGB or RGBA)")
        to_src = pyproj.Transformer.from_crs("EPSG:4326", _horizontal(src.crs), always_xy=True)
        x, y = (np.asarray(v, np.float64) for v in to_src.transform(lon, lat))
        win = from_bounds(
            float(x.min()), float(y.min()), float(x.max()), float(y.max()), src.transform
        )
        try:
            win = (
                win.round_offsets()
                .round_lengths()
                .intersection(Window(0, 0, src.width, src.height))
            )
        except Exception as exc:
            raise SceneError(path, "the orthophoto does not cover the terrain") from exc
        scale = min(1.0, MAX_TEXTURE / max(win.width, win.height))
        out_w, out_h = max(2, int(win.width * scale)), max(2, int(win.height * scale))
        rgb = src.read(
            [1, 2, 3], window=win, out_shape=(3, out_h, out_w), resampling=Resampling.bilinear
        )
        if rgb.dtype != np.uint8:  # 16-bit imagery: stretch its own range
            hi = float(np.percentile(rgb, 99.5)) or 1.0
            rgb = np.clip(rgb.astype(np.float64) / hi * 255.0, 0, 255)
        inv = ~src.window_transform(win)
        col, row = _affine(inv, x, y)
    img = np.concatenate(
        [np.moveaxis(rgb.astype(np.uint8), 0, -1), np.full((out_h, out_w, 1), 255, np.uint8)],
        axis=-1,
    )
    u = np.asarray(col, np.float64) / float(win.width)
    v = 1.0 - np.asarray(row, np.float64) / float(win.height)
    return np.stack([u, v], axis=1).astype(np.float32), np.ascontiguousarray(img[::-1])
