"""A world's tiles over a clip's track -> a DEM and an orthophoto GeoTIFF (each in its source's
CRS: EPSG:3857 for XYZ tiles, a WMTS's or GeoPackage's own grid, a quantized-mesh layer's
EPSG:4326 or EPSG:3857 tiling (its meshes sampled at the DEM's pixels), a GeoTIFF's own) in the
cache folder -> the scene's DEM layer (app.scene.terrain drapes the one on the other, in the
session's ENU frame, with its RTIN mesh and vertical datum).

The area: the track's extent plus the camera's reach on the ground (the assumed ground's,
app.scene.ground_plane.ground_reach_m, or the world's reach_m; at most MAX_REACH_M), in the
source's CRS. The levels: imagery at the coarsest level whose pixels are at most the clip's
ground sampling (estimated from its height above the ground), terrain TERRAIN_COARSER times
coarser, each within a tile budget (a GeoTIFF's window within as many pixels). A tile that
cannot be had is drawn from up to PARENT_LEVELS coarser tiles (a quantized-mesh level no finer
than the finest its layer has tiles at over the area); imagery without terrain lies on the
assumed flat ground. Everything fetched is bounded by the world's timeout_s.

Commands that write files build the world before they go on (resolve_worlds); the viewer opens
on the flat ground instead and builds it in the background, a coarser level first
(deferred_worlds records what to build; app.world.background builds it).
"""

from __future__ import annotations

import hashlib
import math
import re
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import rasterio
from affine import Affine
from scipy import ndimage

from app.core.messages import INFO, Messages
from app.core.progress import ProgressBar
from app.scene.layers import Layer
from app.world import defaults, grids
from app.world import tiles as tm
from app.world.cache import TileCache
from app.world.cog import RasterFault, read_window
from app.world.fetch import SourceFetcher
from app.world.grids import GridRange, lonlat_box
from app.world.overpass import buildings_layers
from app.world.settings import World, how_to_configure, settings_path
from app.world.sources import QUANTIZED_MESH, TileSource, decode_heights

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
MAX_WINDOW_SIDE = 8192  # a GeoTIFF's window is read at most this many pixels a side


def world_layer(world: World) -> Layer:
    """The layer that stands for `world` until a clip's track resolves it (resolve_worlds)."""
    return Layer(f"world:{world.name}", "world", world=world, attribution=world.credit)


Tiles = tm.TileRange | GridRange  # XYZ Web Mercator tiles, or a grid's (app.world.grids)


@dataclass
class Mosaic:
    """Tiles at one level in one array: (H, W, 3) uint8 imagery or (H, W) float64 heights (NaN:
    none), with the tiles it covers, each tile_px wide; counts of tiles had at their own level
    and from a coarser one."""

    data: np.ndarray
    tiles: Tiles
    tile_px: int
    own: int
    coarser: int

    def transform(self) -> Affine:
        """Pixel (col, row) -> (x, y) of its corner in the tiles' CRS (crs)."""
        return Affine(*self.tiles.transform(self.tile_px))

    @property
    def crs(self) -> str:
        return self.tiles.grid.crs if isinstance(self.tiles, GridRange) else "EPSG:3857"


@dataclass
class Made:
    """A layer's raster over the clip: data as Mosaic's, the affine of its pixel corners in
    `crs`, and what the GeoTIFF's SOURCE tag says of its level ("zoom 16", "level 4 of
    swissgrid", "window 240x240")."""

    data: np.ndarray
    transform: Affine
    crs: str
    level: str


@dataclass
class SourcePlan:
    """What is read of one source over a clip: tiles (TileRange or GridRange), or a GeoTIFF's
    window over `box` (west, south, east, north deg) at pixels of needed_m (m) and at most
    max_side a side; neither when the source cannot be opened (its fetcher says why)."""

    kind: str
    source: TileSource
    fetcher: SourceFetcher
    tiles: Tiles | None = None
    box: tuple[float, float, float, float] | None = None
    needed_m: float = 0.0
    max_side: int = 0

    @property
    def count(self) -> int:
        """Tiles to fetch (a window counts as one)."""
        return self.tiles.count if self.tiles is not None else 1


