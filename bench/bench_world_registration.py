"""Registration against a world from tiles (issue 48): simulated sessions registered against
the sample site's textured mesh, against a world built from that mesh served as tiles over the
loopback, and the GNSS prior alone; camera error against the truth.

    python bench/bench_world_registration.py [--flights orbit survey] [--seeds 1]
        [--duration 20] [--mpp 0.3 1] [--terrain terrain-rgb quantized-mesh]
        [--buildings 3dtiles osm none] [--json F]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from its model; the manifest names the model). The model is then served
as tiles on the loopback (tests.test_world_sources' Server, a real HTTP server in process):
imagery as XYZ PNG tiles resampled from a top-down rendering of the model (a pinhole camera
FAR_ABOVE_PER_M times its footprint's width above it, so near-orthographic, north up, at
RENDER_CELL_M a pixel), at the Web Mercator zoom whose pixel at the site is closest to each
--mpp (metres a pixel; the world's imagery_max_zoom); terrain from the model's ground (the
lowest surface under each point, app.scene.ground.ground_heights, on a HEIGHT_CELL_M grid,
ellipsoidal heights) as Terrain-RGB PNG tiles and as quantized-mesh (tests.test_world_quantized's
encoder, geodetic tiles, a layer.json); buildings (--buildings 3dtiles) as a 3D Tiles 1.0
tileset (every primitive of the model but its ground, one b3dm each, textures kept), a
[[layers]] path over HTTP; --buildings osm: the model's buildings as OpenStreetMap footprints
with a height tag, their corners a little off (osm_buildings: LoD1, untextured, what a real
tile world mostly has), a local .osm [[layers]] path; --buildings none: imagery and terrain
alone. Each variant is a copy
of the manifest with [scene] replaced by [origin] (the scene's origin, so the truth's frame is
the same) and a [world] table naming the loopback sources, its own tile cache.

Each session is solved with the `registered` source (app.solve.track.solve_track) against the
mesh (the baseline), against each tile world, and with the `offline` source (the GNSS prior
alone). Figures: camera position error against the truth (app.solve.accuracy.true_track),
median and p95 over every frame (m), attitude error median (deg), keyframes used / tried (and
why the others were not, their figures dropped), the ratio of the median position error to the
mesh's (goal: within 1.5), and the wall time of opening and solving (s).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import re
import sys
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.pinhole import looking_down  # noqa: E402
from app.geodesy import rotations  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.render.views import ModelViews  # noqa: E402
from app.scene.ground import ground_heights  # noqa: E402
from app.scene.mesh import MeshData  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate import session as sample  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.simulate.stadium import BUILDINGS, HALL_MAX, HALL_MIN  # noqa: E402
from app.simulate.tileset import b3dm, glb, region_of  # noqa: E402
from app.solve.accuracy import true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from app.world.sources import encode_heights  # noqa: E402
from app.world.tiles import pixel_m  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402
from tests.test_world import _tile_lat_lon  # noqa: E402
from tests.test_world_quantized import encode_tile, layer_json  # noqa: E402
from tests.test_world_sources import Server  # noqa: E402

RENDER_CELL_M = 0.15  # the top-down rendering's pixel, m (finer than the finest imagery served)
RENDER_TILE_PX = 2048  # rendered in pieces of at most this many pixels a side
FAR_ABOVE_PER_M = 40.0  # the top-down camera stands this many times its piece's width high
HEIGHT_CELL_M = 4.0  # the ground heights' grid, m
AREA_MARGIN_M = 400.0  # the area served reaches this far beyond the track (within the model)
QM_MAX_ZOOM = 17  # the finest quantized-mesh level served (geodetic tiles: ~1.3 m a vertex)
TERRAIN_RGB_MAX_ZOOM = 17
BUILDINGS_SAID = {"3dtiles": ", 3D Tiles buildings", "osm": ", OSM LoD1 buildings", "none": ""}
OSM_CORNER_SD_M = 0.7  # an OpenStreetMap footprint's corners lie this far off (sd, m: traced)


class SiteRaster:
    """The model seen from straight above (RGB) and its ground heights, north up, over an ENU
    box (west, south, east, north m), in the session's frame."""

    def __init__(self, mesh: MeshData, frame: LocalFrame, box: tuple[float, float, float, float]):
        self.frame, self.box = frame, box
        west, south, east, north = box
        self.rgb = _top_down(mesh, box, RENDER_CELL_M)
        xs = np.arange(west, east + HEIGHT_CELL_M, HEIGHT_CELL_M)
        ys = np.arange(north, south - HEIGHT_CELL_M, -HEIGHT_CELL_M)
        gx, gy = np.meshgrid(xs, ys)
        z = ground_heights(mesh, np.column_stack([gx.ravel(), gy.ravel()])).reshape(gx.shape)
        fill = float(np.nanmedian(z)) if np.isfinite(z).any() else 0.0
        self.z = np.where(np.isfinite(z), z, fill).astype(np.float32)
        self.base_h = float(frame.enu_to_geodetic(np.zeros(3))[2])

    def _enu(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        return self.frame.geodetic_to_enu(lat, lon, np.full_like(lat, self.base_h))

    def imagery(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB at each (lat, lon) deg (grey outside the box)."""
        e = self._enu(lat, lon)
        west, _, _, north = self.box
        mx = ((e[..., 0] - west) / RENDER_CELL_M - 0.5).astype(np.float32)
        my = ((north - e[..., 1]) / RENDER_CELL_M - 0.5).astype(np.float32)
        return cv2.remap(
            self.rgb, mx, my, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT, borderValue=(128, 128, 128),
        )  # fmt: skip

    def heights(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        """Ellipsoidal heights (m) of the model's ground at each (lat, lon) deg (the nearest
        edge's beyond the box)."""
        lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
        e = self._enu(lat, lon)
        west, _, _, north = self.box
        mx = ((e[..., 0] - west) / HEIGHT_CELL_M).astype(np.float32)
        my = ((north - e[..., 1]) / HEIGHT_CELL_M).astype(np.float32)
        z = cv2.remap(self.z, np.atleast_2d(mx), np.atleast_2d(my), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE).reshape(lat.shape)  # fmt: skip
        e = e.copy()
        e[..., 2] = z
        return self.frame.enu_to_geodetic(e)[..., 2]


def _top_down(mesh: MeshData, box: tuple[float, float, float, float], cell: float) -> np.ndarray:
    """(H, W, 3) uint8: the mesh from straight above over box (ENU m), `cell` m a pixel."""
    west, south, east, north = box
    w, h = int(round((east - west) / cell)), int(round((north - south) / cell))
    out = np.full((h, w, 3), 128, np.uint8)
    lo, hi = mesh.bounds()
    views = ModelViews(mesh)
    try:
        for r0 in range(0, h, RENDER_TILE_PX):
            for c0 in range(0, w, RENDER_TILE_PX):
                pw, ph = min(RENDER_TILE_PX, w - c0), min(RENDER_TILE_PX, h - r0)
                centre = (west + (c0 + pw / 2) * cell, north - (r0 + ph / 2) * cell)
                above = FAR_ABOVE_PER_M * max(pw, ph) * cell
                # `cell` m a pixel on the ground (the model's lowest)
                cam = looking_down((pw, ph), centre, cell, lo[2], (lo[2], hi[2]), above)
                rgb, _ = views.render(cam)
                out[r0 : r0 + ph, c0 : c0 + pw] = rgb
    finally:
        views.release()
    return out


def _png(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "PNG")
    return buf.getvalue()


def serve(raster: SiteRaster) -> Server:
    """The loopback server: /img/{z}/{x}/{y}.png, /dem/{z}/{x}/{y}.png (Terrain-RGB),
    /qm/layer.json and /qm/{z}/{x}/{y}.terrain (quantized-mesh, geodetic TMS)."""
    server = Server()
    ok = {"Cache-Control": "max-age=3600"}

    def img(path: str, q: dict):
        z, x, y = (int(v) for v in re.findall(r"\d+", path)[:3])
        return 200, _png(raster.imagery(*_tile_lat_lon(z, x, y, 256))), ok

    def dem(path: str, q: dict):
        z, x, y = (int(v) for v in re.findall(r"\d+", path)[:3])
        if z > TERRAIN_RGB_MAX_ZOOM:
            return 404, b"no tile", {}
        h = raster.heights(*_tile_lat_lon(z, x, y, 256))
        return 200, _png(encode_heights(h, "terrain-rgb")), ok

    available = [
        [{"startX": 0, "startY": 0, "endX": (2 << z) - 1, "endY": (1 << z) - 1}]
        for z in range(QM_MAX_ZOOM + 1)
    ]
    doc = layer_json(maxzoom=QM_MAX_ZOOM, available=available)

    def qm(path: str, q: dict):
        if path.endswith("layer.json"):
            return 200, doc, {"Content-Type": "application/json"}
        z, x, y = (int(v) for v in re.findall(r"\d+", path)[:3])
        if z > QM_MAX_ZOOM:
            return 404, b"no tile", {}
        data, _ = encode_tile(z, x, y, heights=raster.heights)
        return 200, data, ok | {"Content-Type": "application/vnd.quantized-mesh"}

    server.routes |= {"/img/": img, "/dem/": dem, "/qm/": qm}
    return server


def buildings_tileset(
    mesh: MeshData, frame: LocalFrame, ground: str = "ground"
) -> dict[str, bytes]:
    """The model's buildings (every primitive but the one named `ground`) as a 3D Tiles 1.0
    tileset: file name -> bytes (tileset.json, one b3dm a primitive, its vertices in ECEF
    relative to RTC_CENTER, its texture and colour kept), ADD refinement under one root."""
    files, children = {}, []
    lo_all, hi_all = np.full(3, np.inf), np.full(3, -np.inf)
    for i, prim in enumerate(p for p in mesh.primitives if p.name != ground):
        v = prim.positions.astype(np.float64)
        lo, hi = v.min(0), v.max(0)
        lo_all, hi_all = np.minimum(lo_all, lo), np.maximum(hi_all, hi)
        rtc = frame.enu_to_ecef(np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0]))
        local = frame.enu_to_ecef(v) - rtc
        tex = None if prim.texture is None else np.ascontiguousarray(prim.texture[::-1, :, :3])
        uvs = None if prim.uvs is None else np.column_stack([prim.uvs[:, 0], 1.0 - prim.uvs[:, 1]])
        color = tuple(float(c) for c in prim.colors[0])
        name = f"b{i}.b3dm"
        files[name] = b3dm(glb(local, prim.indices, color, uvs, tex), rtc)
        children.append({
            "boundingVolume": {"region": region_of(frame, lo - [0, 0, 1], hi + [0, 0, 1])},
            "geometricError": 0.0, "content": {"uri": name},
        })  # fmt: skip
    doc = {
        "asset": {"version": "1.0"},
        "geometricError": 100.0,
        "root": {
            "boundingVolume": {"region": region_of(frame, lo_all - [0, 0, 1], hi_all + [0, 0, 1])},
            "geometricError": 50.0, "refine": "ADD", "children": children,
        },
    }  # fmt: skip
    files["tileset.json"] = json.dumps(doc).encode()
    return files


