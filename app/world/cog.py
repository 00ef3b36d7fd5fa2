"""A GeoTIFF (a Cloud Optimized GeoTIFF at its best) as a world's imagery or DEM: only the window
over the clip is read, over HTTP through GDAL's /vsicurl/ (range requests: the header, then the
internal tiles or strips the window touches, from an overview where the clip needs coarser
pixels than the file's), or from a local file.

The window: the clip's area (a lat/lon box, app.world.grids.lonlat_box) in the file's own CRS,
at the coarsest of the file's pixels and the pixels the clip needs (needed_m), at most max_side
pixels a side. It is kept in the tile cache beside the source's tiles (ROOT/<source>/windows/,
fresh for DEFAULT_FRESH_S), so a warm run makes no request. The source's headers and key go
with every request (GDAL_HTTP_HEADERS; {key} in the URL); no error text holds the URL's query
or the key (TileSource.redact).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from rasterio._err import CPLE_BaseError  # what GDAL's own errors (HTTP ones too) come as
from rasterio.enums import Resampling
from rasterio.errors import RasterioError
from rasterio.windows import Window

from app.world.cache import DEFAULT_FRESH_S, TileCache
from app.world.fetch import REQUEST_TIMEOUT_S, USER_AGENT
from app.world.grids import box_in, ground_m_per_unit
from app.world.sources import TileSource

GDAL_HTTP = {
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",  # no directory listing, no side-car probes
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".tif,.tiff,.TIF,.TIFF",
    "GDAL_HTTP_MAX_RETRY": "2",  # 429, 502-504: retried, Retry-After honoured by GDAL
    "GDAL_HTTP_RETRY_DELAY": "1",
    "GDAL_HTTP_USERAGENT": USER_AGENT,
}


class RasterFault(Exception):
    """The GeoTIFF could not be read over the clip; its text (redacted) says why."""


@dataclass(frozen=True)
class Raster:
    """A window read: data (H, W) float64 heights (NaN: none) or (H, W, 3) uint8 RGB; the
    affine of its pixel corners in `crs` (WKT); its pixels' ground size (m); whether it came
    from the cache, and the GeoTIFF it is kept in there (None where it could not be kept)."""

    data: np.ndarray
    transform: Affine
    crs: str
    pixel_m: float
    from_cache: bool
    kept: Path | None = None  # where the window is kept in the cache


def _path(source: TileSource) -> str:
    """What GDAL opens: /vsicurl/URL (the key put in) or the local file."""
    return source.location if source.is_local else "/vsicurl/" + source.fill(source.location)


def _env(source: TileSource, left_s: float) -> dict[str, str]:
    env = dict(GDAL_HTTP)
    env["GDAL_HTTP_TIMEOUT"] = str(max(1, int(math.ceil(min(REQUEST_TIMEOUT_S, left_s)))))
    headers = source.request_headers()
    if headers:
        env["GDAL_HTTP_HEADERS"] = "\r\n".join(f"{k}: {v}" for k, v in headers.items())
    return env


def _explain(source: TileSource, exc: BaseException) -> str:
    """One redacted line for a GDAL failure."""
    text = str(exc).replace("/vsicurl/", "").splitlines()[0] if str(exc) else type(exc).__name__
    if any(f"code: {c}" in text or f"HTTP {c}" in text for c in (401, 403)):
        text = "refused (401/403: check the key or the token)"
    elif "code: 404" in text or "HTTP 404" in text:
        text = "missing (HTTP 404)"
    text = source.redact(text.replace(source.fill(source.location), source.label))
    return text[:200]


def _window_of(src, box: tuple[float, float, float, float]) -> Window | None:
    """The pixel window (whole pixels) of the file covering a (west, south, east, north) deg
    box, clipped to the file; None when they do not meet."""
    xmin, ymin, xmax, ymax = box_in(src.crs.to_wkt(), box)
    inv = ~src.transform
    cols, rows = zip(
        *(inv @ (x, y) for x, y in ((xmin, ymin), (xmin, ymax), (xmax, ymin), (xmax, ymax))),
        strict=True,
    )
    c0, c1 = max(0, math.floor(min(cols))), min(src.width, math.ceil(max(cols)))
    r0, r1 = max(0, math.floor(min(rows))), min(src.height, math.ceil(max(rows)))
    if c1 <= c0 or r1 <= r0:
        return None
    return Window(c0, r0, c1 - c0, r1 - r0)


def _imagery(bands: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 of (count, H, W) bands: the first three, or a grey band thrice; other
    types than uint8 stretched from their 2nd to 98th percentile."""
    rgb = bands[:3] if bands.shape[0] >= 3 else np.repeat(bands[:1], 3, axis=0)
    if rgb.dtype != np.uint8:
        v = rgb.astype(np.float64)
        lo, hi = np.nanpercentile(v, [2.0, 98.0]) if np.isfinite(v).any() else (0.0, 1.0)
        rgb = np.clip((v - lo) / max(hi - lo, 1e-12) * 255.0, 0, 255).astype(np.uint8)
    return np.moveaxis(rgb, 0, -1).copy()


