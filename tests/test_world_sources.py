"""The world's further sources (issue 48, second slice): OGC WMTS in a national grid, in
EPSG:4326 and in Web Mercator, KVP and REST; GeoPackage and PMTiles archives; GeoTIFF/COG over
HTTP read by range requests; a manifest's [world] table; `geofuse cache`. A loopback HTTP server
serves the synthetic world of tests/test_world.py; no test reaches the internet (the settings,
the cache and GEOFUSE_WORLD are each test's own)."""

from __future__ import annotations

import math
import re
import threading
import urllib.parse
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine
from pmtiles.tile import Compression, TileType
from pmtiles.writer import Writer as PMTilesWriter

from app.cli import main
from app.core.errors import ManifestError
from app.core.messages import Messages
from app.geodesy import geoid
from app.geodesy.enu import LocalFrame
from app.scene.ground_plane import ground_reach_m
from app.scene.layers import load_layers
from app.session import open_session
from app.session.config import read_config
from app.world import tiles as tm
from app.world.archives import write_gpkg, write_pmtiles
from app.world.build import world_scene
from app.world.cache import TileCache
from app.world.grids import Matrix, TileGrid, box_in, lonlat_box, to_lonlat
from app.world.settings import World
from app.world.sources import encode_heights, parse_source
from tests import test_world
from tests.test_world import (
    IMAGERY_Z,
    KEY,
    LAT0,
    LON0,
    TRACK,
    TileServer,
    _points,
    _surface,
    height,
    imagery_tile,
    png,
)

dji_clip = test_world.drone_clip  # a fixture: a 4 s DJI clip over the synthetic world

PIXEL_M = 0.28e-3
DEG_M = 2 * math.pi * 6378137.0 / 360.0  # metres per degree as WMTS counts them
# A national grid (Swiss LV95, EPSG:2056: our world lies in it), levels 8 m .. 0.5 m a pixel
LV95_TOP_LEFT = (2_420_000.0, 1_350_000.0)
LV95_RES = (8.0, 4.0, 2.0, 1.0, 0.5)
CRS84_LEVELS = 18  # WorldCRS84Quad levels 0..17: 2^(z+1) x 2^z tiles, 0.703125 / 2^z deg a pixel
GOOGLE_LEVELS = 17  # GoogleMapsCompatible levels 0..16


def _grid(name: str) -> TileGrid:
    """The test's tile matrix sets as TileGrids (what the capabilities document says)."""
    if name == "lv95":
        left, top = LV95_TOP_LEFT
        return TileGrid(
            "EPSG:2056",
            tuple(
                Matrix(str(i), r, left, top, 256, 256, math.ceil(480e3 / (256 * r)), math.ceil(350e3 / (256 * r)))
                for i, r in enumerate(LV95_RES)
            ),
            "lv95",
        )  # fmt: skip
    if name == "crs84":
        return TileGrid(
            "EPSG:4326",
            tuple(
                Matrix(str(z), 0.703125 / 2**z, -180.0, 90.0, 256, 256, 2 ** (z + 1), 2**z)
                for z in range(CRS84_LEVELS)
            ),
            "crs84",
        )
    half = tm.HALF_WORLD_M
    return TileGrid(
        "EPSG:3857",
        tuple(
            Matrix(str(z), 2 * half / 256 / 2**z, -half, half, 256, 256, 2**z, 2**z)
            for z in range(GOOGLE_LEVELS)
        ),
        "google",
    )


GRIDS = {n: _grid(n) for n in ("lv95", "crs84", "google")}
SET_IDS = {"lv95": "swissgrid", "crs84": "WorldCRS84Quad", "google": "GoogleMapsCompatible"}
SET_CRS = {
    "lv95": "urn:ogc:def:crs:EPSG::2056",
    "crs84": "urn:ogc:def:crs:EPSG::4326",  # latitude first: TopLeftCorner "90 -180"
    "google": "urn:ogc:def:crs:EPSG::3857",
}


def grid_imagery(level: int, col: int, row: int) -> np.ndarray:
    """A grid tile's texel colour: its global column and row at its level (mod 256), blue 10
    times its level, as tests/test_world.py's XYZ tiles."""
    c, r = np.meshgrid((col * 256 + np.arange(256)) % 256, (row * 256 + np.arange(256)) % 256)
    return np.stack([c, r, np.full_like(c, 10 * level)], axis=-1).astype(np.uint8)


def grid_terrain(grid: TileGrid, level: int, col: int, row: int) -> np.ndarray:
    """Terrain-RGB of the world's heights at each pixel centre of a grid tile."""
    m = grid.matrices[level]
    x0, _, _, y1 = m.tile_bounds(col, row)
    c = (np.arange(256) + 0.5) * m.res
    x, y = np.meshgrid(x0 + c, y1 - c)
    lon, lat = to_lonlat(grid.crs, x.ravel(), y.ravel())
    return encode_heights(height(lat, lon).reshape(256, 256), "terrain-rgb")