def osm_buildings(frame: LocalFrame, seed: int) -> bytes:
    """The sample site's buildings as OpenStreetMap XML, as a mapper would have traced them: the
    hall and app.simulate.stadium.BUILDINGS (the model's boxes, ENU m of `frame`), each a closed
    way tagged building=yes with its height to the metre, every corner moved by a normal
    OSM_CORNER_SD_M (m) east and north (seeded): LoD1, untextured, a little off."""
    rng = np.random.default_rng(seed)
    boxes = [(HALL_MIN, HALL_MAX)] + [(b.min_corner, b.max_corner) for b in BUILDINGS]
    nodes, ways = [], []
    for w, (lo, hi) in enumerate(boxes, start=1):
        corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        corners = corners + rng.normal(0.0, OSM_CORNER_SD_M, corners.shape)
        lat_lon = frame.enu_to_geodetic(np.column_stack([corners, np.zeros(4)]))[:, :2]
        ids = [10 * w + i for i in range(4)]
        nodes += [
            f'  <node id="{i}" lat="{la:.8f}" lon="{lo_:.8f}"/>' for i, (la, lo_) in zip(ids, lat_lon, strict=True)
        ]  # fmt: skip
        refs = "".join(f'<nd ref="{i}"/>' for i in [*ids, ids[0]])
        ways.append(
            f'  <way id="{w}">{refs}<tag k="building" v="yes"/>'
            f'<tag k="height" v="{round(hi[2] - lo[2]):d}"/></way>'
        )
    return "\n".join(['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6">', *nodes, *ways, "</osm>\n"]).encode()  # fmt: skip