def read_window(
    source: TileSource,
    box: tuple[float, float, float, float],
    needed_m: float,
    max_side: int,
    cache: TileCache,
    deadline: float,
    clock=time.monotonic,
) -> Raster:
    """The source's window over a (west, south, east, north) deg box, pixels no finer than
    needed_m (m on the ground) where the file's are finer, at most max_side a side: heights
    for a terrain source (its first band, nodata as NaN), RGB for imagery. Raises RasterFault
    (a redacted line) where it cannot be read."""
    key = hashlib.sha256(
        repr((source.identity, [round(v, 7) for v in box], round(needed_m, 3), max_side)).encode()
    ).hexdigest()[:20]
    kept = cache.source_dir(source.identity) / "windows" / f"{key}.tif"
    if kept.is_file() and time.time() - kept.stat().st_mtime < DEFAULT_FRESH_S:
        try:
            return _read_kept(kept, source.kind)
        except (RasterioError, OSError):
            kept.unlink(missing_ok=True)
    left = deadline - clock()
    if left <= 0:
        raise RasterFault("not read within the time allowed")
    try:
        with rasterio.Env(**_env(source, left)), rasterio.open(_path(source)) as src:
            if src.crs is None:
                raise RasterFault("the GeoTIFF has no coordinate reference system")
            window = _window_of(src, box)
            if window is None:
                raise RasterFault("the GeoTIFF does not cover the clip")
            cx, cy = src.xy(window.row_off + window.height / 2, window.col_off + window.width / 2)
            native_m = ground_m_per_unit(
                src.crs.to_wkt(), cx, cy, abs(src.transform.a), abs(src.transform.e)
            )
            factor = max(
                1.0, needed_m / max(native_m, 1e-9), max(window.width, window.height) / max_side
            )
            out_w = max(1, int(math.ceil(window.width / factor)))
            out_h = max(1, int(math.ceil(window.height / factor)))
            if source.kind == "terrain":
                band = src.read(
                    1, window=window, out_shape=(out_h, out_w), masked=True,
                    resampling=Resampling.bilinear,
                )  # fmt: skip
                data = np.ma.filled(band.astype(np.float64), np.nan)
            else:
                count = min(src.count, 3)
                bands = src.read(
                    list(range(1, count + 1)), window=window, out_shape=(count, out_h, out_w),
                    resampling=Resampling.bilinear,
                )  # fmt: skip
                data = _imagery(bands)
            transform = src.window_transform(window) @ Affine.scale(
                window.width / out_w, window.height / out_h
            )
            crs = src.crs.to_wkt()
    except (RasterioError, CPLE_BaseError, OSError, ValueError) as exc:
        raise RasterFault(_explain(source, exc)) from None
    return Raster(
        data,
        transform,
        crs,
        native_m * factor,
        False,
        kept if _keep(kept, data, transform, crs) else None,
    )


def _keep(path: Path, data: np.ndarray, transform: Affine, crs: str) -> bool:
    """The window written where read_window looks for it (a failure to write only costs a
    warm run: False)."""
    bands = data[None] if data.ndim == 2 else np.moveaxis(data, -1, 0)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with rasterio.open(
            tmp, "w", driver="GTiff", width=data.shape[1], height=data.shape[0],
            count=bands.shape[0], dtype="float32" if data.ndim == 2 else "uint8", crs=crs,
            transform=transform, compress="deflate",
        ) as dst:  # fmt: skip
            dst.write(bands.astype("float32" if data.ndim == 2 else "uint8"))
        tmp.replace(path)
        return True
    except (RasterioError, OSError):
        path.unlink(missing_ok=True)
        return False


def _read_kept(path: Path, kind: str) -> Raster:
    with rasterio.open(path) as src:
        if kind == "terrain":
            data = src.read(1).astype(np.float64)
        else:
            data = np.moveaxis(src.read(), 0, -1).copy()
        cx, cy = src.xy(src.height / 2, src.width / 2)
        pixel_m = ground_m_per_unit(
            src.crs.to_wkt(), cx, cy, abs(src.transform.a), abs(src.transform.e)
        )
        return Raster(data, src.transform, src.crs.to_wkt(), pixel_m, True, path)