def capabilities(base: str, sets: tuple[str, ...], key_in_template: bool = False) -> str:
    """A WMTS 1.0.0 capabilities document: layers "ortho" (imagery) and "dem" (Terrain-RGB),
    each linked to `sets`, REST templates and KVP GetTile both offered."""
    q = f"?key={KEY}" if key_in_template else ""  # a service that writes the key back into it
    layers = "".join(
        f"""<Layer><ows:Identifier>{name}</ows:Identifier>
  <Style isDefault="true"><ows:Identifier>default</ows:Identifier></Style>
  <Format>image/png</Format>
  {"".join(f"<TileMatrixSetLink><TileMatrixSet>{SET_IDS[s]}</TileMatrixSet></TileMatrixSetLink>" for s in sets)}
  <ResourceURL format="image/png" resourceType="tile"
   template="{base}/wmts/{name}/{{Style}}/{{TileMatrixSet}}/{{TileMatrix}}/{{TileRow}}/{{TileCol}}.png{q}"/>
</Layer>"""
        for name in ("ortho", "dem")
    )
    matrix_sets = ""
    for s in sets:
        g = GRIDS[s]
        mats = ""
        for m in g.matrices:
            mpu = DEG_M if s == "crs84" else 1.0
            corner = f"{m.top} {m.left}" if s == "crs84" else f"{m.left} {m.top}"
            mats += (
                f"<TileMatrix><ows:Identifier>{m.ident}</ows:Identifier>"
                f"<ScaleDenominator>{m.res * mpu / PIXEL_M!r}</ScaleDenominator>"
                f"<TopLeftCorner>{corner}</TopLeftCorner><TileWidth>256</TileWidth>"
                f"<TileHeight>256</TileHeight><MatrixWidth>{m.cols}</MatrixWidth>"
                f"<MatrixHeight>{m.rows}</MatrixHeight></TileMatrix>"
            )
        matrix_sets += (
            f"<TileMatrixSet><ows:Identifier>{SET_IDS[s]}</ows:Identifier>"
            f"<ows:SupportedCRS>{SET_CRS[s]}</ows:SupportedCRS>{mats}</TileMatrixSet>"
        )
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<Capabilities xmlns="http://www.opengis.net/wmts/1.0" xmlns:ows="http://www.opengis.net/ows/1.1"
 xmlns:xlink="http://www.w3.org/1999/xlink" version="1.0.0">
<ows:OperationsMetadata>
 <ows:Operation name="GetCapabilities"><ows:DCP><ows:HTTP><ows:Get xlink:href="{base}/kvp?">
  <ows:Constraint name="GetEncoding"><ows:AllowedValues><ows:Value>KVP</ows:Value></ows:AllowedValues></ows:Constraint>
 </ows:Get></ows:HTTP></ows:DCP></ows:Operation>
 <ows:Operation name="GetTile"><ows:DCP><ows:HTTP><ows:Get xlink:href="{base}/kvp?">
  <ows:Constraint name="GetEncoding"><ows:AllowedValues><ows:Value>KVP</ows:Value></ows:AllowedValues></ows:Constraint>
 </ows:Get></ows:HTTP></ows:DCP></ows:Operation>
</ows:OperationsMetadata>
<Contents>{layers}{matrix_sets}</Contents>
</Capabilities>"""


class Server:
    """A loopback HTTP server: `routes` maps a path to a function of (path, query dict) giving
    (status, body, headers); files (path -> bytes) are served with Range support. log: (path,
    query, Range asked, bytes sent); need_key: requests without key=KEY in the query get 403."""

    def __init__(self) -> None:
        self.routes: dict[str, Callable] = {}
        self.files: dict[str, bytes] = {}
        self.log: list[tuple[str, dict, str | None, int]] = []
        self.need_key = False
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_HEAD(self) -> None:  # noqa: N802 (http.server's name)
                self._serve(head=True)

            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                self._serve(head=False)

            def _serve(self, head: bool) -> None:
                path, _, query = self.path.partition("?")
                q = {k.upper(): v for k, v in urllib.parse.parse_qsl(query)}
                rng = self.headers.get("Range")
                if server.need_key and q.get("KEY") != KEY:
                    return self._send(403, b"forbidden", {}, path, q, rng, head)
                if path in server.files:
                    data = server.files[path]
                    m = re.match(r"bytes=(\d+)-(\d*)", rng or "")
                    if m:
                        a = int(m.group(1))
                        b = min(int(m.group(2)) if m.group(2) else len(data) - 1, len(data) - 1)
                        part = data[a : b + 1]
                        headers = {"Content-Range": f"bytes {a}-{b}/{len(data)}"}
                        return self._send(206, part, headers, path, q, rng, head)
                    return self._send(200, data, {"Accept-Ranges": "bytes"}, path, q, rng, head)
                route = server.routes.get(path) or next(
                    (f for p, f in server.routes.items() if p.endswith("/") and path.startswith(p)),
                    None,
                )
                if route is None:
                    return self._send(404, b"none", {}, path, q, rng, head)
                code, body, headers = route(path, q)
                self._send(code, body, headers, path, q, rng, head)

            def _send(self, code, body, headers, path, q, rng, head) -> None:
                server.log.append((path, q, rng, 0 if head else len(body)))
                self.send_response(code)
                for k, v in headers.items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if not head:
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

    def sent(self, prefix: str = "") -> int:
        """Bytes sent in answer to paths starting with `prefix`."""
        return sum(n for p, _, _, n in self.log if p.startswith(prefix))


@pytest.fixture(autouse=True)
def _own_folders(tmp_path, monkeypatch):
    """Every test's settings and tile cache in its tmp_path; no default world."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    monkeypatch.setenv("GEOFUSE_TILE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("GEOFUSE_WORLD", "none")


