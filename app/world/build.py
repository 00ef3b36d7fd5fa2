"""A world's tiles over a clip's track -> a DEM and an orthophoto GeoTIFF (EPSG:3857) in the
cache folder -> the scene's DEM layer (app.scene.terrain drapes the one on the other, in the
session's ENU frame, with its RTIN mesh and vertical datum).

The area: the track's extent plus the camera's reach on the ground (the margin the assumed
ground would have had, at most MAX_REACH_M), in Web Mercator. The levels: imagery at the
coarsest zoom whose pixels are at most the clip's ground sampling (estimated from its height
above the ground), terrain TERRAIN_COARSER times coarser, each within a tile budget. A tile that
cannot be had is drawn from up to PARENT_LEVELS coarser tiles; imagery without terrain lies on
the assumed flat ground. Everything fetched is bounded by the world's timeout_s.
"""

from __future__ import annotations

import hashlib
import math
import re
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import rasterio
from affine import Affine
from scipy import ndimage

from app.core.messages import Messages
from app.core.progress import ProgressBar
from app.scene.layers import Layer
from app.world import tiles as tm
from app.world.cache import TileCache
from app.world.fetch import SourceFetcher
from app.world.settings import World
from app.world.sources import TileSource, decode_heights

MAX_REACH_M = 2000.0  # the area fetched reaches at most this far beyond the track, m
MIN_REACH_M = 100.0
IMAGERY_MAX_TILES = 144  # 12 x 12 tiles: 3072 px a side of 256 px tiles
TERRAIN_MAX_TILES = 36
TERRAIN_COARSER = 4.0  # terrain samples this many times coarser than imagery pixels
MIN_GSD_M = 0.3  # no imagery finer than this is asked for, m a pixel
PARENT_LEVELS = 3
FETCH_WORKERS = 8
FLAT_GRID = 33  # samples a side of the flat DEM under imagery without terrain
ASSUMED_TILE_PX = 256


def world_layer(world: World) -> Layer:
    """The layer that stands for `world` until a clip's track resolves it (resolve_worlds)."""
    sources = [s for s in (world.imagery, world.terrain) if s is not None]
    credit = world.attribution or "; ".join(s.attribution for s in sources if s.attribution)
    return Layer(f"world:{world.name}", "world", world=world, attribution=credit)


@dataclass
class Mosaic:
    """Tiles at one zoom in one array: (H, W, 3) uint8 imagery or (H, W) float64 heights (NaN:
    none), with the tiles it covers, each tile_px a side; counts of tiles had at their own level
    and from a coarser one."""

    data: np.ndarray
    tiles: tm.TileRange
    tile_px: int
    own: int
    coarser: int

    def transform(self) -> Affine:
        return Affine(*self.tiles.transform(self.tile_px))


def _resize(tile: np.ndarray, size: int) -> np.ndarray:
    """A tile (H, W[, 3]) resampled (bilinear) to size x size."""
    if tile.shape[0] == size and tile.shape[1] == size:
        return tile
    f = (size / tile.shape[0], size / tile.shape[1]) + ((1,) if tile.ndim == 3 else ())
    out = ndimage.zoom(tile.astype(np.float64), f, order=1, mode="nearest", grid_mode=True)
    return out.astype(tile.dtype) if tile.dtype == np.uint8 else out


def mosaic(
    fetcher: SourceFetcher,
    tiles: tm.TileRange,
    decode: Callable[[np.ndarray], np.ndarray],
    progress: Callable[[float], None] | None = None,
) -> Mosaic | None:
    """The tiles of `tiles` fetched (in parallel) and decoded into one Mosaic; a tile not had is
    cut from a coarser one (up to PARENT_LEVELS up); None when no tile at all was had."""
    got: dict[tuple[int, int, int], np.ndarray] = {}
    todo = tiles.tiles()
    with ThreadPoolExecutor(FETCH_WORKERS) as pool:
        futures = {pool.submit(fetcher.get, *t): t for t in todo}
        for i, future in enumerate(as_completed(futures)):
            arr = future.result()
            if arr is not None:
                got[futures[future]] = decode(arr)
            if progress is not None:
                progress((i + 1) / len(todo))
    parents: dict[tuple[int, int, int], np.ndarray | None] = {}
    filled: dict[tuple[int, int, int], np.ndarray] = {}
    for z, x, y in todo:
        if (z, x, y) in got:
            continue
        for k in range(1, min(PARENT_LEVELS, z) + 1):
            pz, px, py, col, row = tm.parent(z, x, y, k)
            if (pz, px, py) not in parents:
                arr = fetcher.get(pz, px, py)
                parents[(pz, px, py)] = None if arr is None else decode(arr)
            p = parents[(pz, px, py)]
            if p is not None:
                step = p.shape[0] / (1 << k)
                r0, c0 = int(round(row * step)), int(round(col * step))
                n = max(1, int(round(step)))
                filled[(z, x, y)] = p[r0 : r0 + n, c0 : c0 + n]
                break
    if not got and not filled:
        return None
    tile_px = next(iter(got.values())).shape[0] if got else ASSUMED_TILE_PX
    rows, cols = tiles.shape
    sample = next(iter((got or filled).values()))
    shape = (rows * tile_px, cols * tile_px) + sample.shape[2:]
    out = np.full(shape, np.nan if sample.dtype != np.uint8 else 128, sample.dtype)
    for (_, x, y), arr in (got | filled).items():
        r, c = (y - tiles.y0) * tile_px, (x - tiles.x0) * tile_px
        out[r : r + tile_px, c : c + tile_px] = _resize(arr, tile_px)
    return Mosaic(out, tiles, tile_px, len(got), len(filled))


