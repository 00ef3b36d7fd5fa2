"""Pre-fetching a world for offline use (`geofuse cache CLIP | --bbox W,S,E,N [--out AREA]`):
the tiles a clip's scene will ask for (app.world.build.plan_world's levels, and PARENT_LEVELS
coarser ones for the fallback), or an area's at a given ground sampling, fetched into the disk
cache and, with an output, written into a local archive that `--imagery`/`--terrain` open with
the network off: MBTiles for Web Mercator tiles, GeoPackage for any grid (a WMTS's national
grid), a GeoTIFF for a GeoTIFF source's window.

Providers whose usage policy forbids bulk download are refused (app.world.providers.NO_BULK:
OpenStreetMap's own tile servers, Esri's ArcGIS Online basemaps). The size is estimated before anything is fetched, from the
tiles of the same source already in the cache (else TYPICAL_TILE_BYTES).
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.world import tiles as tm
from app.world.archives import write_gpkg, write_mbtiles
from app.world.build import FETCH_WORKERS, PARENT_LEVELS, SourcePlan, plan_world
from app.world.cache import TileCache
from app.world.cog import RasterFault, read_window
from app.world.grids import M_PER_DEG_LAT, GridRange, Matrix, TileGrid
from app.world.providers import bulk_refusal
from app.world.settings import World
from app.world.sources import QUANTIZED_MESH

TYPICAL_TILE_BYTES = {"imagery": 25_000, "terrain": 15_000}  # with no tile in the cache yet
MAX_PREFETCH_TILES = 50_000  # one pre-fetch asks for at most this many tiles
ARCHIVE_SUFFIXES = (".mbtiles", ".gpkg")


@dataclass
class Job:
    """One source's part of a pre-fetch: its plan and every tile (z, x, y) to fetch (the plan's
    level and coarser ones), or a GeoTIFF window (tiles empty); bytes_each: the estimated
    size of a tile (B) and from how many cached tiles it was measured."""

    plan: SourcePlan
    tiles: list[tuple[int, int, int]] = field(default_factory=list)
    bytes_each: float = 0.0
    measured: int = 0

    @property
    def levels(self) -> str:
        """The levels fetched, as people read them ("zoom 13-16", "levels 2-4 of swissgrid")."""
        if not self.tiles:
            return "a window"
        lo, hi = min(t[0] for t in self.tiles), max(t[0] for t in self.tiles)
        span = f"{lo}-{hi}" if lo != hi else f"{hi}"
        if isinstance(self.plan.tiles, GridRange):
            word = "levels" if lo != hi else "level"
            return f"{word} {span} of {self.plan.tiles.grid.name or 'its grid'}"
        return f"zoom {span}"


def refuse_bulk(world: World) -> None:
    """GeofuseError where a source's usage policy forbids bulk download."""
    for source in (world.imagery, world.terrain):
        if source is None or source.is_local:
            continue
        why = bulk_refusal(source.location)
        if why:
            raise GeofuseError(
                f"{source.kind} {source.label}: {why}: pre-fetch from a provider that allows it"
            )


def plan_prefetch(
    world: World,
    lat,
    lon,
    reach_m: float,
    height_m: float,
    cache: TileCache,
    area: bool = False,
) -> list[Job]:
    """The jobs that pre-fetch `world` over a track (lat, lon deg) plus reach_m (m) for a camera
    height_m (m) above the ground: the levels world_scene would take there (area: an area's,
    within MAX_PREFETCH_TILES rather than a scene's tile budget), and PARENT_LEVELS coarser
    ones. Raises GeofuseError for a refused provider or too many tiles."""
    refuse_bulk(world)
    budget = (MAX_PREFETCH_TILES, MAX_PREFETCH_TILES) if area else None
    plans = plan_world(
        world,
        lat,
        lon,
        reach_m if area else world.reach(reach_m),
        height_m,
        cache,
        math.inf,
        **({"max_tiles": budget, "max_reach_m": math.inf} if area else {}),
    )
    jobs = []
    for plan in plans:
        job = Job(plan)
        if plan.tiles is not None:
            job.tiles = _with_coarser(plan.tiles)
        sizes = _cached_sizes(cache, plan)
        job.measured = len(sizes)
        job.bytes_each = sum(sizes) / len(sizes) if sizes else float(TYPICAL_TILE_BYTES[plan.kind])
        jobs.append(job)
    total = sum(len(j.tiles) for j in jobs)
    if total > MAX_PREFETCH_TILES:
        for job in jobs:
            job.plan.fetcher.close()
        raise GeofuseError(
            f"{total} tiles is more than one pre-fetch asks for ({MAX_PREFETCH_TILES}): "
            "a smaller area, or a coarser --gsd"
        )
    return jobs