@pytest.fixture
def server():
    s = Server()
    yield s
    s.stop()


def _wmts(server: Server, sets: tuple[str, ...], key_in_template: bool = False) -> None:
    """The WMTS routes: its capabilities (REST and KVP), REST tiles and KVP GetTile."""
    ok = {"Cache-Control": "max-age=3600"}

    def tile(layer: str, set_id: str, level: str, row: int, col: int):
        name = next(n for n, s in SET_IDS.items() if s == set_id)
        z = int(level)
        if layer == "ortho":
            return 200, png(grid_imagery(z, col, row)), ok
        return 200, png(grid_terrain(GRIDS[name], z, col, row)), ok

    def caps(path, q):
        body = capabilities(server.base, sets, key_in_template).encode()
        return 200, body, {"Content-Type": "application/xml", **ok}

    def rest(path, q):
        layer, _, set_id, level, row, col = path.removesuffix(".png").split("/")[2:]
        return tile(layer, set_id, level, int(row), int(col))

    def kvp(path, q):
        if q.get("REQUEST", "").lower() == "getcapabilities":
            return caps(path, q)
        assert q["SERVICE"] == "WMTS" and q["STYLE"] == "default" and q["FORMAT"] == "image/png"
        return tile(q["LAYER"], q["TILEMATRIXSET"], q["TILEMATRIX"], int(q["TILEROW"]), int(q["TILECOL"]))  # fmt: skip

    server.routes["/wmts/1.0.0/WMTSCapabilities.xml"] = caps
    server.routes["/wmts/"] = rest
    server.routes["/kvp"] = kvp


def _build(world: World, cache: Path, high: bool = False) -> tuple[tuple, Messages]:
    """world_scene over TRACK, 300 m around it, for a camera 100 m above the ground (imagery at
    0.3 m a pixel at most), or 1000 m (high: 1 m, terrain at 4 m)."""
    notes = Messages()
    layers = world_scene(
        world, TRACK[:, 0], TRACK[:, 1], 600.0, 300.0, 1000.0 if high else 100.0, notes,
        cache=TileCache(cache),
    )  # fmt: skip
    return layers, notes


def _sample(path: str, lat: np.ndarray, lon: np.ndarray, centres: bool = False):
    """A GeoTIFF's pixels at (lat, lon) (nearest), and its CRS as WKT; centres: and the
    (lat, lon) of those pixels' centres too."""
    with rasterio.open(path) as src:
        crs = src.crs.to_wkt()
        x, y = pyproj.Transformer.from_crs("EPSG:4326", src.crs, always_xy=True).transform(lon, lat)
        rows, cols = rasterio.transform.rowcol(src.transform, x, y)
        data = src.read()[:, np.asarray(rows), np.asarray(cols)].T
        cx, cy = rasterio.transform.xy(src.transform, rows, cols)
    if not centres:
        return data, crs
    clon, clat = pyproj.Transformer.from_crs(src.crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    return data, crs, np.asarray(clat), np.asarray(clon)


def _texels_right(rgb: np.ndarray, grid: TileGrid, lat: np.ndarray, lon: np.ndarray) -> None:
    """Each texel drawn at (lat, lon) is the grid's texel holding it at the level its blue says,
    within one texel."""
    level = int(rgb[0, 2]) // 10
    assert (rgb[:, 2] == 10 * level).all()
    m = grid.matrices[level]
    x, y = pyproj.Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True).transform(lon, lat)
    want_c = np.floor((np.asarray(x) - m.left) / m.res).astype(int) % 256
    want_r = np.floor((m.top - np.asarray(y)) / m.res).astype(int) % 256
    dc = (rgb[:, 0].astype(int) - want_c + 128) % 256 - 128
    dr = (rgb[:, 1].astype(int) - want_r + 128) % 256 - 128
    assert np.abs(dc).max() <= 1 and np.abs(dr).max() <= 1, (dc, dr)