def _bounds(lat: np.ndarray, lon: np.ndarray, reach_m: float) -> tuple[float, float, float, float]:
    """(west, south, east, north) EPSG:3857 m of the track plus reach_m on the ground."""
    x, y = tm.to_mercator(lat, lon)
    grow = reach_m / max(math.cos(math.radians(float(np.mean(lat)))), 0.05)  # ground -> map m
    return (
        float(x.min()) - grow,
        float(y.min()) - grow,
        float(x.max()) + grow,
        float(y.max()) + grow,
    )


def _zoom(source: TileSource, bounds, needed_m: float, lat: float, max_tiles: int) -> int:
    return tm.choose_zoom(bounds, needed_m, lat, ASSUMED_TILE_PX, source.max_zoom, max_tiles)


def _write(path: Path, data: np.ndarray, transform: Affine, tags: dict[str, str]) -> Path:
    """A GeoTIFF in EPSG:3857: (H, W) float heights (NaN nodata) or (H, W, 3) uint8 RGB."""
    bands = data[None] if data.ndim == 2 else np.moveaxis(data, -1, 0)
    profile = {
        "driver": "GTiff",
        "width": data.shape[1],
        "height": data.shape[0],
        "count": bands.shape[0],
        "dtype": "float32" if data.ndim == 2 else "uint8",
        "crs": "EPSG:3857",
        "transform": transform,
        "compress": "deflate",
        **({"nodata": np.nan} if data.ndim == 2 else {"photometric": "RGB"}),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with rasterio.open(tmp, "w", **profile) as dst:
        dst.write(bands.astype(profile["dtype"]))
        dst.update_tags(**tags)
    tmp.replace(path)
    return path


def _tags(world: World, source: TileSource, z: int) -> dict[str, str]:
    """GeoTIFF metadata of a world's layer: its attribution (as licences require), the source
    by its label (never its key) and zoom."""
    credit = world.attribution or source.attribution
    return {
        "TIFFTAG_COPYRIGHT": credit,
        "ATTRIBUTION": credit,
        "SOURCE": f"{source.kind} {source.label} zoom {z}",
    }


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)[:40] or "world"