def zoom_for(mpp: float, lat_deg: float) -> int:
    """The Web Mercator zoom whose pixel at lat_deg is closest to mpp metres (in log)."""
    return int(round(math.log2(pixel_m(0, 256, lat_deg) / mpp)))


def world_manifest(
    base: Path, name: str, origin: np.ndarray, world: dict, buildings: str | None = None
) -> Path:
    """A copy of the manifest base (session.toml) named name.toml beside it: [scene] replaced
    by [origin] (lat, lon deg, h ellipsoidal m), the [world] table `world` and, given a
    tileset.json URL, a [[layers]] table of it."""
    text = base.read_text()
    text = re.sub(r"\[scene\]\n(?:[^\[\n][^\n]*\n|\n)*", "", text)
    lines = [
        f"[origin]\nlat = {float(origin[0])!r}\nlon = {float(origin[1])!r}\nh = {float(origin[2])!r}\n",
        "[world]",
    ]
    lines += [f"{k} = {json.dumps(v)}" for k, v in world.items()]
    if buildings is not None:
        lines += ["", "[[layers]]", f"path = {json.dumps(buildings)}"]
    out = base.parent / f"{name}.toml"
    out.write_text(text + "\n" + "\n".join(lines) + "\n")
    return out


def measure(manifest: Path, source: str, cache: Path) -> dict:
    """Solve the session with `source`; its camera's error against the truth over every frame."""
    os.environ["GEOFUSE_TILE_CACHE"] = str(cache)
    t0 = time.perf_counter()
    session = open_session(manifest)
    track = solve_track(session, source)
    wall = time.perf_counter() - t0
    truth = true_track(session)
    frames = np.arange(track.frame_count)
    ours = track.poses_at(track.clock.media_s[frames], frames)
    true = truth.poses_at(truth.clock.media_s[frames])
    pos = np.linalg.norm(ours.enu - true.enu, axis=1)
    att = np.degrees(rotations.angle_between(ours.q, true.q))
    reg = track.registration
    keys = reg.keyframes if reg is not None else ()
    return {
        "pos_median_m": float(np.median(pos)),
        "pos_p95_m": float(np.percentile(pos, 95)),
        "att_median_deg": float(np.median(att)),
        "att_p95_deg": float(np.percentile(att, 95)),
        "keyframes_used": int(sum(bool(k.used) for k in keys)),
        "keyframes": len(keys),
        "registered": int(sum(k.registered for k in keys)),
        "matches_median": float(np.median([k.matches for k in keys])) if keys else 0.0,
        "why_not": dict(Counter(_why(k.reason) for k in keys if not k.used)),
        "seconds": wall,
        "layers": [p.name for p in session.mesh.primitives]
        + [f"{len(session.mesh.tilesets)} tileset(s)"],
        "notes": [str(m) for m in session.messages.since(0)][-6:],
    }