def test_wmts_in_a_national_grid_is_draped_where_its_georeference_says(server, tmp_path):
    """LV95 (EPSG:2056) by REST: imagery layer first in the document, terrain by #layer=dem;
    the tile maths from ScaleDenominator and TopLeftCorner, not Web Mercator's."""
    _wmts(server, ("lv95", "google"))
    caps = f"{server.base}/wmts/1.0.0/WMTSCapabilities.xml"
    world = World(
        "swiss",
        parse_source(caps, "imagery", attribution="(c) test"),
        parse_source(f"terrain-rgb:{caps}#layer=dem", "terrain"),
    )
    layers, notes = _build(world, tmp_path / "cache", high=True)
    (layer,) = layers
    text = "\n".join(notes.items)
    assert "level 3 of swissgrid" in text and "level 1 of swissgrid" in text, text  # 1 m, 4 m
    assert not any(q for p, q, _, _ in server.log if p == "/kvp")  # asked as it was: REST
    frame = LocalFrame(LAT0, LON0, 600.0)
    lat, lon = _points()
    z, uv, prim = _surface(load_layers(layers, frame, TRACK).mesh, frame, lat, lon)
    truth = geoid.to_ellipsoidal(height(lat, lon), lat, lon, "egm2008")
    got = frame.enu_to_geodetic(
        np.column_stack([frame.geodetic_to_enu(lat, lon, np.zeros(len(lat)))[:, :2], z])
    )[:, 2]
    assert np.abs(got - truth).max() < 1.0  # the mesh's bound (0.5 m), 4 m pixels of the hills
    tex = prim.texture[::-1]
    col = np.clip((uv[:, 0] * tex.shape[1]).astype(int), 0, tex.shape[1] - 1)
    row = np.clip(((1 - uv[:, 1]) * tex.shape[0]).astype(int), 0, tex.shape[0] - 1)
    _texels_right(tex[row, col, :3], GRIDS["lv95"], lat, lon)
    assert pyproj.CRS(_sample(str(layer.ortho), lat, lon)[1]).to_epsg() == 2056


@pytest.mark.parametrize("grid", ["crs84", "google"])
def test_wmts_kvp_in_epsg4326_and_web_mercator_with_the_key_on_every_request(
    grid, server, tmp_path
):
    """KVP (the capabilities asked by GetCapabilities): WorldCRS84Quad, whose TopLeftCorner is
    latitude first, and GoogleMapsCompatible, chosen by #tilematrixset; the capabilities URL's
    key goes with every tile request and is in no file written, though the service writes it
    into its capabilities."""
    _wmts(server, ("lv95", "crs84", "google"), key_in_template=True)
    server.need_key = True
    caps = f"{server.base}/kvp?SERVICE=WMTS&REQUEST=GetCapabilities&key={{key}}"
    world = World(
        "w", parse_source(f"{caps}#tilematrixset={SET_IDS[grid]}", "imagery", key=KEY), None, "(c)"
    )
    layers, notes = _build(world, tmp_path / "cache")
    (layer,) = layers
    tiles = [q for p, q, _, _ in server.log if p == "/kvp" and q.get("REQUEST") == "GetTile"]
    assert len(tiles) >= 4 and all(q["TILEMATRIXSET"] == SET_IDS[grid] for q in tiles)
    assert all(q.get("KEY") == KEY for _, q, _, _ in server.log)
    lat, lon = _points(20)
    rgb, _ = _sample(str(layer.ortho), lat, lon)
    _texels_right(rgb, GRIDS[grid], lat, lon)
    for f in tmp_path.rglob("*"):
        if f.is_file():
            assert KEY.encode() not in f.read_bytes(), f
    assert not any(KEY in m for m in notes.items)
    n = len(server.log)
    _build(world, tmp_path / "cache")
    assert len(server.log) == n  # warm: the capabilities and the tiles from the cache


def test_wmts_faults_are_said_once_naming_the_source_and_the_flat_ground_kept(server, tmp_path):
    _wmts(server, ("lv95",))
    server.routes["/bad/WMTSCapabilities.xml"] = lambda p, q: (200, b"<html>no</html>", {})
    for location, said in (
        (f"{server.base}/gone/WMTSCapabilities.xml", "missing (HTTP 404)"),
        (f"{server.base}/bad/WMTSCapabilities.xml", "not a readable WMTS capabilities document"),
        (
            f"{server.base}/wmts/1.0.0/WMTSCapabilities.xml#layer=roads",
            "no layer 'roads' (it offers ortho, dem)",
        ),
        (
            f"{server.base}/wmts/1.0.0/WMTSCapabilities.xml#tilematrixset=nope",
            "no tile matrix set 'nope' (it links swissgrid)",
        ),
    ):
        world = World("w", parse_source(location, "imagery"), None, "(c)")
        layers, notes = _build(world, tmp_path / "cache")
        assert layers == ()
        text = "\n".join(notes.items)
        assert said in text and "its WMTS capabilities could not be used" in text, text
        assert text.count("world w imagery (127.0.0.1") == 1 and "flat ground" in text