def world_scene(
    world: World,
    lat: npt.ArrayLike,
    lon: npt.ArrayLike,
    ground_h: float,
    reach_m: float,
    height_m: float,
    messages: Messages,
    cache: TileCache | None = None,
    progress: Callable[[float], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> tuple[Layer, ...]:
    """The world's DEM layer (its orthophoto draped) over the track (lat, lon deg), or () when
    no tile could be had (said in `messages`, the caller keeps its flat ground).

    ground_h: the assumed ground's ellipsoidal height (m), under imagery without terrain;
    reach_m: the camera's reach on the ground beyond the track (m); height_m: the camera's
    typical height above the ground (m), which sets the imagery's ground sampling."""
    cache = cache or TileCache()
    lat, lon = (
        np.atleast_1d(np.asarray(lat, np.float64)),
        np.atleast_1d(np.asarray(lon, np.float64)),
    )
    lat0 = float(np.mean(lat))
    bounds = _bounds(lat, lon, min(max(reach_m, MIN_REACH_M), MAX_REACH_M))
    needed = max(MIN_GSD_M, abs(height_m) / 1000.0)  # a 1000-px-wide view of 53 deg, nadir
    deadline = clock() + world.timeout_s
    what = f"world {world.name}"
    plan = []
    if world.terrain is not None:
        z = _zoom(world.terrain, bounds, needed * TERRAIN_COARSER, lat0, TERRAIN_MAX_TILES)
        plan.append(("terrain", world.terrain, tm.covering(bounds, z)))
    if world.imagery is not None:
        z = _zoom(world.imagery, bounds, needed, lat0, IMAGERY_MAX_TILES)
        plan.append(("imagery", world.imagery, tm.covering(bounds, z)))
    total = sum(r.count for _, _, r in plan)
    done = 0
    made: dict[str, Mosaic] = {}
    fetchers = []
    for kind, source, tiles in plan:
        fetcher = SourceFetcher(source, cache, deadline, clock=clock)
        fetchers.append(fetcher)
        decode = (
            (lambda a, enc=source.encoding: decode_heights(a, enc))
            if kind == "terrain"
            else (lambda a: a)
        )
        start = done

        def step(f: float, start: int = start, n: int = tiles.count) -> None:
            if progress is not None:
                progress((start + f * n) / total)

        m = mosaic(fetcher, tiles, decode, step)
        done += tiles.count
        fetcher.close()
        fetcher.report(messages, f"{what} {kind}")
        if m is not None:
            made[kind] = m
            messages.info(
                f"{what} {kind}: {m.own + m.coarser} tiles of {source.label} at zoom {tiles.z} "
                f"(~{tm.pixel_m(tiles.z, m.tile_px, lat0):.1f} m a pixel; {fetcher.requests} requests, {fetcher.from_cache} from the cache"
                + (f", {m.coarser} drawn from a coarser level" if m.coarser else "")
                + ")"
            )
    if not made:
        messages.add(
            f"{what}: no tile could be had: the video is projected on the assumed flat ground instead"
        )
        return ()
    cache.trim()
    key = hashlib.sha256(
        repr([(s.identity, r) for _, s, r in plan] + [ground_h]).encode()
    ).hexdigest()[:16]
    folder = cache.root / "worlds" / key
    ortho = None
    if "imagery" in made:
        m = made["imagery"]
        ortho = _write(
            folder / f"{_safe(world.name)}-imagery.tif",
            m.data,
            m.transform(),
            _tags(world, world.imagery, m.tiles.z),
        )
    if "terrain" in made:
        m = made["terrain"]
        datum = world.terrain.datum
        dem = _write(
            folder / f"{_safe(world.name)}-terrain.tif",
            m.data.astype(np.float32),
            m.transform(),
            _tags(world, world.terrain, m.tiles.z),
        )
        messages.info(
            f"{what} terrain: heights taken as above {'the ellipsoid' if datum == 'ellipsoid' else datum.upper()} "
            "(datum in its [[world]] table says otherwise)"
        )
    else:
        m = made["imagery"]
        west, south, east, north = m.tiles.bounds_m()
        flat = np.full((FLAT_GRID, FLAT_GRID), float(ground_h), np.float32)
        step_x, step_y = (east - west) / FLAT_GRID, (north - south) / FLAT_GRID
        dem = _write(
            folder / f"{_safe(world.name)}-flat.tif",
            flat,
            Affine(step_x, 0.0, west, 0.0, -step_y, north),
            {"SOURCE": "the assumed flat ground"},
        )
        datum = "ellipsoid"
        messages.add(f"{what} has no terrain source: its imagery lies on the assumed flat ground")
    if not (world.attribution or any(s.attribution for _, s, _ in plan)):
        messages.add(
            f"{what}: no attribution given: credit its providers as their terms require (attribution in its [[world]] table)"
        )
    return (
        Layer(
            str(dem),
            "dem",
            ortho=ortho,
            vertical=datum,
            attribution=world.attribution or next((s.attribution for _, s, _ in plan), ""),
        ),
    )


def resolve_worlds(
    layers: tuple[Layer, ...],
    lat: npt.ArrayLike,
    lon: npt.ArrayLike,
    h: npt.ArrayLike,
    ground_h: float,
    reach_m: float,
    messages: Messages,
) -> tuple[Layer, ...]:
    """`layers` with each world layer (world_layer) replaced by the DEM layer built over the
    track (lat, lon deg, h ellipsoidal m; world_scene), or dropped when none could be built.
    A progress bar on stderr (a terminal only) while tiles are fetched."""
    out: list[Layer] = []
    for layer in layers:
        if layer.kind != "world":
            out.append(layer)
            continue
        height = float(np.median(np.asarray(h, np.float64))) - float(ground_h)
        out.extend(
            world_scene(
                layer.world,
                lat,
                lon,
                ground_h,
                reach_m,
                height,
                messages,
                progress=ProgressBar(f"world {layer.world.name}", sys.stderr),
            )
        )
    return tuple(out)
