"""A true orthophoto painted from a clip: what the video saw, kept on the scene's surfaces as seen
from straight above, in a map grid. Pure numpy and numba (the GL part, each frame's distances,
is app.export.painting's).

1. The grid: north-up cells of `gsd` metres in a projected CRS (the site's UTM zone by default),
   over an area. ENU -> grid is one affine map fitted on the area's corners through pyproj (its
   error is reported: micrometres over a site, the map's curvature only).
2. The surface: every triangle of the scene rasterised from above (a z-buffer keeping the
   highest), so each cell holds the model's top surface point (ENU m) and its normal: a true
   orthophoto, roofs where roofs are, not leaning.
3. Painting: the cells with a surface are the samples of a SurfaceMemory (app.export.memory:
   the occlusion test, colour, time, quality and the rules newest, best, first).
The memory is the grid's size whatever the clip's length.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pyproj
from numba import njit

from app.export.memory import SurfaceMemory
from app.geodesy.crs import utm_zone
from app.geodesy.enu import LocalFrame
from app.scene.mesh import MeshData

MAX_CELLS = 64_000_000  # 8000 x 8000: an area and a gsd beyond this are refused


@dataclass(frozen=True)
class Grid:
    """North-up cells: crs (pyproj CRS), west and north edges (CRS units), gsd (units a cell),
    shape (rows, columns). `enu_to_grid` is the affine (2, 3) that takes ENU (x, y, 1) to
    (column, row) in cells (0, 0 the top-left corner of the top-left cell)."""

    crs: pyproj.CRS
    west: float
    north: float
    gsd: float
    shape: tuple[int, int]
    enu_to_grid: np.ndarray = field(repr=False)
    fit_error_m: float = 0.0

    @property
    def transform(self) -> tuple[float, float, float, float, float, float]:
        """The GDAL geotransform's affine (a, b, c, d, e, f): x = a col + b row + c."""
        return (self.gsd, 0.0, self.west, 0.0, -self.gsd, self.north)

    def cell_centres_enu(self, frame: LocalFrame) -> np.ndarray:
        """(rows, cols, 2) ENU x, y of the cells' centres (through the inverse of the affine)."""
        rows, cols = self.shape
        c, r = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
        a = np.vstack([self.enu_to_grid, [0.0, 0.0, 1.0]])
        inv = np.linalg.inv(a)
        xy = np.stack([c, r, np.ones_like(c)], axis=-1) @ inv.T
        return xy[..., :2]


def make_grid(
    frame: LocalFrame,
    lo_enu: npt.ArrayLike,
    hi_enu: npt.ArrayLike,
    gsd: float,
    crs: pyproj.CRS | None = None,
) -> Grid:
    """The grid of `gsd` (CRS units, metres for UTM) covering the ENU box lo..hi (x, y m) in
    `crs` (the site's UTM zone when None), its edges on whole multiples of gsd. Raises
    ValueError for a grid beyond MAX_CELLS or a CRS that is not projected."""
    crs = crs or utm_zone(frame.lat_deg, frame.lon_deg)
    if not crs.is_projected:
        raise ValueError(f"{crs.name}: an orthophoto needs a projected CRS (metres), e.g. UTM")
    lo, hi = np.asarray(lo_enu, np.float64)[:2], np.asarray(hi_enu, np.float64)[:2]
    xs = np.array([lo[0], hi[0], hi[0], lo[0], (lo[0] + hi[0]) / 2])
    ys = np.array([lo[1], lo[1], hi[1], hi[1], (lo[1] + hi[1]) / 2])
    geo = frame.enu_to_geodetic(np.column_stack([xs, ys, np.zeros(5)]))
    to_crs = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    X, Y = (np.asarray(v) for v in to_crs.transform(geo[:, 1], geo[:, 0]))
    west = np.floor(X.min() / gsd) * gsd
    north = np.ceil(Y.max() / gsd) * gsd
    cols = int(np.ceil((X.max() - west) / gsd))
    rows = int(np.ceil((north - Y.min()) / gsd))
    if rows * cols > MAX_CELLS:
        raise ValueError(
            f"{cols} x {rows} cells of {gsd:g} m: more than {MAX_CELLS:,} (give a larger --gsd or a smaller --area)"
        )
    # ENU (x, y, 1) -> (col, row): least squares over the corners, the middle as a check
    design = np.column_stack([xs, ys, np.ones(5)])
    target = np.column_stack([(X - west) / gsd, (north - Y) / gsd])
    affine, *_ = np.linalg.lstsq(design, target, rcond=None)
    error = float(np.abs(design @ affine - target).max() * gsd)
    return Grid(crs, float(west), float(north), float(gsd), (rows, cols), affine.T, error)