def _why(reason: str) -> str:
    """A keyframe's reason, its figures dropped (so that alike reasons count together)."""
    return re.sub(r"[-+]?\d[\d.]*", "#", reason)[:90]


def run_session(folder: Path, flight: str, seed: int, args: argparse.Namespace) -> list[dict]:
    config = replace(sample.quick_config(args.duration), flight=flight, seed=seed)
    t0 = time.perf_counter()
    sample.write_sample_session(folder, SAMPLE_SCENE, config)
    print(f"# {flight} seed {seed}: simulated in {time.perf_counter() - t0:.0f} s", flush=True)
    base = folder / "session.toml"
    rows = []

    def row(name: str, got: dict) -> None:
        got = {"flight": flight, "seed": seed, "scene": name} | got
        rows.append(got)
        print(
            f"{flight} seed {seed} {name}: position {got['pos_median_m']:.2f} / {got['pos_p95_m']:.2f} m, "
            f"attitude {got['att_median_deg']:.2f} deg, keyframes {got['keyframes_used']}/{got['keyframes']}, "
            f"{got['seconds']:.0f} s; layers {got['layers']}; not used: {got['why_not']}",
            flush=True,
        )

    row("textured mesh (baseline)", measure(base, "registered", folder / "cache-mesh"))
    session = open_session(base)
    origin = session.frame.enu_to_geodetic(np.zeros(3))
    truth = true_track(session)
    p = truth.poses_at(truth.clock.media_s[np.arange(len(session.frame_times))]).enu
    lo, hi = session.mesh.bounds()
    box = (
        max(lo[0], p[:, 0].min() - AREA_MARGIN_M), max(lo[1], p[:, 1].min() - AREA_MARGIN_M),
        min(hi[0], p[:, 0].max() + AREA_MARGIN_M), min(hi[1], p[:, 1].max() + AREA_MARGIN_M),
    )  # fmt: skip
    t0 = time.perf_counter()
    raster = SiteRaster(session.mesh, session.frame, box)
    print(
        f"# site rendered top-down over {box[2] - box[0]:.0f} x {box[3] - box[1]:.0f} m "
        f"({raster.rgb.shape[1]} x {raster.rgb.shape[0]} px) and its ground sampled in "
        f"{time.perf_counter() - t0:.0f} s",
        flush=True,
    )
    server = serve(raster)
    server.files |= {
        f"/3d/{k}": v for k, v in buildings_tileset(session.mesh, session.frame).items()
    }
    osm = folder / "buildings.osm"
    osm.write_bytes(osm_buildings(session.frame, seed))
    buildings = {"3dtiles": f"{server.base}/3d/tileset.json", "osm": str(osm), "none": None}
    try:
        for mpp in args.mpp:
            z = zoom_for(mpp, float(origin[0]))
            px = pixel_m(z, 256, float(origin[0]))
            for terrain, tiles3d in [(t, b) for t in args.terrain for b in args.buildings]:
                url = (
                    f"terrain-rgb:{server.base}/dem/{{z}}/{{x}}/{{y}}.png"
                    if terrain == "terrain-rgb"
                    else f"{server.base}/qm/layer.json"
                )
                world = {
                    "name": "tiles", "imagery": f"{server.base}/img/{{z}}/{{x}}/{{y}}.png",
                    "terrain": url, "datum": "ellipsoid", "imagery_max_zoom": z,
                    "attribution": "bench: the sample model as tiles",
                }  # fmt: skip
                if terrain == "terrain-rgb":
                    world["terrain_max_zoom"] = TERRAIN_RGB_MAX_ZOOM
                name = f"world-z{z}-{terrain}-{tiles3d}"
                manifest = world_manifest(base, name, origin, world, buildings[tiles3d])
                label = f"tiles z{z} ({px:.2f} m/px), {terrain}{BUILDINGS_SAID[tiles3d]}"
                try:
                    row(label, measure(manifest, "registered", folder / f"cache-{name}"))
                except Exception as exc:  # noqa: BLE001 (the bench reports and goes on)
                    print(f"{flight} seed {seed} {label}: FAILED {type(exc).__name__}: {exc}")
                    rows.append(
                        {"flight": flight, "seed": seed, "scene": label, "error": repr(exc)}
                    )
        row("GNSS prior alone (offline)", measure(base, "offline", folder / "cache-mesh"))
    finally:
        server.stop()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--mpp", nargs="+", type=float, default=[0.3, 1.0])
    parser.add_argument(
        "--terrain", nargs="+", default=["terrain-rgb", "quantized-mesh"],
        choices=["terrain-rgb", "quantized-mesh"],
    )  # fmt: skip
    parser.add_argument(
        "--buildings", nargs="+", default=["3dtiles", "none"], choices=list(BUILDINGS_SAID),
        help="the tile worlds with the model's buildings as 3D Tiles, as OpenStreetMap LoD1"
        " footprints (osm_buildings), without, or some of them",
    )  # fmt: skip
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    print(f"# {machine()}, load {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="bench-world-reg-") as tmp:
        for flight in args.flights:
            for seed in args.seeds:
                rows += run_session(Path(tmp) / f"{flight}-{seed}", flight, seed, args)
    print(f"# load after {' '.join(f'{x:.1f}' for x in os.getloadavg())}\n")
    out = []
    for r in rows:
        if "error" in r:
            out.append([r["flight"], r["seed"], r["scene"], "failed", "", "", "", ""])
            continue
        mesh = next(
            m["pos_median_m"] for m in rows
            if m["flight"] == r["flight"] and m["seed"] == r["seed"] and m["scene"].startswith("textured")
        )  # fmt: skip
        out.append([
            r["flight"], r["seed"], r["scene"], f"{r['pos_median_m']:.2f} / {r['pos_p95_m']:.2f}",
            f"{r['att_median_deg']:.2f}", f"{r['keyframes_used']}/{r['keyframes']}",
            f"{r['pos_median_m'] / mesh:.2f}", f"{r['seconds']:.0f}",
        ])  # fmt: skip
    print(
        table(
            [
                "flight",
                "seed",
                "source scene",
                "position error median / p95 (m)",
                "attitude median (deg)",
                "keyframes used",
                "ratio to mesh median",
                "solve s",
            ],
            out,
        )  # fmt: skip
    )
    if args.json is not None:
        write_json(args.json, {"machine": machine(), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