def _covering(grid: TileGrid, levels: range, reach: float = 350.0):
    """(level, col, row) of every tile of `levels` over TRACK plus reach (m)."""
    box = box_in(grid.crs, lonlat_box(TRACK[:, 0], TRACK[:, 1], reach))
    return [t for z in levels for t in grid.covering(box, z).tiles()]


def test_geopackage_tiles_in_their_own_grid_as_imagery_and_terrain(tmp_path):
    """A GeoPackage in LV95 (EPSG:2056) holding imagery and Terrain-RGB tables, opened with no
    server at all: the first table, then #table=dem."""
    grid = GRIDS["lv95"]
    path = tmp_path / "area.gpkg"
    write_gpkg(
        path, grid, ((z, x, y, png(grid_imagery(z, x, y))) for z, x, y in _covering(grid, range(2, 4))), "ortho"
    )  # fmt: skip
    dem = tmp_path / "dem.gpkg"
    write_gpkg(
        dem, grid, ((z, x, y, png(grid_terrain(grid, z, x, y))) for z, x, y in _covering(grid, range(0, 2))), "dem"
    )  # fmt: skip
    world = World(
        "gpkg",
        parse_source(str(path), "imagery"),
        parse_source(f"terrain-rgb:{dem}#table=dem", "terrain"),
        "(c) test",
    )
    layers, notes = _build(world, tmp_path / "cache", high=True)
    (layer,) = layers
    text = "\n".join(notes.items)
    assert "level 3 of ortho" in text and "level 1 of dem" in text, text
    lat, lon = _points(20)
    rgb, crs = _sample(str(layer.ortho), lat, lon)
    _texels_right(rgb, grid, lat, lon)
    heights, _ = _sample(layer.location, lat, lon)
    assert np.abs(heights[:, 0] - height(lat, lon)).max() < 0.5  # 4 m pixels of smooth hills
    assert pyproj.CRS(crs).to_epsg() == 2056
    bad = World("bad", parse_source(str(tmp_path / "dem.gpkg#table=none"), "imagery"), None, "c")
    layers, notes = _build(bad, tmp_path / "cache")
    assert (
        layers == ()
        and "the archive could not be read: no tiles table 'none' (it holds dem)"
        in "\n".join(notes.items)
    )


def test_pmtiles_archive_as_imagery_opens_at_its_finest_level(tmp_path):
    """A PMTiles v3 archive of Web Mercator tiles written by the pmtiles package: its finest
    level (14) is taken though the source would allow 19; a vector archive is refused."""
    area = tm.covering(_area(600.0), 14)
    tiles = [
        (z, x, y, png(imagery_tile(z, x, y)))
        for z in (12, 13, 14)
        for _, x, y in tm.covering(_area(600.0), z).tiles()
    ]
    path = tmp_path / "area.pmtiles"
    assert write_pmtiles(path, tiles) == len(tiles) >= area.count
    world = World("pm", parse_source(str(path), "imagery"), None, "(c) test")
    layers, notes = _build(world, tmp_path / "cache")
    (layer,) = layers
    assert "at zoom 14" in "\n".join(notes.items)
    lat, lon = _points(20)
    rgb, _ = _sample(str(layer.ortho), lat, lon)
    x, y = tm.to_mercator(lat, lon)
    res = tm.tile_span_m(14) / 256
    assert (rgb[:, 2] == 140).all()
    dc = (
        rgb[:, 0].astype(int) - np.floor((x + tm.HALF_WORLD_M) / res).astype(int) % 256 + 128
    ) % 256 - 128
    dr = (
        rgb[:, 1].astype(int) - np.floor((tm.HALF_WORLD_M - y) / res).astype(int) % 256 + 128
    ) % 256 - 128
    assert np.abs(dc).max() <= 1 and np.abs(dr).max() <= 1
    vector = tmp_path / "roads.pmtiles"
    with open(vector, "wb") as f:
        w = PMTilesWriter(f)
        w.write_tile(0, b"\x1a\x00")
        w.finalize({"tile_type": TileType.MVT, "tile_compression": Compression.NONE}, {})
    layers, notes = _build(
        World("v", parse_source(str(vector), "imagery"), None, "c"), tmp_path / "c2"
    )
    assert layers == () and "holds MVT tiles, not raster images" in "\n".join(notes.items)