def check_archive(jobs: list[Job], out: Path) -> None:
    """GeofuseError, before anything is fetched, where `out` cannot hold a job's tiles: MBTiles
    holds Web Mercator tiles only; neither holds quantized-mesh tiles (they stay in the cache)."""
    for job in jobs:
        src = job.plan.source
        if src.form == QUANTIZED_MESH:
            raise GeofuseError(
                f"{src.kind} {src.label}: quantized-mesh tiles go into no archive here: "
                "pre-fetch them into the tile cache (no --out)"
            )
    if out.suffix.lower() != ".mbtiles":
        return
    for job in jobs:
        tiles = job.plan.tiles
        if isinstance(tiles, GridRange):
            src = job.plan.source
            raise GeofuseError(
                f"{src.kind} {src.label}: its tiles are in {tiles.grid.name or 'a grid'} (not Web "
                f"Mercator), which MBTiles cannot hold: --out {out.stem}.gpkg"
            )


def _with_coarser(tiles) -> list[tuple[int, int, int]]:
    """The range's tiles and those of up to PARENT_LEVELS coarser levels over the same area."""
    out = list(tiles.tiles())
    for k in range(1, min(PARENT_LEVELS, tiles.z) + 1):
        if isinstance(tiles, GridRange):
            out += tiles.grid.covering(tiles.bounds(), tiles.z - k).tiles()
        else:
            out += tm.covering(tiles.bounds_m(), tiles.z - k).tiles()
    return sorted(set(out))


def _cached_sizes(cache: TileCache, plan: SourcePlan, most: int = 200) -> list[int]:
    """Sizes (B) of up to `most` tiles of the plan's source already in the cache."""
    folder = cache.folder_of(plan.source.identity)
    sizes = []
    for p in folder.rglob("*") if folder.is_dir() else ():
        if p.is_file() and p.suffix == "" and p.name.isdigit():
            sizes.append(p.stat().st_size)
            if len(sizes) >= most:
                break
    return sizes


def estimate_line(jobs: list[Job]) -> str:
    """What a pre-fetch will fetch and about how much, in one line."""
    parts = []
    total = 0.0
    for job in jobs:
        src = job.plan.source
        if job.tiles:
            size = len(job.tiles) * job.bytes_each
            how = (
                f"measured on {job.measured} cached"
                if job.measured
                else f"~{job.bytes_each / 1000:.0f} kB each"
            )
            parts.append(
                f"{len(job.tiles)} {src.kind} tiles of {src.label} at {job.levels} ({how})"
            )
        elif job.plan.box is not None:
            w, h = _window_px(job.plan)
            size = w * h * (3 if src.kind == "imagery" else 4) / 2.0  # deflated, roughly
            parts.append(f"a {src.kind} window of {src.label} (at most {w} x {h} px)")
        else:
            continue
        total += size
    return "; ".join(parts) + f": about {total / 1e6:.1f} MB"


def _window_px(plan: SourcePlan) -> tuple[int, int]:
    """The most pixels (across, down) a GeoTIFF window over the plan's box is read at."""
    west, south, east, north = plan.box
    lat = math.radians((south + north) / 2.0)
    w_m = (east - west) * M_PER_DEG_LAT * max(math.cos(lat), 0.05)
    h_m = (north - south) * M_PER_DEG_LAT
    step = max(plan.needed_m, 1e-3)
    return (
        min(plan.max_side, max(1, math.ceil(w_m / step))),
        min(plan.max_side, max(1, math.ceil(h_m / step))),
    )


