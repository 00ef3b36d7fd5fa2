"""Write GeoTIFF DEMs and orthophotos (tests and `geofuse bench`): heights or RGB on a grid in
any CRS, north-up, each value at its pixel's centre."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import rasterio
from rasterio.crs import CRS
from rasterio.transform import from_origin

NODATA = -9999.0


def write_geotiff(
    path: str | Path,
    data: npt.ArrayLike,
    crs: str,
    west: float,
    north: float,
    step_x: float,
    step_y: float,
    nodata: float | None = NODATA,
) -> Path:
    """A north-up GeoTIFF: data (rows, cols) float heights or (bands, rows, cols) uint8 imagery,
    row 0 at the north; (west, north): the outer corner of pixel (0, 0) in `crs` units; steps in
    CRS units per pixel. NaN heights are written as nodata."""

    arr = np.asarray(data)
    bands = arr[None] if arr.ndim == 2 else arr
    if bands.dtype.kind == "f":
        bands = np.where(np.isfinite(bands), bands, NODATA).astype(np.float32)
    path = Path(path)
    with rasterio.open(
        path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0], dtype=bands.dtype,
        crs=CRS.from_user_input(crs), transform=from_origin(west, north, step_x, step_y),
        nodata=nodata if bands.dtype.kind == "f" else None, tiled=True, compress="deflate",
    ) as dst:  # fmt: skip
        dst.write(bands)
    return path


def hills(rows: int, cols: int, step_m: float, seed: int = 3) -> np.ndarray:
    """(rows, cols) heights in metres: rolling hills (a few sines) plus fine roughness."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64) * step_m
    h = (
        40.0 * np.sin(x / 700.0) * np.cos(y / 900.0)
        + 15.0 * np.sin((x + y) / 230.0)
        + 6.0 * np.cos(x / 90.0 - y / 140.0)
    )
    return 400.0 + h + rng.normal(0.0, 0.05, (rows, cols))
