"""The world around a clip (issue 48, first slice): imagery and terrain tiles served by a local
HTTP server from a known synthetic world, mosaicked and draped by the DEM path; the cache, the
key, the faults, MBTiles, and the settings file's [[world]] tables. No test reaches the
internet: the settings folder, the tile cache and GEOFUSE_WORLD are the test's own."""

from __future__ import annotations

import io
import math
import sqlite3
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
import rasterio
from PIL import Image

from app.cli import main
from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.geodesy import geoid
from app.geodesy.enu import LocalFrame
from app.scene.layers import load_layers
from app.world import fetch as world_fetch
from app.world import tiles as tm
from app.world.build import FETCH_WORKERS, world_scene
from app.world.cache import TileCache
from app.world.settings import World, choose_world
from app.world.sources import decode_heights, encode_heights, parse_source

LAT0, LON0 = 46.0, 7.0  # the synthetic world's centre
IMAGERY_Z, TERRAIN_Z = 16, 14  # the finest levels the test server says it has
KEY = "s3cr3t-K3y-0123456789"
GATE_LIMIT_S = 120.0  # a held request is answered after this long at most (a test that failed)


def height(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """The synthetic world's heights above EGM2008 (m): smooth hills of +-40 m around 600 m."""
    return (
        600.0
        + 40.0 * np.sin(2 * np.pi * (lon - LON0) / 0.02) * np.cos(2 * np.pi * (lat - LAT0) / 0.015)
        + 0.002 * (lon - LON0) * 111_000
    )


def _tile_lat_lon(z: int, x: int, y: int, px: int) -> tuple[np.ndarray, np.ndarray]:
    """Latitude, longitude (deg) of each pixel centre of tile (z, x, y)."""
    west, _, _, north = tm.TileRange(z, x, y, x, y).bounds_m()
    res = tm.tile_span_m(z) / px
    c = (np.arange(px) + 0.5) * res
    mx, my = np.meshgrid(west + c, north - c)
    lon = np.degrees(mx / 6378137.0)
    lat = np.degrees(2 * np.arctan(np.exp(my / 6378137.0)) - np.pi / 2)
    return lat, lon


def imagery_tile(z: int, x: int, y: int) -> np.ndarray:
    """A texel's colour is its own global column and row at its zoom (mod 256), blue its zoom."""
    cols = (x * 256 + np.arange(256)) % 256
    rows = (y * 256 + np.arange(256)) % 256
    c, r = np.meshgrid(cols, rows)
    return np.stack([c, r, np.full_like(c, 10 * z)], axis=-1).astype(np.uint8)


def terrain_tile(z: int, x: int, y: int, encoding: str = "terrain-rgb") -> np.ndarray:
    return encode_heights(height(*_tile_lat_lon(z, x, y, 256)), encoding)


def png(rgb: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "PNG")
    return buf.getvalue()


class TileServer:
    """Tiles of the synthetic world on the loopback: /img/{z}/{x}/{y}.png, /dem/{z}/{x}/{y}.png.
    faults: path -> '404', '403', 'corrupt', '429once', '429', 'slow'; need_key: every request
    must carry ?key=KEY and X-Key: KEY (else 403); log: (path, had the key, time); gate: an
    Event every request waits for (at most GATE_LIMIT_S) before it is answered; delay_s: added
    to every request (a network's round trip, for benchmarks)."""

    def __init__(self) -> None:
        self.faults: dict[str, str] = {}
        self.need_key = False
        self.gate: threading.Event | None = None
        self.delay_s = 0.0
        self.log: list[tuple[str, bool, float]] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                path, _, query = self.path.partition("?")
                keyed = f"key={KEY}" in query and self.headers.get("X-Key") == KEY
                server.log.append((path, keyed, time.monotonic()))
                if server.gate is not None:
                    server.gate.wait(GATE_LIMIT_S)
                if server.delay_s:
                    time.sleep(server.delay_s)
                fault = server.faults.get(path)
                if (server.need_key and not keyed) or fault == "403":
                    return self._send(403, b"forbidden")
                if fault == "404":
                    return self._send(404, b"no tile")
                if fault in ("429", "429once"):
                    if fault == "429once":
                        server.faults.pop(path)
                    return self._send(429, b"slow down", {"Retry-After": "1"})
                if fault == "slow":
                    time.sleep(1.0)
                kind, z, x, y = path.strip("/").removesuffix(".png").split("/")
                z, x, y = int(z), int(x), int(y)
                if z > (IMAGERY_Z if kind == "img" else TERRAIN_Z):
                    return self._send(404, b"no tile")
                body = (
                    b"\x89PNG garbage"
                    if fault == "corrupt"
                    else png(imagery_tile(z, x, y) if kind == "img" else terrain_tile(z, x, y))
                )
                self._send(200, body, {"Cache-Control": "max-age=3600", "ETag": f'"{path}"'})

            def _send(self, code: int, body: bytes, headers: dict | None = None) -> None:
                self.send_response(code)
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                try:
                    self.wfile.write(body)
                except (BrokenPipeError, ConnectionResetError):
                    pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.base = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(autouse=True)
def _own_folders(tmp_path, monkeypatch):
    """Every test's settings and tile cache in its tmp_path; no default world."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    monkeypatch.setenv("GEOFUSE_TILE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("GEOFUSE_WORLD", "none")


@pytest.fixture
def server():
    s = TileServer()
    yield s
    s.stop()


def _world(server: TileServer, keyed: bool = False, **kw) -> World:
    q = "?key={key}" if keyed else ""
    common = {"key": KEY if keyed else None, "headers": {"X-Key": "{key}"} if keyed else {}}
    return World(
        "test",
        parse_source(
            f"{server.base}/img/{{z}}/{{x}}/{{y}}.png{q}",
            "imagery",
            attribution="(c) Test imagery",
            max_zoom=IMAGERY_Z,
            **common,
        ),
        parse_source(
            f"terrain-rgb:{server.base}/dem/{{z}}/{{x}}/{{y}}.png{q}",
            "terrain",
            max_zoom=TERRAIN_Z,
            **common,
        ),
        "(c) Test imagery, test heights",
        timeout_s=kw.get("timeout_s", 60.0),
    )


TRACK = np.array([[LAT0, LON0], [LAT0 + 0.001, LON0 + 0.0015]])


def _area(reach_m: float) -> tuple[float, float, float, float]:
    """The map area (EPSG:3857 m) a build over TRACK with this reach fetches."""
    x, y = tm.to_mercator(TRACK[:, 0], TRACK[:, 1])
    grow = reach_m / math.cos(math.radians(float(TRACK[:, 0].mean())))
    return (x.min() - grow, y.min() - grow, x.max() + grow, y.max() + grow)


def _build(world: World, cache_dir: Path, **kw) -> tuple[tuple, Messages]:
    notes = Messages()
    layers = world_scene(
        world, TRACK[:, 0], TRACK[:, 1], 600.0, kw.get("reach", 300.0), 100.0, notes,
        cache=TileCache(cache_dir),
    )  # fmt: skip
    return layers, notes


def _surface(mesh, frame: LocalFrame, lat: np.ndarray, lon: np.ndarray):
    """(ENU z, (u, v)) of the terrain under each (lat, lon), by barycentric interpolation."""
    (prim,) = [p for p in mesh.primitives if p.texture is not None or p.name.startswith("terrain")]
    p = prim.positions.astype(np.float64)
    tri = prim.indices.astype(np.int64).reshape(-1, 3)
    q = frame.geodetic_to_enu(lat, lon, np.zeros(len(lat)))[:, :2]
    zs, uvs = [], []
    a, b, c = p[tri[:, 0], :2], p[tri[:, 1], :2], p[tri[:, 2], :2]
    for pt in q:
        den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
        w0 = (
            (b[:, 1] - c[:, 1]) * (pt[0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (pt[1] - c[:, 1])
        ) / den
        w1 = (
            (c[:, 1] - a[:, 1]) * (pt[0] - c[:, 0]) + (a[:, 0] - c[:, 0]) * (pt[1] - c[:, 1])
        ) / den
        w2 = 1 - w0 - w1
        i = int(np.flatnonzero((w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9))[0])
        w = np.array([w0[i], w1[i], w2[i]])
        zs.append(float(w @ p[tri[i], 2]))
        if prim.uvs is not None:
            uvs.append(w @ prim.uvs[tri[i]].astype(np.float64))
    return np.array(zs), np.array(uvs), prim


def _points(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(4)
    return LAT0 + rng.uniform(-0.001, 0.002, n), LON0 + rng.uniform(-0.001, 0.0025, n)


def test_decoders_invert_the_published_formulas():
    h = np.array([[-412.3, 0.0, 8848.8]])
    for enc, tol in (("terrain-rgb", 0.05), ("terrarium", 1 / 512)):
        assert np.allclose(decode_heights(encode_heights(h, enc), enc), h, atol=tol)
    # Mapbox: -10000 + (R * 65536 + G * 256 + B) * 0.1; Terrarium: R * 256 + G + B / 256 - 32768
    assert decode_heights(np.array([[[1, 134, 160]]], np.uint8), "terrain-rgb")[
        0, 0
    ] == pytest.approx(0.0)
    assert decode_heights(np.array([[[128, 0, 128]]], np.uint8), "terrarium")[0, 0] == 0.5


def test_imagery_lands_where_its_georeference_says_and_heights_match(server, tmp_path):
    layers, notes = _build(_world(server), tmp_path / "cache")
    (layer,) = layers
    assert layer.kind == "dem" and layer.ortho is not None and layer.vertical == "egm2008"
    frame = LocalFrame(LAT0, LON0, 600.0)
    loaded = load_layers(layers, frame, TRACK)
    lat, lon = _points()
    z, uv, prim = _surface(loaded.mesh, frame, lat, lon)
    # heights: the source's, above EGM2008 (~50 m of geoid here), within the mesh's bound
    # (0.5 m), the tiles' 0.1 m steps and their resampling
    truth = geoid.to_ellipsoidal(height(lat, lon), lat, lon, "egm2008")
    got = frame.enu_to_geodetic(
        np.column_stack([frame.geodetic_to_enu(lat, lon, np.zeros(len(lat)))[:, :2], z])
    )[:, 2]
    assert np.abs(got - truth).max() < 0.8
    assert np.abs(truth - height(lat, lon)).min() > 40  # the datum's shift was applied
    # imagery: the texel drawn at each point is the one whose square holds it at its zoom
    tex = prim.texture[::-1]  # top row first
    hgt, wid = tex.shape[:2]
    col = np.clip((uv[:, 0] * wid).astype(int), 0, wid - 1)
    row = np.clip(((1 - uv[:, 1]) * hgt).astype(int), 0, hgt - 1)
    drawn = tex[row, col, :3].astype(int)
    x, y = tm.to_mercator(lat, lon)
    res = tm.tile_span_m(IMAGERY_Z) / 256
    want_c = np.floor((x + tm.HALF_WORLD_M) / res).astype(int) % 256
    want_r = np.floor((tm.HALF_WORLD_M - y) / res).astype(int) % 256
    assert (drawn[:, 2] == 10 * IMAGERY_Z).all()
    dc = (drawn[:, 0] - want_c + 128) % 256 - 128
    dr = (drawn[:, 1] - want_r + 128) % 256 - 128
    assert np.abs(dc).max() <= 1 and np.abs(dr).max() <= 1, (dc, dr)
    with rasterio.open(layer.ortho) as src:
        assert src.tags()["ATTRIBUTION"] == "(c) Test imagery, test heights"
    assert any("heights taken as above EGM2008" in m for m in notes.items)


def test_a_warm_run_makes_no_request_and_the_key_is_sent_but_never_written(server, tmp_path):
    server.need_key = True
    world = _world(server, keyed=True)
    _, notes = _build(world, tmp_path / "cache")
    cold = len(server.log)
    assert cold > 0 and all(keyed for _, keyed, _ in server.log)
    layers, notes2 = _build(world, tmp_path / "cache")
    assert len(server.log) == cold  # warm: the cache answered everything
    assert layers and any("from the cache" in m for m in notes2.items)
    for f in tmp_path.rglob("*"):
        if f.is_file():
            assert KEY.encode() not in f.read_bytes(), f
    assert not any(KEY in m for m in notes.items + notes2.items)


def test_a_wrong_key_is_said_without_the_key_and_the_flat_ground_kept(server, tmp_path):
    server.need_key = True
    world = _world(server, keyed=True)
    wrong = "wr0ng-" + KEY
    world = World(
        world.name,
        parse_source(
            world.imagery.location, "imagery", key=wrong, headers={"X-Key": "{key}"}, max_zoom=18
        ),
        None,
    )
    layers, notes = _build(world, tmp_path / "cache")
    assert layers == ()
    text = "\n".join(notes.items)
    assert "401/403" in text and "flat ground" in text
    assert wrong not in text and KEY not in text
    # given up at the first refusal: only the requests already under way were made
    assert len(server.log) <= FETCH_WORKERS < tm.covering(_area(300.0), 18).count


def test_faults_are_said_once_each_and_survived(server, tmp_path, monkeypatch):
    monkeypatch.setattr(world_fetch, "REQUEST_TIMEOUT_S", 0.3)
    notes0 = Messages()
    world = _world(server)
    first = world_scene(
        world,
        TRACK[:, 0],
        TRACK[:, 1],
        600.0,
        300.0,
        100.0,
        notes0,
        cache=TileCache(tmp_path / "probe"),
    )
    assert first
    paths = sorted({p for p, _, _ in server.log if p.startswith("/img/16/")})
    assert len(paths) >= 5
    for path, fault in zip(paths, ("404", "corrupt", "429", "429once", "slow"), strict=False):
        server.faults[path] = fault
    once = paths[3]
    server.log.clear()
    layers, notes = _build(world, tmp_path / "cache")
    assert layers  # survived: a scene all the same
    text = "\n".join(notes.items)
    for said in ("missing (404", "not a readable image", "too many requests (429)", "timed out"):
        assert said in text, text
    assert text.count("world test imagery (") == 1  # one message for the source
    assert "drawn from a coarser level" in text
    times = [t for p, _, t in server.log if p == once]
    assert len(times) == 2 and times[1] - times[0] >= 0.9  # Retry-After: 1 honoured


def test_mbtiles_open_with_the_server_stopped(tmp_path):
    path = tmp_path / "world.mbtiles"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE metadata (name text, value text)")
    db.execute("CREATE TABLE tiles (zoom_level int, tile_column int, tile_row int, tile_data blob)")
    area = _area(600.0)
    for z in range(12, IMAGERY_Z + 1):
        for _, tx, ty in tm.covering(area, z).tiles():
            db.execute(
                "INSERT INTO tiles VALUES (?, ?, ?, ?)",
                (z, tx, (1 << z) - 1 - ty, png(imagery_tile(z, tx, ty))),
            )
    db.commit()
    db.close()
    world = World(
        "offline", parse_source(str(path), "imagery", max_zoom=IMAGERY_Z), None, "(c) Test"
    )
    layers, notes = _build(world, tmp_path / "cache")
    (layer,) = layers
    assert "flat" in Path(layer.location).name and layer.vertical == "ellipsoid"
    frame = LocalFrame(LAT0, LON0, 600.0)
    z, uv, prim = _surface(load_layers(layers, frame, TRACK).mesh, frame, *_points(4))
    assert np.allclose(z, 0.0, atol=0.05)  # the assumed flat ground, at 600 m
    assert (prim.texture[..., 2] == 10 * IMAGERY_Z).mean() > 0.9


SETTINGS = """
[[world]]
name = "local"
imagery = "{base}/img/{{z}}/{{x}}/{{y}}.png"
terrain = "terrain-rgb:{base}/dem/{{z}}/{{x}}/{{y}}.png"
attribution = "(c) Test world"
imagery_max_zoom = 16
terrain_max_zoom = 14

[[world]]
name = "other"
imagery = "https://example.invalid/{{z}}/{{x}}/{{y}}.png?key={{key}}"
key_env = "GEOFUSE_TEST_KEY"
"""


def _settings(tmp_path: Path, base: str) -> None:
    folder = tmp_path / "config" / "geofuse"
    folder.mkdir(parents=True)
    (folder / "settings.toml").write_text(SETTINGS.format(base=base))


def test_settings_name_worlds_and_a_missing_name_lists_them(tmp_path, monkeypatch):
    _settings(tmp_path, "http://127.0.0.1:9")
    monkeypatch.setenv("GEOFUSE_TEST_KEY", KEY)
    assert choose_world("local").terrain.encoding == "terrain-rgb"
    assert choose_world("other").imagery.key == KEY
    assert KEY not in repr(choose_world("other"))
    assert choose_world("none") is None
    assert choose_world() is None  # GEOFUSE_WORLD=none, as every test has it
    monkeypatch.delenv("GEOFUSE_WORLD")
    assert choose_world().name == "local"  # the first, with no --world
    assert choose_world(scene_named=True) is None
    with pytest.raises(
        GeofuseError, match=r"--world nowhere: no such world .*configured: local, other, or none"
    ):
        choose_world("nowhere")
    monkeypatch.delenv("GEOFUSE_TEST_KEY")
    assert choose_world("local").name == "local"  # another world's key is not needed
    with pytest.raises(GeofuseError, match="GEOFUSE_TEST_KEY"):
        choose_world("other")
    with pytest.raises(GeofuseError, match="encoding"):
        choose_world(terrain="https://x/{z}/{x}/{y}.png")


def write_drone_clip(folder: Path, seconds: int = 4, size: tuple[int, int] = (96, 54)) -> Path:
    """A DJI clip of `seconds` s over the synthetic world (from its centre, 0.0002 deg north and
    0.0003 deg east a second), heights above take-off (its subtitle); returns the video."""
    from app.simulate.phone import write_video

    folder.mkdir(parents=True, exist_ok=True)
    video = write_video(folder / "DJI_0001.MP4", np.arange(30 * seconds) / 30.0, size, 0)

    def stamp(s: int) -> str:
        return f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d},000"

    entries = []
    for i in range(seconds):
        lat, lon = LAT0 + 0.0002 * i, LON0 + 0.0003 * i
        entries.append(
            f"{i + 1}\n{stamp(i)} --> {stamp(i + 1)}\n"
            f"F/5.6, SS 400, ISO 100, EV 0, GPS ({lon:.6f}, {lat:.6f}, 15), HOME ({LON0:.6f}, {LAT0:.6f}, 0.00m), "
            f"D 0.00m, H 80.00m, H.S 0.00m/s, V.S 0.00m/s, F.PRY (0.0°, 0.0°, 45.0°), G.PRY (-60.0°, 0.0°, 45.0°)"
        )
    (folder / "DJI_0001.SRT").write_text("\n\n".join(entries) + "\n", encoding="utf-8")
    return video


@pytest.fixture
def drone_clip(tmp_path):
    """A 4 s DJI clip over the synthetic world, heights above take-off (its subtitle)."""
    return write_drone_clip(tmp_path / "clip")


def test_a_clip_is_draped_on_the_world_and_none_keeps_the_flat_ground(
    server, tmp_path, drone_clip, capsys
):
    _settings(tmp_path, server.base)
    out = tmp_path / "poses.csv"
    assert main(["solve", str(drone_clip), "--out", str(out)]) == 0  # GEOFUSE_WORLD=none
    err = capsys.readouterr().err
    assert "assumed flat ground" in err and "[[world]]" in err and not server.log
    assert main(["solve", str(drone_clip), "--out", str(out), "--world", "local"]) == 0
    err = capsys.readouterr().err
    assert "world local imagery" in err and "world local terrain" in err
    assert "take-off height" in err and "assumed flat ground" not in err
    assert main(["solve", str(drone_clip), "--out", str(out), "--world", "gone"]) == 2
    assert "configured: local, other, or none" in capsys.readouterr().err