def run_prefetch(
    jobs: list[Job],
    cache: TileCache,
    out: Path | None,
    messages: Messages,
    what: str,
    progress: Callable[[float], None] | None = None,
) -> list[tuple[str, Path, int]]:
    """Fetch every job's tiles (into the cache), and with `out` (an .mbtiles or .gpkg path)
    write them into archives: imagery at `out`, terrain beside it (AREA-terrain.SUFFIX; a
    GeoTIFF window as AREA-KIND.tif). Faults said once per source in `messages` (`what` names
    the world). Returns (kind, archive, tiles written) for each archive written."""
    total = max(1, sum(max(1, len(j.tiles)) for j in jobs))
    done = 0
    written = []
    for job in jobs:
        plan, fetcher = job.plan, job.plan.fetcher
        label = f"{what} {plan.kind}"
        try:
            if plan.box is not None:
                try:
                    r = read_window(
                        plan.source, plan.box, plan.needed_m, plan.max_side, cache, math.inf
                    )
                except RasterFault as exc:
                    messages.add(
                        plan.source.redact(
                            f"{label} ({plan.source.label}): the GeoTIFF could not be read: {exc}"
                        )
                    )
                    continue
                done += 1
                if out is not None and r.kept is not None:
                    target = out.with_name(f"{out.stem}-{plan.kind}.tif")
                    shutil.copyfile(r.kept, target)
                    written.append((plan.kind, target, 1))
                continue
            got: dict[tuple[int, int, int], bytes] = {}
            with ThreadPoolExecutor(FETCH_WORKERS) as pool:
                futures = {pool.submit(fetcher.get_bytes, *t, True): t for t in job.tiles}
                for future in as_completed(futures):
                    data = future.result()
                    if data is not None:
                        got[futures[future]] = data
                    done += 1
                    if progress is not None:
                        progress(done / total)
            fetcher.report(messages, label)
            if out is not None and got:
                target = (
                    out
                    if plan.kind == "imagery"
                    else out.with_name(f"{out.stem}-terrain{out.suffix}")
                )
                written.append((plan.kind, target, _write_archive(target, job, got)))
        finally:
            fetcher.close()
    cache.trim()
    return written


def _write_archive(target: Path, job: Job, got: dict[tuple[int, int, int], bytes]) -> int:
    """Tiles into an MBTiles (Web Mercator only) or a GeoPackage (any grid) at `target`."""
    plan = job.plan
    src = plan.source
    grid_range = plan.tiles if isinstance(plan.tiles, GridRange) else None
    if target.suffix.lower() == ".mbtiles":
        check_archive([job], target)
        first = next(iter(got.values()))
        fmt = "jpg" if first[:3] == b"\xff\xd8\xff" else "png"
        zs = [z for z, _, _ in got]
        lon_lat = _lonlat_bounds(plan)
        metadata = {
            "name": target.stem,
            "format": fmt,
            "type": "baselayer",
            "minzoom": str(min(zs)),
            "maxzoom": str(max(zs)),
            "bounds": ",".join(f"{v:.7f}" for v in lon_lat),
            "attribution": src.attribution,
            "description": f"{src.kind} from {src.label} (geofuse cache)",
        }
        if src.encoding:
            metadata["encoding"] = src.encoding
        return write_mbtiles(
            target, ((z, x, y, d) for (z, x, y), d in sorted(got.items())), metadata
        )
    grid = (
        grid_range.grid if grid_range is not None else _web_mercator_grid(max(z for z, _, _ in got))
    )
    return write_gpkg(
        target,
        grid,
        ((z, x, y, d) for (z, x, y), d in sorted(got.items())),
        table=plan.kind,
    )


def _lonlat_bounds(plan: SourcePlan) -> tuple[float, float, float, float]:
    west, south, east, north = plan.tiles.bounds_m()
    lon = [v / tm.HALF_WORLD_M * 180.0 for v in (west, east)]
    lat = [
        math.degrees(2.0 * math.atan(math.exp(v / 6378137.0)) - math.pi / 2.0)
        for v in (south, north)
    ]
    return lon[0], lat[0], lon[1], lat[1]


def _web_mercator_grid(max_zoom: int) -> TileGrid:
    """The XYZ scheme as a TileGrid (levels 0..max_zoom), for a GeoPackage of XYZ tiles."""
    half = tm.HALF_WORLD_M
    return TileGrid(
        "EPSG:3857",
        tuple(
            Matrix(str(z), tm.tile_span_m(z) / 256, -half, half, 256, 256, 1 << z, 1 << z)
            for z in range(max_zoom + 1)
        ),
        "GoogleMapsCompatible",
    )