def _area(reach_m: float) -> tuple[float, float, float, float]:
    x, y = tm.to_mercator(TRACK[:, 0], TRACK[:, 1])
    grow = reach_m / math.cos(math.radians(float(TRACK[:, 0].mean())))
    return (x.min() - grow, y.min() - grow, x.max() + grow, y.max() + grow)


def _geotiff(
    path: Path, data: np.ndarray, transform: Affine, crs: str, overviews: bool = False
) -> bytes:
    """A tiled GeoTIFF (128-px blocks, deflate; internal overviews where asked): a COG's
    layout as far as range requests care."""
    bands = data[None] if data.ndim == 2 else np.moveaxis(data, -1, 0)
    with rasterio.open(
        path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=bands.shape[0],
        dtype=bands.dtype, crs=crs, transform=transform, tiled=True, blockxsize=128,
        blockysize=128, compress="deflate", **({"nodata": -9999.0} if data.ndim == 2 else {}),
    ) as dst:  # fmt: skip
        dst.write(bands)
        if overviews:
            dst.build_overviews([2, 4, 8])
    return path.read_bytes()


def test_a_cog_over_http_is_read_by_range_requests_only_over_the_clip(server, tmp_path):
    """A DEM GeoTIFF (EPSG:4326, ~20 km a side at ~20 m) and an orthophoto (EPSG:2056, 3 km a
    side at 2 m) over HTTP: Range requests only, a small part of each file served, heights and
    texels where their georeference says; the datum given taken and said; a warm run asks
    nothing; a missing file said once, without its key, the flat ground kept."""
    n = 1024
    lon = LON0 - 0.13 + (np.arange(n) + 0.5) * 0.26 / n
    lat = LAT0 + 0.09 - (np.arange(n) + 0.5) * 0.18 / n
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    rng = np.random.default_rng(1)
    dem = (height(la, lo) + rng.normal(0, 0.02, la.shape)).astype(np.float32)  # incompressible
    server.files["/data/dem.tif"] = _geotiff(
        tmp_path / "dem.tif", dem, Affine(0.26 / n, 0, LON0 - 0.13, 0, -0.18 / n, LAT0 + 0.09), "EPSG:4326"
    )  # fmt: skip
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:2056", always_xy=True).transform(
        LON0 - 0.018, LAT0 + 0.014
    )
    x0, y0 = math.floor(x0), math.floor(y0)
    m, px = 1536, 2.0  # 3 km a side at 2 m
    c = (np.arange(m) % 256).astype(np.uint8)
    ortho = np.empty((m, m, 3), np.uint8)
    ortho[..., 0], ortho[..., 1] = c[None, :], c[:, None]
    ortho[..., 2] = rng.integers(0, 256, (m, m), dtype=np.uint8)  # incompressible
    server.files["/data/ortho.tif"] = _geotiff(
        tmp_path / "ortho.tif", ortho, Affine(px, 0, x0, 0, -px, y0), "EPSG:2056"
    )
    world = World(
        "cog",
        parse_source(f"{server.base}/data/ortho.tif", "imagery"),
        parse_source(f"{server.base}/data/dem.tif", "terrain", datum="egm96"),
        "(c) test",
    )
    layers, notes = _build(world, tmp_path / "cache")
    (layer,) = layers
    text = "\n".join(notes.items)
    assert "read by range requests" in text and "heights taken as above EGM96" in text, text
    assert layer.vertical == "egm96"
    for name in ("/data/dem.tif", "/data/ortho.tif"):
        asked = [(r, sent) for p, _, r, sent in server.log if p == name]
        assert asked and all(r is not None for r, sent in asked if sent)  # every byte by Range
        assert server.sent(name) < 0.15 * len(server.files[name]), (name, server.sent(name))
    la, lo = _points(20)
    heights, _, clat, clon = _sample(layer.location, la, lo, centres=True)
    assert np.abs(heights[:, 0] - height(clat, clon)).max() < 0.1  # the file's noise: 0.02 m
    rgb, crs = _sample(str(layer.ortho), la, lo)
    assert pyproj.CRS(crs).to_epsg() == 2056
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:2056", always_xy=True).transform(lo, la)
    want_c = np.floor((np.asarray(x) - x0) / px).astype(int) % 256
    want_r = np.floor((y0 - np.asarray(y)) / px).astype(int) % 256
    assert np.abs((rgb[:, 0].astype(int) - want_c + 128) % 256 - 128).max() <= 1
    assert np.abs((rgb[:, 1].astype(int) - want_r + 128) % 256 - 128).max() <= 1
    before = len(server.log)
    layers2, notes2 = _build(world, tmp_path / "cache")
    assert layers2 and len(server.log) == before and "from the cache" in "\n".join(notes2.items)
    gone = World(
        "gone",
        parse_source(f"{server.base}/data/none.tif?key={{key}}", "imagery", key=KEY),
        None,
        "c",
    )
    layers, notes = _build(gone, tmp_path / "cache")
    text = "\n".join(notes.items)
    assert layers == () and text.count("world gone imagery (127.0.0.1") == 1, text
    assert "the GeoTIFF could not be read" in text and KEY not in text and "flat ground" in text


