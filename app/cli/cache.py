"""`geofuse cache`: what the tile cache of worlds holds (app.world.cache), clearing it, and
pre-fetching a clip's or an area's tiles for offline use, perhaps into archives that
`--imagery`/`--terrain` open with the network off (app.world.prefetch)."""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from pathlib import Path

import numpy as np

from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.core.outputs import check_output
from app.core.progress import ProgressBar
from app.footage.clips import open_any
from app.session.model import Session
from app.world import providers
from app.world.build import MAX_REACH_M, world_box
from app.world.cache import KeptSource, TileCache
from app.world.overpass import OverpassFetch
from app.world.prefetch import (
    ARCHIVE_SUFFIXES,
    check_archive,
    estimate_line,
    plan_prefetch,
    run_prefetch,
)
from app.world.settings import World, choose_world, world_tables

WORLDS_FOLDER = "worlds"  # app.world.build keeps the scenes it built there


def run(args: argparse.Namespace) -> int:
    if getattr(args, "providers", None) is not None:
        if args.clips or args.bbox is not None or args.clear is not None:
            raise GeofuseError("--providers goes alone (no CLIP, --bbox or --clear)")
        return _providers(args.providers)
    cache = TileCache()
    if args.clear is not None:
        if args.clips or args.bbox is not None:
            raise GeofuseError("--clear goes alone (no CLIP, no --bbox)")
        return _clear(cache, args.clear)
    if not args.clips and args.bbox is None:
        if args.out is not None:
            raise GeofuseError("--out: name what to pre-fetch (CLIP... or --bbox W,S,E,N)")
        return _list(cache)
    if args.clips and args.bbox is not None:
        raise GeofuseError("pre-fetch CLIP... or --bbox W,S,E,N, not both")
    out = None
    if args.out is not None:
        out = check_output(args.out, "--out", ARCHIVE_SUFFIXES, args.clips)
    world = choose_world(
        args.world, args.imagery, args.terrain, buildings=getattr(args, "buildings", None)
    )
    if world is None:
        raise GeofuseError(
            "nothing to pre-fetch: name the sources (--world NAME, or --imagery/--terrain SRC, --buildings overpass:)"
        )
    areas = [_bbox_area(args.bbox, args.gsd)] if args.bbox is not None else []
    areas += [_clip_area(Path(c)) for c in args.clips]
    lat = np.concatenate([a[0] for a in areas])
    lon = np.concatenate([a[1] for a in areas])
    reach = max(a[2] for a in areas)
    height = max(a[3] for a in areas)
    jobs = plan_prefetch(world, lat, lon, reach, height, cache, area=args.bbox is not None)
    if out is not None:
        try:
            check_archive(jobs, out)
        except GeofuseError:
            for job in jobs:
                job.plan.fetcher.close()
            raise
    messages = Messages()
    for job in jobs:
        if job.plan.tiles is None and job.plan.box is None:  # could not be opened: say why
            job.plan.fetcher.report(messages, f"world {world.name} {job.plan.kind}")
    if jobs:
        print(f"geofuse cache: world {world.name}: {estimate_line(jobs)}", file=sys.stderr)
    written = run_prefetch(
        jobs,
        cache,
        out,
        messages,
        f"world {world.name}",
        ProgressBar(f"pre-fetching world {world.name}", sys.stderr),
    )
    if world.buildings is not None:
        box = world_box(lat, lon, reach, math.inf if args.bbox is not None else MAX_REACH_M)
        written += _prefetch_buildings(world, box, cache, messages, out)
    for message in messages.since(0):
        print(message, file=sys.stderr)
    fetched = sum(j.plan.fetcher.requests for j in jobs)
    kept = sum(j.plan.fetcher.from_cache for j in jobs)
    print(f"{fetched} tile requests, {kept} tiles already in the cache ({cache.root})")
    for kind, path, n in written:
        what = "window" if path.suffix.lower() == ".tif" else "tile" if n == 1 else "tiles"
        what = "answer" if kind == "buildings" else what
        print(f"wrote {path}: {n} {kind} {what}")
    if written:
        print("offline: " + _offline_options(world, written))
    return 0 if written or out is None else 1


def _offline_options(world: World, written: list[tuple[str, Path, int]]) -> str:
    """The --imagery/--terrain that open what was written."""
    parts = []
    for kind, path, _ in written:
        if kind == "buildings":
            parts.append(f"--buildings {path}")
            continue
        source = world.imagery if kind == "imagery" else world.terrain
        prefix = f"{source.encoding}:" if source is not None and source.encoding else ""
        if path.suffix.lower() == ".tif":
            prefix = ""
        parts.append(f"--{kind} {prefix}{path}")
    return " ".join(parts)