@njit(cache=True)
def _rasterise(tri: np.ndarray, top: np.ndarray, which: np.ndarray) -> None:
    """Keep, per cell, the highest triangle over its centre: tri (T, 3, 3) with x, y in grid
    cells (column, row) and z in ENU metres; top (rows, cols) the height there so far, which
    (rows, cols) the triangle's index."""
    rows, cols = top.shape
    for t in range(tri.shape[0]):
        ax, ay, az = tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2]
        bx, by, bz = tri[t, 1, 0], tri[t, 1, 1], tri[t, 1, 2]
        cx, cy, cz = tri[t, 2, 0], tri[t, 2, 1], tri[t, 2, 2]
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if abs(det) < 1e-12:
            continue  # a wall seen edge-on from above covers no cell centre
        c0 = max(0, int(np.floor(min(ax, bx, cx) - 0.5)))
        c1 = min(cols - 1, int(np.ceil(max(ax, bx, cx) - 0.5)))
        r0 = max(0, int(np.floor(min(ay, by, cy) - 0.5)))
        r1 = min(rows - 1, int(np.ceil(max(ay, by, cy) - 0.5)))
        for r in range(r0, r1 + 1):
            py = r + 0.5
            for c in range(c0, c1 + 1):
                px = c + 0.5
                w0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
                w1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                z = w0 * az + w1 * bz + w2 * cz
                if z > top[r, c]:
                    top[r, c] = z
                    which[r, c] = t


def surface(mesh: MeshData, grid: Grid, frame: LocalFrame) -> tuple[np.ndarray, np.ndarray]:
    """The scene's top surface over each cell: (points (rows, cols, 3) ENU m, NaN where no
    triangle lies; normals (rows, cols, 3) unit, pointing up). Static primitives only (models,
    terrain, city models); streamed 3D Tiles are not rasterised."""
    rows, cols = grid.shape
    top = np.full((rows, cols), -np.inf)
    which = np.full((rows, cols), -1, np.int64)
    tris = [p.positions.astype(np.float64)[p.indices] for p in mesh.primitives if len(p.indices)]
    if not tris:
        return np.full((rows, cols, 3), np.nan), np.full((rows, cols, 3), np.nan)
    enu = np.concatenate(tris)  # (T, 3, 3)
    g = enu.copy()
    flat = enu.reshape(-1, 3)
    g.reshape(-1, 3)[:, :2] = (
        np.column_stack([flat[:, :2], np.ones(len(flat))]) @ grid.enu_to_grid.T
    )
    _rasterise(g, top, which)
    seen = np.isfinite(top)
    xy = grid.cell_centres_enu(frame)
    points = np.full((rows, cols, 3), np.nan)
    points[..., :2] = np.where(seen[..., None], xy, np.nan)
    points[..., 2] = np.where(seen, top, np.nan)
    n = np.cross(enu[:, 1] - enu[:, 0], enu[:, 2] - enu[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    n *= np.where(n[:, 2:3] < 0, -1.0, 1.0)
    normals = np.where(seen[..., None], n[np.clip(which, 0, len(n) - 1)], np.nan)
    return points, normals


class OrthoMemory:
    """A SurfaceMemory (app.export.memory) over the grid's cells that have a surface, seen as
    grids: rgb (rows, cols, 3) uint8, seen (bool), time (UTC s, NaN unseen), quality (0
    unseen); points and normals (rows, cols, 3) the surface it paints (NaN: none)."""

    def __init__(self, grid: Grid, points: np.ndarray, normals: np.ndarray, rule: str = "newest"):
        self.grid, self.points, self.normals = grid, points, normals
        self._cells = np.flatnonzero(np.isfinite(points[..., 2]).ravel())
        self.memory = SurfaceMemory(
            points.reshape(-1, 3)[self._cells], normals.reshape(-1, 3)[self._cells], rule
        )

    @property
    def rule(self) -> str:
        return self.memory.rule

    @property
    def frames(self) -> int:
        return self.memory.frames

    @property
    def nbytes(self) -> int:
        """Bytes held, whatever the number of frames painted."""
        return self.memory.nbytes + self.points.nbytes + self.normals.nbytes + self._cells.nbytes

    def _grid(self, values: np.ndarray, empty: object) -> np.ndarray:
        rows, cols = self.grid.shape
        out = np.full((rows * cols, *values.shape[1:]), empty, values.dtype)
        out[self._cells] = values
        return out.reshape(rows, cols, *values.shape[1:])

    @property
    def rgb(self) -> np.ndarray:
        return self._grid(self.memory.rgb, 0)

    @property
    def seen(self) -> np.ndarray:
        return self._grid(self.memory.seen, False)

    @property
    def time(self) -> np.ndarray:
        return self._grid(self.memory.time, np.nan)

    @property
    def quality(self) -> np.ndarray:
        return self._grid(self.memory.quality, 0.0)