def _xyz_world_args(base: str) -> list[str]:
    return ["--imagery", f"{base}/img/{{z}}/{{x}}/{{y}}.png", "--terrain", f"terrain-rgb:{base}/dem/{{z}}/{{x}}/{{y}}.png"]  # fmt: skip


def test_cache_prefetches_an_area_that_opens_with_the_server_stopped_lists_and_clears(
    tmp_path, capsys
):
    """`geofuse cache --bbox ... --out AREA.mbtiles`: the size said before anything is
    fetched, imagery and terrain archives written, the scene built from them with the server
    stopped and nothing missing; `geofuse cache` lists the sources, --clear SOURCE removes one,
    --clear all; OpenStreetMap's tile servers refused for bulk download."""
    xyz = TileServer()
    bbox = f"{LON0 - 0.003},{LAT0 - 0.002},{LON0 + 0.004},{LAT0 + 0.003}"
    area = tmp_path / "area.mbtiles"
    try:
        assert main(["cache", "--bbox", bbox, "--gsd", "2", *_xyz_world_args(xyz.base), "--out", str(area)]) == 0  # fmt: skip
        out, err = capsys.readouterr()
        fetched = len(xyz.log)
    finally:
        xyz.stop()
    assert re.search(
        r"(\d+) terrain tiles .* at zoom 11-14 .*(\d+) imagery tiles .* at zoom 13-16 .*about [\d.]+ MB",
        err,
    ), err
    assert f"wrote {area}:" in out and "offline: --terrain terrain-rgb:" in out and fetched > 10
    world = World(
        "offline",
        parse_source(str(area), "imagery"),
        parse_source(f"terrain-rgb:{tmp_path / 'area-terrain.mbtiles'}", "terrain"),
        "(c) test",
    )
    track = np.array([[LAT0, LON0], [LAT0 + 0.001, LON0 + 0.001]])
    notes = Messages()
    layers = world_scene(
        world, track[:, 0], track[:, 1], 600.0, 100.0, 2000.0, notes, cache=TileCache(tmp_path / "c2")
    )  # fmt: skip
    (layer,) = layers
    text = "\n".join(notes.items)
    assert "missing" not in text and "imagery: " in text and "at zoom 16" in text, text
    lat, lon = LAT0 + np.linspace(0, 0.001, 9), LON0 + np.linspace(0, 0.001, 9)
    rgb, _ = _sample(str(layer.ortho), lat, lon)
    assert (rgb[:, 2] == 160).all()
    heights, _, clat, clon = _sample(layer.location, lat, lon, centres=True)
    assert np.abs(heights[:, 0] - height(clat, clon)).max() < 0.5
    assert main(["cache"]) == 0
    listing = capsys.readouterr().out
    assert "/img/{z}/{x}/{y}.png" in listing and "/dem/{z}/{x}/{y}.png (terrain-rgb)" in listing
    assert main(["cache", "--clear", "/dem/"]) == 0
    assert "removed terrain" in capsys.readouterr().out
    assert main(["cache"]) == 0
    assert "/dem/" not in capsys.readouterr().out
    assert main(["cache", "--clear"]) == 0 and main(["cache"]) == 0
    assert "is empty" in capsys.readouterr().out
    osm = ["--imagery", "https://a.tile.openstreetmap.org/{z}/{x}/{y}.png"]
    assert main(["cache", "--bbox", bbox, *osm, "--out", str(tmp_path / "osm.mbtiles")]) == 2
    assert "forbid bulk download" in capsys.readouterr().err
    assert not (tmp_path / "osm.mbtiles").exists()


def test_a_clip_prefetched_opens_offline_from_a_manifest_world(tmp_path, dji_clip, capsys):
    """`geofuse cache CLIP --out`: the tiles the clip's scene asks for; then, the server stopped,
    a manifest's [world] naming the archives (relative to it) builds the clip's scene."""
    xyz = TileServer()
    try:
        assert main(["cache", str(dji_clip), *_xyz_world_args(xyz.base), "--out", str(tmp_path / "area.mbtiles")]) == 0  # fmt: skip
    finally:
        xyz.stop()
    capsys.readouterr()
    manifest = tmp_path / "clip.toml"
    srt = dji_clip.with_suffix(".SRT")
    manifest.write_text(
        f'[video]\npath = "{dji_clip}"\nstart_time = 0.0\n\n[camera]\nhfov_deg = 73.7\n\n'
        f'[sensors]\nformat = "none"\n\n[gnss]\npath = "{srt}"\ntakeoff_height_m = 600.0\n\n'
        '[world]\nimagery = "area.mbtiles"\nterrain = "terrain-rgb:area-terrain.mbtiles"\n'
        'attribution = "(c) test"\n'
    )
    session = open_session(manifest)
    text = "\n".join(session.messages.items)
    assert "world manifest imagery: " in text and "world manifest terrain: " in text, text
    assert "missing" not in text and "flat ground" not in text, text
    assert any(p.texture is not None for p in session.mesh.primitives)