def _prefetch_buildings(
    world: World,
    box: tuple[float, float, float, float],
    cache: TileCache,
    messages: Messages,
    out: Path | None,
) -> list[tuple[str, Path, int]]:
    """The world's buildings over the (west, south, east, north) deg box fetched into the cache
    (the query a scene over it asks: app.world.overpass); with `out`, copied beside it as
    AREA-buildings.osm. Returns what was written, as run_prefetch does."""
    what = f"world {world.name} buildings"
    answer = OverpassFetch(world.buildings, cache, world.timeout_s).answer(box, messages, what)
    if answer is None or answer.path is None or out is None:
        return []
    target = out.with_name(f"{out.stem}-buildings.osm")
    shutil.copyfile(answer.path, target)
    return [("buildings", target, 1)]


def _bbox_area(bbox: tuple[float, ...], gsd_m: float):
    """(lat, lon, reach m, height m) of a W,S,E,N box: its corners, no reach, the camera height
    whose ground sampling world_scene takes as gsd_m (1000 px across a 53 deg view)."""
    west, south, east, north = bbox
    if west >= east or south >= north:
        raise GeofuseError(f"--bbox {bbox}: expected W < E and S < N")
    return np.array([south, north]), np.array([west, east]), 0.0, gsd_m * 1000.0


def _clip_area(path: Path):
    """(lat, lon, reach m, height m) of a clip as its scene would be built: its track, the
    reach its assumed ground has (app.footage.clips.frame_and_ground) and its height above it."""
    if path.suffix.lower() == ".toml":
        raise GeofuseError(
            f"{path}: geofuse cache takes clips; a manifest's [world] is fetched as it opens (or give --bbox)"
        )
    session: Session = open_any(path)
    gnss, frame = session.gnss, session.frame
    enu = frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h)
    plane = [p.positions for p in session.mesh.primitives if p.name == "assumed ground"]
    half = float(np.ptp(np.asarray(plane[0] if plane else enu)[:, 0])) / 2.0
    reach = max(0.0, half - float(np.max(np.ptp(enu[:, :2], axis=0))) / 2.0)
    height = float(np.median(gnss.h)) - frame.h_m
    return gnss.lat, gnss.lon, reach, height


def _providers(contains: str) -> int:
    """`geofuse cache --providers [TEXT]`: the catalogue (app.world.providers), one a line."""
    found = list(providers.catalogue(contains))
    if not found:
        raise GeofuseError(f"--providers {contains}: no provider's name holds it")
    for p in found:
        print(providers.describe(p))
    print(
        f"{len(found)} provider{'s' if len(found) != 1 else ''}: name one with --imagery NAME (terrain: --terrain NAME), or in a "
        "[[world]] table; a key goes in the environment variable named, or key_env/key there"
    )
    return 0


def _describe(kept: KeptSource) -> str:
    if not kept.identity:
        return "scenes built" if kept.folder.name == WORLDS_FOLDER else f"({kept.folder.name})"
    parts = kept.identity.split("|", 3)
    if len(parts) < 4:
        return kept.identity
    kind, encoding, _, location = parts
    doc = location.endswith("|capabilities")
    location = location.removesuffix("|capabilities")
    return (
        f"{kind} {location}"
        + (f" ({encoding})" if encoding not in ("None", "") else "")
        + (" capabilities" if doc else "")
    )


def _list(cache: TileCache) -> int:
    kept = cache.sources()
    if not kept:
        print(f"the tile cache {cache.root} is empty")
        return 0
    total = sum(k.bytes for k in kept)
    print(
        f"the tile cache {cache.root}: {total / 1e6:.1f} MB of at most {cache.limit_bytes / 1e6:.0f} MB"
    )
    for k in kept:
        doc = k.identity.endswith("|capabilities")
        count = f"{k.tiles} tile{'s' if k.tiles != 1 else ''}" if k.identity and not doc else ""
        print(f"  {k.bytes / 1e6:8.1f} MB  {count:>12}  {_describe(k)}")
    return 0


def _clear(cache: TileCache, what: str) -> int:
    kept = cache.sources()
    if not what:
        freed = cache.clear()
        print(f"cleared the tile cache {cache.root}: {freed / 1e6:.1f} MB freed")
        return 0
    names = {t["name"] for t in world_tables()}
    if what in names:
        world = choose_world(what)
        wanted = [s.identity for s in (world.imagery, world.terrain) if s is not None]
        chosen = [k for k in kept if k.identity and any(k.identity.startswith(w) for w in wanted)]
        if world.buildings is not None:
            chosen += [k for k in kept if world.buildings.kept(k.identity)]
    else:
        chosen = [k for k in kept if k.identity and what in k.identity]
    if not chosen:
        raise GeofuseError(
            f"--clear {what}: no source in the cache matches (geofuse cache lists them)"
        )
    freed = cache.clear([k.folder for k in chosen])
    for k in chosen:
        print(f"removed {_describe(k)} ({k.bytes / 1e6:.1f} MB)")
    print(f"{freed / 1e6:.1f} MB freed")
    return 0