def _resize(tile: np.ndarray, size: int, width: int | None = None) -> np.ndarray:
    """A tile (H, W[, 3]) resampled (bilinear) to size rows x width (default size) columns."""
    width = size if width is None else width
    if tile.shape[0] == size and tile.shape[1] == width:
        return tile
    f = (size / tile.shape[0], width / tile.shape[1]) + ((1,) if tile.ndim == 3 else ())
    out = ndimage.zoom(tile.astype(np.float64), f, order=1, mode="nearest", grid_mode=True)
    return out.astype(tile.dtype) if tile.dtype == np.uint8 else out


def _parent_window(tiles: Tiles, z: int, x: int, y: int, k: int):
    """(z', x', y', (row0, col0, height, width)) of the tile k levels up holding (z, x, y),
    where the child lies in it as fractions of the parent's size; None where none holds it."""
    if isinstance(tiles, GridRange):
        return tiles.parent(z, x, y, k)
    pz, px, py, col, row = tm.parent(z, x, y, k)
    f = 1.0 / (1 << k)
    return pz, px, py, (row * f, col * f, f, f)


def mosaic(
    fetcher: SourceFetcher,
    tiles: Tiles,
    decode: Callable[[np.ndarray], np.ndarray],
    progress: Callable[[float], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> Mosaic | None:
    """The tiles of `tiles` fetched (in parallel) and decoded into one Mosaic; a tile not had is
    cut from a coarser one (up to PARENT_LEVELS up); None when no tile at all was had, or when
    stop() turned true (the tiles not asked for yet are not asked for)."""
    got: dict[tuple[int, int, int], np.ndarray] = {}
    todo = tiles.tiles()
    with ThreadPoolExecutor(FETCH_WORKERS) as pool:
        futures = {pool.submit(fetcher.get, *t): t for t in todo}
        for i, future in enumerate(as_completed(futures)):
            if stop is not None and stop():
                for f in futures:
                    f.cancel()
                return None
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
            found = _parent_window(tiles, z, x, y, k)
            if found is None:
                continue
            pz, px, py, (fr, fc, fh, fw) = found
            if (pz, px, py) not in parents:
                arr = fetcher.get(pz, px, py)
                parents[(pz, px, py)] = None if arr is None else decode(arr)
            p = parents[(pz, px, py)]
            if p is not None:
                r0, c0 = int(round(fr * p.shape[0])), int(round(fc * p.shape[1]))
                h = max(1, int(round(fh * p.shape[0])))
                w = max(1, int(round(fw * p.shape[1])))
                filled[(z, x, y)] = p[r0 : r0 + h, c0 : c0 + w]
                break
    if not got and not filled:
        return None
    tile_px = next(iter(got.values())).shape[1] if got else ASSUMED_TILE_PX
    tile_h = max(1, int(round(tile_px * getattr(tiles, "tile_aspect", 1.0))))
    rows, cols = tiles.shape
    sample = next(iter((got or filled).values()))
    shape = (rows * tile_h, cols * tile_px) + sample.shape[2:]
    out = np.full(shape, np.nan if sample.dtype != np.uint8 else 128, sample.dtype)
    for (_, x, y), arr in (got | filled).items():
        r, c = (y - tiles.y0) * tile_h, (x - tiles.x0) * tile_px
        out[r : r + tile_h, c : c + tile_px] = _resize(arr, tile_h, tile_px)
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


def _write(
    path: Path, data: np.ndarray, transform: Affine, tags: dict[str, str], crs: str = "EPSG:3857"
) -> Path:
    """A GeoTIFF in `crs`: (H, W) float heights (NaN nodata) or (H, W, 3) uint8 RGB."""
    bands = data[None] if data.ndim == 2 else np.moveaxis(data, -1, 0)
    profile = {
        "driver": "GTiff",
        "width": data.shape[1],
        "height": data.shape[0],
        "count": bands.shape[0],
        "dtype": "float32" if data.ndim == 2 else "uint8",
        "crs": crs,
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


def _tags(world: World, source: TileSource, z: int | str) -> dict[str, str]:
    """GeoTIFF metadata of a world's layer: its attribution (as licences require), the source
    by its label (never its key) and its level (a zoom, or words: Made.level)."""
    credit = world.attribution or source.attribution
    level = f"zoom {z}" if isinstance(z, int) else z
    return {
        "TIFFTAG_COPYRIGHT": credit,
        "ATTRIBUTION": credit,
        "SOURCE": f"{source.kind} {source.label} {level}",
    }


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)[:40] or "world"


def bounded_reach(reach_m: float, max_reach_m: float = MAX_REACH_M) -> float:
    """A camera's reach on the ground (m) as a world is read over it: at least MIN_REACH_M, at
    most max_reach_m."""
    return min(max(reach_m, MIN_REACH_M), max_reach_m)


def world_box(
    lat: npt.ArrayLike, lon: npt.ArrayLike, reach_m: float, max_reach_m: float = MAX_REACH_M
) -> tuple[float, float, float, float]:
    """(west, south, east, north) deg of the area a world is read over: the track (lat, lon
    deg) plus reach_m (m, bounded by MIN_REACH_M and max_reach_m) on the ground."""
    lat, lon = (
        np.atleast_1d(np.asarray(lat, np.float64)),
        np.atleast_1d(np.asarray(lon, np.float64)),
    )
    return lonlat_box(lat, lon, bounded_reach(reach_m, max_reach_m))


def plan_world(
    world: World,
    lat: npt.ArrayLike,
    lon: npt.ArrayLike,
    reach_m: float,
    height_m: float,
    cache: TileCache,
    deadline: float,
    clock: Callable[[], float] = time.monotonic,
    max_tiles: tuple[int, int] = (TERRAIN_MAX_TILES, IMAGERY_MAX_TILES),
    max_reach_m: float = MAX_REACH_M,
    coarser: int = 0,
) -> list[SourcePlan]:
    """What world_scene reads of each of the world's sources (terrain first) over the track
    (lat, lon deg) plus reach_m (m, bounded by MIN_REACH_M and max_reach_m) for a camera
    height_m above the ground (m): the sources opened (a WMTS's capabilities fetched, an
    archive's pyramid read), their levels chosen within max_tiles (terrain, imagery; a
    GeoTIFF's window within as many 256-px tiles), each `coarser` levels coarser than that
    (a window's pixels 2**coarser times larger). Close each plan's fetcher when done."""
    lat, lon = (
        np.atleast_1d(np.asarray(lat, np.float64)),
        np.atleast_1d(np.asarray(lon, np.float64)),
    )
    lat0 = float(np.mean(lat))
    reach = bounded_reach(reach_m, max_reach_m)
    bounds = _bounds(lat, lon, reach)
    box = lonlat_box(lat, lon, reach)
    needed = max(MIN_GSD_M, abs(height_m) / 1000.0)  # a 1000-px-wide view of 53 deg, nadir
    plans = []
    for kind, source, needed_m, budget in (
        ("terrain", world.terrain, needed * TERRAIN_COARSER, max_tiles[0]),
        ("imagery", world.imagery, needed, max_tiles[1]),
    ):
        if source is None:
            continue
        fetcher = SourceFetcher(source, cache, deadline, clock=clock)
        plan = SourcePlan(kind, source, fetcher, needed_m=needed_m * 2.0**coarser)
        if source.form == "cog":
            plan.box = box
            plan.max_side = min(int(math.sqrt(budget)) * ASSUMED_TILE_PX, MAX_WINDOW_SIDE)
        elif source.web_mercator:
            if fetcher.open():
                z = tm.choose_zoom(
                    bounds, needed_m, lat0, ASSUMED_TILE_PX, fetcher.max_zoom(), budget
                )
                plan.tiles = tm.covering(bounds, max(0, z - coarser))
        else:
            grid = fetcher.grid()
            if grid is not None:
                own = grids.box_in(grid.crs, box)
                z = fetcher.finest_level(own, grid.choose_level(own, needed_m, budget))
                plan.tiles = grid.covering(own, max(0, z - coarser))
        plans.append(plan)
    return plans


def _read_plan(
    plan: SourcePlan,
    what: str,
    lat0: float,
    messages: Messages,
    cache: TileCache,
    deadline: float,
    clock: Callable[[], float],
    progress: Callable[[float], None],
    stop: Callable[[], bool] | None = None,
) -> Made | None:
    """A plan's raster (its tiles mosaicked, or its window read), what it took said in
    `messages`; None when nothing could be had (the fault said once)."""
    source, fetcher = plan.source, plan.fetcher
    label = f"{what} {plan.kind}"
    if plan.box is not None:
        try:
            r = read_window(source, plan.box, plan.needed_m, plan.max_side, cache, deadline, clock)
        except RasterFault as exc:
            messages.add_once(
                f"world-faults {label}",
                source.redact(f"{label} ({source.label}): the GeoTIFF could not be read: {exc}"),
            )
            return None
        finally:
            progress(1.0)
        h, w = r.data.shape[:2]
        messages.info(
            f"{label}: a {w} x {h} window of {source.label} (~{r.pixel_m:.1f} m a pixel; "
            + ("from the cache" if r.from_cache else "read by range requests")
            + ")"
        )
        return Made(r.data, r.transform, r.crs, f"window {w}x{h}")
    if plan.tiles is None:
        fetcher.report(messages, label)
        return None
    tiles = plan.tiles
    decode = (
        (lambda a, enc=source.encoding: decode_heights(a, enc))
        if plan.kind == "terrain" and source.form != QUANTIZED_MESH  # meshes come as heights
        else (lambda a: a)
    )
    m = mosaic(fetcher, tiles, decode, progress, stop)
    fetcher.report(messages, label)
    if m is None:
        return None
    if isinstance(tiles, GridRange):
        west, south, east, north = tiles.bounds()
        res_m = tiles.grid.pixel_m(tiles.z, (west + east) / 2, (south + north) / 2)
        res_m *= tiles.matrix.tile_w / m.tile_px
        level = f"level {tiles.matrix.ident} of {tiles.grid.name or 'its grid'}"
    else:
        res_m = tm.pixel_m(tiles.z, m.tile_px, lat0)
        level = f"zoom {tiles.z}"
    messages.info(
        f"{label}: {m.own + m.coarser} tiles of {source.label} at {level} "
        f"(~{res_m:.1f} m a pixel; {fetcher.requests} requests, {fetcher.from_cache} from the cache"
        + (f", {m.coarser} drawn from a coarser level" if m.coarser else "")
        + ")"
    )
    return Made(m.data, m.transform(), m.crs, level)


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
    coarser: int = 0,
    stop: Callable[[], bool] | None = None,
    tiles: Callable[[int, int], None] | None = None,
) -> tuple[Layer, ...]:
    """The world's DEM layer (its orthophoto draped) over the track (lat, lon deg), or () when
    no tile could be had (said in `messages`, the caller keeps its flat ground).

    ground_h: the assumed ground's ellipsoidal height (m), under imagery without terrain;
    reach_m: the camera's reach on the ground beyond the track (m); height_m: the camera's
    typical height above the ground (m), which sets the imagery's ground sampling; coarser:
    levels coarser than that (plan_world; a first look: nothing said when none is had);
    stop: () as soon as it turns true; tiles: called with (tiles done, tiles to fetch) as they
    come. Notes said again by a second build in the same `messages` are said once."""
    cache = cache or TileCache()
    lat0 = float(np.mean(np.atleast_1d(np.asarray(lat, np.float64))))
    deadline = clock() + world.timeout_s
    what = f"world {world.name}"
    plans = plan_world(world, lat, lon, reach_m, height_m, cache, deadline, clock, coarser=coarser)
    total = sum(p.count for p in plans)
    if tiles is not None:
        tiles(0, total)
    done = 0
    made: dict[str, Made] = {}
    for plan in plans:

        def step(f: float, start: int = done, n: int = plan.count) -> None:
            if progress is not None:
                progress((start + f * n) / max(1, total))
            if tiles is not None:
                tiles(int(round(start + f * n)), total)

        got = None
        try:
            if stop is None or not stop():
                got = _read_plan(plan, what, lat0, messages, cache, deadline, clock, step, stop)
        finally:
            plan.fetcher.close()
        done += plan.count
        if got is not None:
            made[plan.kind] = got
    if stop is not None and stop():
        return ()
    if not made:
        if not coarser:
            messages.add(
                f"{what}: no tile could be had: the video is projected on the assumed flat ground instead"
            )
        return ()
    cache.trim()
    key = hashlib.sha256(
        repr([(p.source.identity, p.tiles, p.box, p.needed_m) for p in plans] + [ground_h]).encode()
    ).hexdigest()[:16]
    folder = cache.root / "worlds" / key
    ortho = None
    if "imagery" in made:
        m = made["imagery"]
        ortho = _write(
            folder / f"{_safe(world.name)}-imagery.tif",
            m.data,
            m.transform,
            _tags(world, world.imagery, m.level),
            m.crs,
        )
    if "terrain" in made:
        m = made["terrain"]
        datum = world.terrain.datum
        dem = _write(
            folder / f"{_safe(world.name)}-terrain.tif",
            m.data.astype(np.float32),
            m.transform,
            _tags(world, world.terrain, m.level),
            m.crs,
        )
        text = (
            f"{what} terrain: heights taken as above {'the ellipsoid' if datum == 'ellipsoid' else datum.upper()} "
            "(datum in its [[world]] table, or --dem-vertical, says otherwise)"
        )
        messages.add_once(text, text, INFO)
    else:
        m = made["imagery"]
        h, w = m.data.shape[:2]
        west, north = m.transform.c, m.transform.f
        east, south = m.transform @ (w, h)
        flat = np.full((FLAT_GRID, FLAT_GRID), float(ground_h), np.float32)
        step_x, step_y = (east - west) / FLAT_GRID, (north - south) / FLAT_GRID
        dem = _write(
            folder / f"{_safe(world.name)}-flat.tif",
            flat,
            Affine(step_x, 0.0, west, 0.0, -step_y, north),
            {"SOURCE": "the assumed flat ground"},
            m.crs,
        )
        datum = "ellipsoid"
        text = f"{what} has no terrain source: its imagery lies on the assumed flat ground"
        messages.add_once(text, text)
    sources = [p.source for p in plans]
    if not (world.attribution or any(s.attribution for s in sources)):
        text = f"{what}: no attribution given: credit its providers as their terms require (attribution in its [[world]] table)"
        messages.add_once(text, text)
    return (
        Layer(
            str(dem),
            "dem",
            ortho=ortho,
            vertical=datum,
            attribution=world.credit,
        ),
    )


@dataclass(frozen=True)
class WorldRequest:
    """A world layer (world_layer) to build over a clip's track: lat, lon (N,) deg and h (N,)
    ellipsoidal m of its fixes; ground_h: the assumed ground's ellipsoidal height (m); reach_m:
    the camera's reach on the ground beyond the track (m); above_takeoff: the track's heights
    are above a take-off assumed at ground_h, which the world's terrain is to be placed at (the
    viewer opens such a clip on the flat ground before the terrain is had)."""

    layer: Layer
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    ground_h: float
    reach_m: float
    above_takeoff: bool = False

    @property
    def world(self) -> World:
        return self.layer.world


def build_world(
    request: WorldRequest,
    messages: Messages,
    progress: Callable[[float], None] | None = None,
    coarser: int = 0,
    stop: Callable[[], bool] | None = None,
    tiles: Callable[[int, int], None] | None = None,
) -> tuple[Layer, ...]:
    """The request's DEM layer built over its track (world_scene, with its progress, coarser,
    stop and tiles), and, at the full level (coarser 0), its buildings fetched over the same
    area (app.world.overpass), where it has them; () when none could be had."""
    world, lat, lon = request.world, request.lat, request.lon
    out: list[Layer] = []
    if world.probe_s and not _default_answers(world, messages):
        return ()
    height = float(np.median(np.asarray(request.h, np.float64))) - float(request.ground_h)
    if world.imagery is not None or world.terrain is not None:
        out.extend(
            world_scene(
                world,
                lat,
                lon,
                request.ground_h,
                request.reach_m,
                height,
                messages,
                progress=progress,
                coarser=coarser,
                stop=stop,
                tiles=tiles,
            )  # fmt: skip
        )
    if world.buildings is not None and not coarser and not (stop is not None and stop()):
        box = world_box(lat, lon, request.reach_m)
        what = f"world {world.name} buildings"
        out.extend(
            buildings_layers(world.buildings, box, TileCache(), messages, what, world.timeout_s)
        )
    return tuple(out)


def _default_answers(world: World, messages: Messages) -> bool:
    """Whether the default world's servers answer within its probe_s (app.world.defaults),
    said either way (once): the sources used, or the flat ground and how to configure."""
    sources = [s for s in (world.imagery, world.terrain) if s is not None]
    names = ", ".join(dict.fromkeys(s.label.split("/", 1)[0] for s in sources))
    if defaults.network_answers([s.location for s in sources], world.probe_s):
        credit = f"; credited: {world.credit}" if world.credit else ""
        text = (
            f"world {world.name}: nothing configured, so the default open sources ({names}"
            f"{credit}); others: a [[world]] table of {settings_path()}, or --imagery/--terrain "
            "SRC (`geofuse cache --providers` lists providers by name)"
        )
        messages.add_once(text, text, INFO)
        return True
    text = (
        f"world {world.name}: the default open sources ({names}) did not answer within "
        f"{world.probe_s:g} s (offline?): the video is projected on the assumed flat ground; "
        + how_to_configure()
    )
    messages.add_once(text, text)
    return False


_DEFERRED: ContextVar[list[WorldRequest] | None] = ContextVar("geofuse_worlds", default=None)


@contextmanager
def deferred_worlds() -> Iterator[list[WorldRequest]]:
    """Within it, on this thread, resolve_worlds builds no world: it drops each world layer
    (the flat ground, or the other layers, stand in) and appends what it would have built to
    the list yielded, for a caller that builds it in the background (the viewer:
    app.world.background). Other threads build as before."""
    requests: list[WorldRequest] = []
    token = _DEFERRED.set(requests)
    try:
        yield requests
    finally:
        _DEFERRED.reset(token)


def deferring(layers: tuple[Layer, ...]) -> bool:
    """Whether resolve_worlds would defer a world layer among `layers` (deferred_worlds): the
    flat ground then stands in for it only until it is built, which is no cause for a warning."""
    return _DEFERRED.get() is not None and any(layer.kind == "world" for layer in layers)


def resolve_worlds(
    layers: tuple[Layer, ...],
    lat: npt.ArrayLike,
    lon: npt.ArrayLike,
    h: npt.ArrayLike,
    ground_h: float,
    reach_m: float,
    messages: Messages,
    above_takeoff: bool = False,
) -> tuple[Layer, ...]:
    """`layers` with each world layer (world_layer) replaced by the DEM layer built over the
    track (lat, lon deg, h ellipsoidal m; world_scene), or dropped when none could be built,
    and by its buildings fetched over the same area (app.world.overpass), where it has them.
    A progress bar on stderr (a terminal only) while tiles are fetched; said that it is built
    before the command goes on. Within deferred_worlds, recorded instead (above_takeoff: the
    track's heights are above a take-off assumed at ground_h, see WorldRequest)."""
    deferred = _DEFERRED.get()
    others = any(layer.kind != "world" for layer in layers)
    out: list[Layer] = []
    for layer in layers:
        if layer.kind != "world":
            out.append(layer)
            continue
        request = WorldRequest(
            layer,
            np.array(lat, np.float64),
            np.array(lon, np.float64),
            np.array(h, np.float64),
            float(ground_h),
            float(layer.world.reach(reach_m)),
            above_takeoff and not others,
        )
        bounded = bounded_reach(request.reach_m)
        whose = "its reach_m" if layer.world.reach_m is not None else "the camera's reach"
        area = f"over the track plus {bounded:.0f} m ({whose})"
        if deferred is not None:
            deferred.append(request)
            messages.info(
                f"world {layer.world.name}: {area}, built in the background; the flat ground stands in until its first tiles arrive"
            )
            continue
        messages.info(
            f"world {layer.world.name}: {area}, built in full before going on (`geofuse view` "
            "streams it in instead)"
        )
        out.extend(
            build_world(request, messages, ProgressBar(f"world {layer.world.name}", sys.stderr))
        )
    return tuple(out)