@pytest.mark.parametrize("given", [None, 600.0], ids=["camera", "reach_m"])
def test_a_manifest_world_reaches_as_far_as_the_flown_camera_sees(given, tmp_path, dji_clip):
    """A manifest's [world] over a flown track (the clip hovers 80 m above take-off) is fetched
    over the track plus 500 m + 10 x 80 m = 1300 m on the ground, as the clip opened alone is,
    not the 300 m of a hand-held one, or as far as its reach_m says: every imagery tile of that
    area at the level taken is asked for, and none beyond it; the reach is said."""
    xyz = TileServer()
    try:
        manifest = tmp_path / "clip.toml"
        manifest.write_text(
            f'[video]\npath = "{dji_clip}"\nstart_time = 0.0\n\n[camera]\nhfov_deg = 73.7\n\n'
            f'[sensors]\nformat = "none"\n\n[gnss]\npath = "{dji_clip.with_suffix(".SRT")}"\n'
            f'takeoff_height_m = 600.0\n\n[world]\nimagery = "{xyz.base}/img/{{z}}/{{x}}/{{y}}.png"\n'
            f'imagery_max_zoom = {IMAGERY_Z}\nattribution = "(c) test"\n'
            + (f"reach_m = {given}\n" if given else "")
        )
        session = open_session(manifest)
        asked = {
            tuple(int(v) for v in path.removesuffix(".png").split("/")[2:5])
            for path, *_ in xyz.log
            if path.startswith("/img/")
        }
    finally:
        xyz.stop()
    reach = given or 1300.0
    text = "\n".join(session.messages.items)
    whose = "its reach_m" if given else "the camera's reach"
    assert f"world manifest: over the track plus {reach:.0f} m ({whose})" in text, text
    (z,) = {t[0] for t in asked}
    lat = LAT0 + 0.0002 * np.arange(4)  # the clip's fixes (tests/test_world.py write_drone_clip)
    lon = LON0 + 0.0003 * np.arange(4)
    x, y = tm.to_mercator(lat, lon)

    def area(reach_m: float) -> tuple[float, float, float, float]:
        grow = reach_m / math.cos(math.radians(float(lat.mean())))  # ground m -> Mercator m
        return (x.min() - grow, y.min() - grow, x.max() + grow, y.max() + grow)

    assert asked == set(tm.covering(area(reach), z).tiles()), (z, len(asked))
    assert len(asked) > tm.covering(area(300.0), z).count  # more than a hand-held track's


def test_a_camera_sees_300_m_held_and_500_m_plus_10x_its_height_flown():
    assert ground_reach_m([1.5, 2.0, 9.0]) == 300.0  # a phone, a car's roof, a mast
    assert ground_reach_m([1.5, 80.0, np.nan]) == 1300.0  # a drone hovering 80 m up
    assert ground_reach_m([]) == 300.0  # no fix at all (a cold start)


def test_a_manifest_world_names_a_settings_world_or_says_what_is_wrong(tmp_path, monkeypatch):
    folder = tmp_path / "config" / "geofuse"
    folder.mkdir(parents=True)
    (folder / "settings.toml").write_text(
        '[[world]]\nname = "local"\nimagery = "http://127.0.0.1:9/{z}/{x}/{y}.png"\n'
    )
    base = '[video]\npath = "v.mp4"\n'
    for table, said in (
        ('[world]\nname = "elsewhere"\n', "no such world"),
        ('[world]\nimagery = "x.png"\n', "world"),
        ('[world]\nimagery = "a.mbtiles"\nkey = "abc"\n', "key_env"),
        ('[world]\nimagery = "a.mbtiles"\nkye_env = "X"\n', "unknown key"),
        ('[world]\nimagery = "a.mbtiles"\nreach_m = -5\n', "reach_m must be a distance"),
        ('[world]\nimagery = "a.mbtiles"\nreach_m = "far"\n', "reach_m must be a distance"),
    ):
        manifest = tmp_path / "m.toml"
        manifest.write_text(table + base)
        with pytest.raises(ManifestError, match=said):
            read_config(manifest)
    manifest.write_text('[world]\nname = "local"\n' + base)
    with pytest.raises(ManifestError) as err:  # the world is read; the video is what is missing
        read_config(manifest)
    assert err.value.field.startswith("video")
