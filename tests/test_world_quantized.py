"""Cesium quantized-mesh terrain (issue 48): tiles of a known surface (a plane tilted 5 % and a
Gaussian bump) written by the test's own encoder and decoded within what the quantization and
the triangles allow; a layer.json served with them from a loopback server (test_world_sources'
Server): the geodetic tiling and its TMS rows, `available` and metadata availability honoured
(a missing tile never asked for, drawn from its parent), gzip, extension blocks skipped, faults
said once without the key; a clip with no scene standing on them. Real tiles from a public
decoder's tests: tests/data/quantized_mesh (README there)."""

from __future__ import annotations

import gzip
import json
import math
import re
import struct
import threading
from pathlib import Path

import numpy as np
import pyproj
import pytest

from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.footage.clips import open_clip
from app.geodesy.enu import LocalFrame
from app.scene.ground import ellipsoidal_ground
from app.scene.layers import load_layers
from app.world.build import plan_world, world_layer, world_scene
from app.world.cache import TileCache
from app.world.grids import lonlat_box
from app.world.prefetch import Job, check_archive
from app.world.quantized import (
    QUANT_MAX,
    SAMPLES,
    QuantizedMeshError,
    decode_mesh,
    read_layer,
    tile_heights,
)
from app.world.settings import World, choose_world, manifest_world
from app.world.sources import SourceError, parse_source
from tests.test_world import KEY, LAT0, LON0, TRACK, _own_folders, drone_clip  # noqa: F401
from tests.test_world_sources import Server

DATA = Path(__file__).parent / "data" / "quantized_mesh"

# The surface, in metres above the WGS84 ellipsoid: a plane rising 5 % to the east and a bump
K_LAT = 111_320.0  # the surface's own metres a degree of latitude (its definition, not a measure)
K_LON = K_LAT * math.cos(math.radians(LAT0))
BASE_M, SLOPE = 480.0, 0.05
BUMP_M, BUMP_SIGMA_M = 20.0, 120.0
BUMP_AT = (LAT0 + 0.0005, LON0 + 0.00075)  # (lat, lon): under the middle of TRACK
CURVATURE = BUMP_M / BUMP_SIGMA_M**2  # the largest second derivative of the surface, 1/m
VERTICES = 65  # a tile's vertices a side (a regular grid, two triangles a cell)
LEVELS = 15  # the finest level served
DEM_ERROR_M = 0.5  # the terrain mesh's own error (the default --dem-error)
ACCEPT_NONE = "application/vnd.quantized-mesh,application/octet-stream;q=0.9,*/*;q=0.01"
ACCEPT_METADATA = (
    "application/vnd.quantized-mesh;extensions=metadata,application/octet-stream;q=0.9,*/*;q=0.01"
)
EXTRA_BLOCKS = ((2, b"\x00"), (7, b"\xde\xad\xbe\xef" * 3))  # a water mask, an unknown one
TO_ECEF = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def surface(lat, lon, bump: bool = True) -> np.ndarray:
    """The test's terrain (m above the ellipsoid) at (lat, lon) deg."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    h = BASE_M + SLOPE * (lon - LON0) * K_LON
    if bump:
        e, n = (lon - BUMP_AT[1]) * K_LON, (lat - BUMP_AT[0]) * K_LAT
        h = h + BUMP_M * np.exp(-(e**2 + n**2) / (2 * BUMP_SIGMA_M**2))
    return h


def tile_span(z: int) -> float:
    """A geodetic tile's side at level z, deg (level 0: two tiles of 180 deg)."""
    return 180.0 / (1 << z)


def tms_tile(z: int, lat: float, lon: float) -> tuple[int, int]:
    """(column, TMS row from the south) of the geodetic tile holding (lat, lon) at level z."""
    d = tile_span(z)
    return int((lon + 180.0) // d), int((lat + 90.0) // d)


def triangle_bound(z: int, vertices: int = VERTICES) -> float:
    """The most the triangles of a level-z tile can depart from the surface (m): for a linear
    interpolant on a triangle, |f - I f| <= M / 2 * max |x - x_i|^2 <= M / 2 * (longest edge)^2,
    M the surface's largest second derivative, the longest edge a cell's diagonal."""
    cell = tile_span(z) / (vertices - 1)
    return CURVATURE / 2.0 * ((cell * K_LON) ** 2 + (cell * K_LAT) ** 2)


def height_step(z: int) -> float:
    """Half a height quantum (m) at most in a level-z tile near the track: (max - min) / 32767
    / 2, the range at most the plane's rise across the tile plus the bump."""
    return (SLOPE * tile_span(z) * K_LON + BUMP_M + 1.0) / QUANT_MAX / 2.0


GAP = (LEVELS, *tms_tile(LEVELS, LAT0, LON0))  # the tile under TRACK[0] the server lacks


def _zigzag_deltas(values: np.ndarray) -> bytes:
    d = np.diff(values.astype(np.int64), prepend=0)
    return ((d << 1) ^ (d >> 63)).astype("<u2").tobytes()


def encode_tile(
    z: int,
    x: int,
    y: int,
    bump: bool = True,
    vertices: int = VERTICES,
    extensions: tuple[tuple[int, bytes], ...] = (),
    box: tuple[float, float, float, float] | None = None,
    heights=None,
) -> tuple[bytes, dict]:
    """A quantized-mesh-1.0 tile of the surface (or of heights(lat, lon)) over geodetic tile (z,
    x, TMS row y), or over box (west, south, east, north deg): a regular grid of vertices a
    side, linear in longitude and latitude, two triangles a cell, its heights taken at the
    quantized vertex positions; and what it holds (u, v, h, triangles, edges, the float32
    height range)."""
    d = tile_span(z)
    west, south, east, north = box or (-180.0 + x * d, -90.0 + y * d, -180.0 + (x + 1) * d, -90.0 + (y + 1) * d)  # fmt: skip
    q = np.round(np.linspace(0, QUANT_MAX, vertices)).astype(np.int64)
    uu, vv = np.meshgrid(q, q)
    u, v = uu.ravel(), vv.ravel()
    lat, lon = south + v / QUANT_MAX * (north - south), west + u / QUANT_MAX * (east - west)
    h = surface(lat, lon, bump) if heights is None else heights(lat, lon)
    lo = float(np.nextafter(np.float32(h.min()), np.float32(-np.inf)))  # float32, as stored
    hi = float(np.nextafter(np.float32(h.max()), np.float32(np.inf)))
    hq = np.round((h - lo) / (hi - lo) * QUANT_MAX).astype(np.int64)
    k = np.arange(vertices - 1)
    a = (k[None, :] + vertices * k[:, None]).ravel()  # each cell's south-west vertex
    tri = np.stack([a, a + 1, a + vertices + 1, a, a + vertices + 1, a + vertices], 1)
    tri = tri.reshape(-1, 3)
    # vertices renumbered in the order of their first use, as the high-water mark needs
    _, first = np.unique(tri.ravel(), return_index=True)
    order = np.argsort(first)
    renumber = np.empty_like(order)
    renumber[order] = np.arange(len(order))
    u, v, hq, tri = u[order], v[order], hq[order], renumber[tri]
    flat = tri.ravel()
    highest = np.concatenate([[0], np.maximum.accumulate(flat)[:-1] + 1])
    codes = highest - flat
    assert (codes >= 0).all()
    n = len(u)
    index = "<u4" if n > 65536 else "<u2"
    cx, cy, cz = TO_ECEF.transform((west + east) / 2, (south + north) / 2, (lo + hi) / 2)
    out = bytearray(struct.pack("<3d2f4d3d", cx, cy, cz, lo, hi, cx, cy, cz, d * K_LAT, cx, cy, cz))
    out += struct.pack("<I", n) + _zigzag_deltas(u) + _zigzag_deltas(v) + _zigzag_deltas(hq)
    if index == "<u4" and len(out) % 4:
        out += b"\x00" * (4 - len(out) % 4)
    out += struct.pack("<I", len(tri)) + codes.astype(index).tobytes()
    edges = [np.flatnonzero(u == 0), np.flatnonzero(v == 0)]
    edges += [np.flatnonzero(u == QUANT_MAX), np.flatnonzero(v == QUANT_MAX)]
    for e in edges:
        out += struct.pack("<I", len(e)) + e.astype(index).tobytes()
    for ext, data in extensions:
        out += struct.pack("<BI", ext, len(data)) + data
    truth = {"u": u, "v": v, "h": hq, "triangles": tri, "edges": edges, "range": (lo, hi)}
    return bytes(out), truth


def metadata_block(available: list[list[dict]]) -> tuple[int, bytes]:
    """The metadata extension (id 4) listing `available` for the levels below a tile."""
    text = json.dumps({"available": available}).encode()
    return 4, struct.pack("<I", len(text)) + text


def ranges_without_gap(z: int, x0: int, y0: int, x1: int, y1: int) -> list[dict]:
    """The tile ranges (TMS rows) of x0..x1, y0..y1 at level z, less the GAP tile."""
    if (z, *GAP[1:]) != GAP or not (x0 <= GAP[1] <= x1 and y0 <= GAP[2] <= y1):
        return [{"startX": x0, "startY": y0, "endX": x1, "endY": y1}]
    gx, gy = GAP[1:]
    parts = [(x0, y0, x1, gy - 1), (x0, gy + 1, x1, y1), (x0, gy, gx - 1, gy), (gx + 1, gy, x1, gy)]
    return [
        {"startX": a, "startY": b, "endX": c, "endY": d}
        for a, b, c, d in parts
        if a <= c and b <= d
    ]


def subtree(z: int, x: int, y: int, levels: int) -> list[list[dict]]:
    """What the metadata of tile (z, x, y) says of the `levels` levels below it (to LEVELS)."""
    out = []
    for k in range(1, levels + 1):
        if z + k > LEVELS:
            break
        s = 1 << k
        out.append(ranges_without_gap(z + k, x * s, y * s, (x + 1) * s - 1, (y + 1) * s - 1))
    return out


def layer_json(metadata: bool = False, **fields) -> bytes:
    """A layer.json: geodetic TMS tiles to LEVELS, availability by `available` (every tile but
    GAP) or, with metadata, by tile metadata every 10 levels."""
    doc = {
        "tilejson": "2.1.0",
        "format": "quantized-mesh-1.0",
        "version": "1.2.0",
        "scheme": "tms",
        "tiles": ["{z}/{x}/{y}.terrain?v={version}"],
        "projection": "EPSG:4326",
        "minzoom": 0,
        "maxzoom": LEVELS,
        "attribution": "(c) test terrain",
    }
    if metadata:
        doc |= {"extensions": ["octvertexnormals", "metadata"], "metadataAvailability": 10}
    else:
        doc |= {"extensions": ["octvertexnormals", "watermask"]}
        doc["available"] = [
            ranges_without_gap(z, 0, 0, (2 << z) - 1, (1 << z) - 1) for z in range(LEVELS + 1)
        ]
    return json.dumps(doc | fields).encode()


class MeshServer(Server):
    """test_world_sources' loopback Server serving /qm/layer.json and /qm/{z}/{x}/{y}.terrain
    of the surface (every tile but GAP; metadata in the tiles of levels 0 and 10 where asked
    for); tiles where (x + y) % 3 is 0 gzipped with Content-Encoding, 1 gzipped without it, 2
    plain; each with EXTRA_BLOCKS. faults: tile path -> '404' or 'corrupt'; heard: (path, Accept)
    of every request."""

    def __init__(self, metadata: bool = False) -> None:
        super().__init__()
        self.metadata = metadata
        self.faults: dict[str, str] = {}
        self.heard: list[tuple[str, str | None]] = []
        self.modes: set[int] = set()
        self._now = threading.local()
        server, base = self, self.httpd.RequestHandlerClass

        class Handler(base):
            def _serve(self, head: bool) -> None:
                accept = self.headers.get("Accept")
                server._now.accept = accept
                server.heard.append((self.path.partition("?")[0], accept))
                super()._serve(head)

        self.httpd.RequestHandlerClass = Handler
        self.routes["/qm/layer.json"] = lambda p, q: (200, layer_json(metadata), {})
        self.routes["/qm/"] = self._tile

    def _tile(self, path: str, q: dict):
        m = re.fullmatch(r"/qm/(\d+)/(\d+)/(\d+)\.terrain", path)
        z, x, y = (int(g) for g in m.groups())
        if z > LEVELS or (z, x, y) == GAP or self.faults.get(path) == "404":
            return 404, b"no tile", {}
        blocks = EXTRA_BLOCKS
        if self.metadata and z % 10 == 0 and "metadata" in (self._now.accept or ""):
            blocks = (metadata_block(subtree(z, x, y, 10)),) + blocks
        data, _ = encode_tile(z, x, y, extensions=blocks)
        if self.faults.get(path) == "corrupt":
            return 200, data[: len(data) // 2], {}
        mode = (x + y) % 3
        self.modes.add(mode)
        headers = {"Cache-Control": "max-age=3600"}
        if mode == 0:
            return 200, gzip.compress(data), headers | {"Content-Encoding": "gzip"}
        return 200, gzip.compress(data) if mode == 1 else data, headers

    def tiles_asked(self) -> list[tuple[int, int, int]]:
        """(z, x, TMS row) of every tile request, in order."""
        out = []
        for path, _ in self.heard:
            m = re.fullmatch(r"/qm/(\d+)/(\d+)/(\d+)\.terrain", path)
            if m:
                out.append(tuple(int(g) for g in m.groups()))
        return out


@pytest.fixture
def mesh_server():
    s = MeshServer()
    yield s
    s.stop()


def _terrain(url: str, key: str | None = None) -> World:
    return World("w", None, parse_source(url, "terrain", key=key), "(c) test terrain")


def _build(world: World, cache: Path) -> tuple[tuple, Messages]:
    """world_scene over TRACK, 300 m around it, for a camera 100 m above the ground."""
    notes = Messages()
    layers = world_scene(
        world, TRACK[:, 0], TRACK[:, 1], BASE_M, 300.0, 100.0, notes, cache=TileCache(cache)
    )
    return layers, notes


def _expected_tiles(reach_m: float = 300.0) -> set[tuple[int, int, int]]:
    """(z, x, TMS row) of the level-LEVELS tiles over TRACK plus reach_m, by hand."""
    west, south, east, north = lonlat_box(TRACK[:, 0], TRACK[:, 1], reach_m)
    (x0, y0), (x1, y1) = tms_tile(LEVELS, south, west), tms_tile(LEVELS, north, east)
    return {(LEVELS, x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)}


# -- the decoder ---------------------------------------------------------------------------------


def test_the_decoder_reads_what_the_encoder_wrote_within_the_quantization():
    z, x, y = LEVELS, *tms_tile(LEVELS, *BUMP_AT)
    d = tile_span(z)
    frac = (np.arange(SAMPLES) + 0.5) / SAMPLES
    lon, lat = np.meshgrid(-180.0 + x * d + frac * d, -90.0 + y * d + (1 - frac) * d)
    layer = read_layer(layer_json(), "http://h/qm/layer.json")
    row = layer.grid.matrices[z].rows - 1 - y  # the grid counts rows from the north
    for bump in (False, True):
        data, truth = encode_tile(z, x, y, bump, extensions=EXTRA_BLOCKS)
        for raw in (data, gzip.compress(data)):
            mesh = decode_mesh(raw)
            for k in ("u", "v", "h"):
                assert np.array_equal(getattr(mesh, k), truth[k]), k
            assert np.array_equal(mesh.triangles, truth["triangles"])
            for side, want in zip(("west", "south", "east", "north"), truth["edges"], strict=True):
                assert np.array_equal(getattr(mesh, side), want), side
            assert (mesh.min_height, mesh.max_height) == truth["range"]
            assert mesh.extensions == dict(EXTRA_BLOCKS)  # read past, kept as bytes
        # heights at the pixel centres: a plane is exact but for the height quantum; the bump
        # departs from its triangles by at most the interpolation bound
        got = tile_heights(layer, mesh, z, x, row)
        lo, hi = truth["range"]
        bound = (hi - lo) / QUANT_MAX / 2 + (triangle_bound(z) if bump else 0.0) + 1e-9
        err = np.abs(got - surface(lat, lon, bump))
        assert err.max() <= bound, (bump, err.max(), bound)
        if bump:
            assert err.max() > bound / 20  # the bound is not idle: the bump is really there


def test_32_bit_indices_and_faults_in_the_bytes():
    data, truth = encode_tile(10, 1100, 700, vertices=257)  # 66049 vertices: 32-bit indices
    mesh = decode_mesh(data)
    assert len(mesh.u) == 257 * 257 > 65536
    assert np.array_equal(mesh.triangles, truth["triangles"])
    assert np.array_equal(mesh.north, truth["edges"][3])
    small, _ = encode_tile(LEVELS, *GAP[1:], vertices=5)
    for bad, said in (
        (small[:60], "cut short in the header"),
        (small[:150], "cut short in the vertices' v"),
        (small + b"\x07\x10\x00\x00\x00ab", "cut short in extension 7"),
        (b"\x1f\x8b" + small[:40], "gzipped, but does not gunzip"),
    ):
        with pytest.raises(QuantizedMeshError, match=re.escape(said)):
            decode_mesh(bad)


def test_real_tiles_of_a_public_decoder_read():
    """tests/data/quantized_mesh: heremaps/quantized-mesh-decoder's test tiles (MIT)."""
    opentin = decode_mesh((DATA / "tile-opentin.terrain").read_bytes())
    # its two triangles as that repository's test states them (u, v, height quantized)
    q = [
        [int(f * QUANT_MAX) for f in p] for p in ((0.255763, 0.805321, 0), (0.300351, 0.760477, 1))
    ]
    a, b = q
    c, d = [b[0], a[1], 0], [a[0], b[1], 0]
    got = [[[int(m[i]) for m in (opentin.u, opentin.v, opentin.h)] for i in t] for t in opentin.triangles]  # fmt: skip
    assert got == [[a, b, c], [b, a, d]]
    assert (opentin.min_height, opentin.max_height) == (0.0, 7.0)
    assert opentin.heights.tolist() == [0.0, 7.0, 0.0, 0.0]
    with_ext = decode_mesh((DATA / "tile-with-extensions.terrain").read_bytes())
    n = len(with_ext.u)
    assert sorted(with_ext.extensions) == [1, 2] and len(with_ext.extensions[1]) == 2 * n
    assert with_ext.triangles.max() < n and len(with_ext.west) > 0
    meta = decode_mesh((DATA / "tile-with-metadata-extension.terrain").read_bytes())
    assert sorted(meta.extensions) == [1, 2, 4]
    assert set(meta.metadata) == {"geometricerror", "surfacearea"}
    layer = read_layer(layer_json(), "http://h/qm/layer.json")
    for m in (with_ext, meta):
        h = tile_heights(layer, m, 0, 0, 0, size=64)
        assert np.isfinite(h).all()  # the triangles cover the tile
        assert m.min_height - 1e-6 <= h.min() and h.max() <= m.max_height + 1e-6


# -- the layer -----------------------------------------------------------------------------------


def test_layer_json_tiling_rows_urls_and_what_is_asked_for():
    layer = read_layer(layer_json(), "http://h/qm/layer.json?key={key}")
    g = layer.grid
    assert (g.matrices[0].cols, g.matrices[0].rows) == (2, 1)  # geodetic: 2 x 1 at level 0
    assert g.matrices[0].tile_bounds(0, 0) == (-180.0, -90.0, 0.0, 90.0)
    assert g.matrices[0].tile_bounds(1, 0) == (0.0, -90.0, 180.0, 90.0)
    assert (g.matrices[1].cols, g.matrices[1].rows) == (4, 2) and layer.max_level == LEVELS
    r = g.covering((LON0, LAT0, LON0, LAT0), LEVELS)
    assert (r.x0, layer.server_row(LEVELS, r.y0)) == GAP[1:]  # TMS: rows from the south
    assert layer.url(LEVELS, r.x0, r.y0) == (
        f"http://h/qm/{LEVELS}/{GAP[1]}/{GAP[2]}.terrain?v=1.2.0&key={{key}}"
    )
    assert layer.available(*GAP[:2], r.y0) is False and layer.available(LEVELS, r.x0 + 1, r.y0)
    assert layer.accept == ACCEPT_NONE  # normals and water masks are offered, not wanted
    meta = read_layer(layer_json(metadata=True), "http://h/qm/layer.json")
    assert meta.accept == ACCEPT_METADATA and meta.available(0, 1, 0)
    assert meta.available(LEVELS, r.x0, r.y0) is None  # not known before the metadata
    assert meta.to_load(LEVELS, r.x0, r.y0) == (0, 1, 0)
    merc = read_layer(layer_json(projection="EPSG:3857", scheme="slippyMap"), "http://h/l.json")
    assert (merc.grid.matrices[0].cols, merc.grid.matrices[0].rows) == (1, 1)
    assert merc.server_row(3, 2) == 2 and merc.url(3, 1, 2) == "http://h/3/1/2.terrain?v=1.2.0"
    # a Web Mercator tile's v is linear in latitude: a surface linear in latitude comes back
    # within the height quantum at its rows' latitudes (1.6 km off, were v taken as linear in y)
    z, x, y = 4, 8, 5  # 0..22.5 deg E, 40.98..55.78 deg N
    _, ymin, _, ymax = merc.grid.matrices[z].tile_bounds(x, y)
    south, north = (math.degrees(2 * math.atan(math.exp(m / 6378137.0)) - math.pi / 2) for m in (ymin, ymax))  # fmt: skip
    tilted = lambda lat, lon: 1000.0 + 3000.0 * (lat - south) + 10.0 * lon  # noqa: E731
    data, truth = encode_tile(z, x, y, box=(0.0, south, 22.5, north), heights=tilted)
    got = tile_heights(merc, decode_mesh(data), z, x, y, size=64)
    rows_y = ymax - (np.arange(64) + 0.5) / 64 * (ymax - ymin)
    lat = np.degrees(2 * np.arctan(np.exp(rows_y / 6378137.0)) - np.pi / 2)
    lon = (np.arange(64) + 0.5) / 64 * 22.5
    lo, hi = truth["range"]
    assert (
        np.abs(got - tilted(lat[:, None], lon[None, :])).max() <= (hi - lo) / QUANT_MAX / 2 + 1e-6
    )
    for doc, said in (
        (layer_json(format="heightmap-1.0"), "format 'heightmap-1.0'"),
        (layer_json(tiles=[]), "no tile URL template"),
        (layer_json(projection="EPSG:2056"), "projection EPSG:2056 is not one of"),
        (b"<html>", "not a readable layer.json"),
    ):
        with pytest.raises(QuantizedMeshError, match=re.escape(said)):
            read_layer(doc, "http://h/layer.json")


def test_the_source_is_spelt_by_its_layer_json_or_its_folder(tmp_path, monkeypatch):
    url = "https://t.example/dem/layer.json?key={key}"
    for spelt in (url, "quantized-mesh:https://t.example/dem/?key={key}"):
        s = parse_source(spelt, "terrain", key=KEY)
        assert (s.location, s.form, s.encoding, s.datum) == (
            url, "quantized-mesh", "quantized-mesh", "ellipsoid"
        )  # fmt: skip
        assert KEY not in s.label and s.label == "t.example/dem/layer.json"
    assert choose_world(terrain="https://t.example/dem/layer.json").terrain.datum == "ellipsoid"
    folder = tmp_path / "m"
    world = manifest_world({"terrain": "quantized-mesh:https://t.example/dem"}, folder)
    assert world.terrain.location == "https://t.example/dem/layer.json"  # not made a file
    for spelt, kind, said in (
        ("https://t.example/layer.json", "imagery", "is terrain (--terrain)"),
        ("terrain-rgb:https://t.example/layer.json", "terrain", "drop terrain-rgb:"),
        ("quantized-mesh:dem/layer.json", "terrain", "goes before the http(s) URL"),
    ):
        with pytest.raises(SourceError, match=re.escape(said)):
            parse_source(spelt, kind)


# -- served --------------------------------------------------------------------------------------


def _heights_match(layers: tuple, points: list[tuple[float, float, int]]) -> None:
    """The scene's ground at each (lat, lon, level its tile came from) is the surface's, within
    the terrain mesh's error, the triangles' bound at that level and the height quantum, and
    the DEM's pixels (the interpolation bound again over a pixel's diagonal)."""
    frame = LocalFrame(LAT0, LON0, BASE_M)
    mesh = load_layers(layers, frame, TRACK).mesh
    for lat, lon, z in points:
        pixel = tile_span(z) / SAMPLES
        pixel_bound = CURVATURE / 2 * ((pixel * K_LON) ** 2 + (pixel * K_LAT) ** 2)
        bound = DEM_ERROR_M + triangle_bound(z) + height_step(z) + pixel_bound
        got = ellipsoidal_ground(mesh, frame, lat, lon)
        assert got is not None and abs(got - float(surface(lat, lon))) <= bound, (lat, lon, got)


@pytest.mark.parametrize("metadata", [False, True], ids=["available", "metadata"])
def test_a_world_on_quantized_mesh_terrain(metadata, tmp_path):
    """Availability by layer.json's `available`, or by the metadata of the tiles of levels 0 and
    10: the tile the server lacks is never asked for and is drawn from its parent; the key in
    the layer.json's query goes with every tile and into no file or message; gzip (with and
    without Content-Encoding) and extension blocks read; a warm run asks nothing."""
    server = MeshServer(metadata)
    server.need_key = True
    try:
        world = _terrain(f"{server.base}/qm/layer.json?key={{key}}", key=KEY)
        layers, notes = _build(world, tmp_path / "cache")
        (layer,) = layers
        text = "\n".join(notes.items)
        assert layer.vertical == "ellipsoid" and "heights taken as above the ellipsoid" in text
        assert f"at level {LEVELS} of quantized-mesh EPSG:4326" in text, text
        assert "1 drawn from a coarser level" in text and "missing" not in text, text
        assert all(q.get("KEY") == KEY for _, q, _, _ in server.log)
        tiles = server.tiles_asked()
        want = _expected_tiles()
        assert GAP in want and GAP not in tiles  # never asked for
        parent = (LEVELS - 1, GAP[1] // 2, GAP[2] // 2)
        fetched = set(tiles) - ({(0, 1, 0), (10, GAP[1] >> 5, GAP[2] >> 5)} if metadata else set())
        assert fetched == (want - {GAP}) | {parent}, sorted(fetched ^ want)
        if metadata:  # the availability tiles, once each, before the rest
            assert tiles[:2] == [(0, 1, 0), (10, GAP[1] >> 5, GAP[2] >> 5)]
        accept = ACCEPT_METADATA if metadata else ACCEPT_NONE
        assert {a for p, a in server.heard if p.endswith(".terrain")} == {accept}
        assert server.modes == {0, 1, 2}  # gzip with and without the header, and plain
        # heights: the level-15 triangles, or the level-14 parent's in the tile drawn from it
        rng = np.random.default_rng(7)
        lat = LAT0 + rng.uniform(-0.0015, 0.0025, 10)
        lon = LON0 + rng.uniform(-0.002, 0.003, 10)
        d = tile_span(LEVELS)
        in_gap = (GAP[2] * d - 90 + 0.2 * d, GAP[1] * d - 180 + 0.5 * d)  # inside the gap tile
        points = [(a, b, LEVELS - (tms_tile(LEVELS, a, b) == GAP[1:])) for a, b in zip(lat, lon, strict=True)]  # fmt: skip
        _heights_match(layers, points + [(*in_gap, LEVELS - 1)])
        for f in tmp_path.rglob("*"):
            if f.is_file():
                assert KEY.encode() not in f.read_bytes(), f
        assert not any(KEY in m for m in notes.items)
        n = len(server.log)
        assert _build(world, tmp_path / "cache")[0] and len(server.log) == n  # warm: no request
    finally:
        server.stop()


def test_faults_are_said_once_naming_the_tile_and_the_source_without_the_key(mesh_server, tmp_path):
    want = sorted(_expected_tiles() - {GAP})
    corrupt, missing = want[0], want[-1]
    for (z, x, y), fault in ((corrupt, "corrupt"), (missing, "404")):
        mesh_server.faults[f"/qm/{z}/{x}/{y}.terrain"] = fault
    mesh_server.need_key = True
    world = _terrain(f"{mesh_server.base}/qm/layer.json?key={{key}}", key=KEY)
    layers, notes = _build(world, tmp_path / "cache")
    assert layers  # survived: those tiles drawn from their parents
    text = "\n".join(notes.items)
    label = f"world w terrain ({mesh_server.base.removeprefix('http://')}/qm/layer.json)"
    assert text.count("world w terrain (") == 1 and label in text, text
    z, x, y = corrupt
    assert f"1 not a readable quantized-mesh tile (corrupt) (first {z}/{x}/{y}: cut short" in text
    assert "1 missing (404" in text and KEY not in text
    # the layer.json itself: missing, not quantized-mesh, or with no tile over the clip: said,
    # and the flat ground kept
    mesh_server.need_key = False
    west_only = [[{"startX": 0, "startY": 0, "endX": 0, "endY": 0}]]  # the other hemisphere
    for path, doc in (("hm", {"format": "heightmap-1.0"}), ("west", {"available": west_only})):
        body = layer_json(**doc)
        mesh_server.routes[f"/{path}/layer.json"] = lambda p, q, body=body: (200, body, {})
    for path, said in (
        ("gone", "missing (HTTP 404)"),
        ("hm", "layer.json says format 'heightmap-1.0'"),
        ("west", "it lists no tile over the clip's area"),
    ):
        world = _terrain(f"{mesh_server.base}/{path}/layer.json")
        layers, notes = _build(world, tmp_path / "cache2")
        text = "\n".join(notes.items)
        assert layers == () and "flat ground" in text, text
        assert f"its layer.json could not be used: {said}" in text, text
    assert not any(p.startswith("/west/") and p != "/west/layer.json" for p, _ in mesh_server.heard)


def test_quantized_mesh_goes_into_no_archive(mesh_server, tmp_path):
    world = _terrain(f"{mesh_server.base}/qm/layer.json")
    (plan,) = plan_world(world, TRACK[:, 0], TRACK[:, 1], 300.0, 100.0, TileCache(tmp_path), 1e18)
    try:
        with pytest.raises(GeofuseError, match="quantized-mesh tiles go into no archive"):
            check_archive([Job(plan)], tmp_path / "area.gpkg")
    finally:
        plan.fetcher.close()


def test_a_clip_with_no_scene_stands_on_quantized_mesh_terrain(mesh_server, drone_clip):  # noqa: F811
    world = choose_world(terrain=f"{mesh_server.base}/qm/layer.json")
    session = open_clip(drone_clip, layers=(world_layer(world),))
    text = "\n".join(session.messages.items)
    assert "world given terrain: " in text and "above the ellipsoid" in text, text
    assert "assumed flat ground" not in text
    lat, lon = session.gnss.lat, session.gnss.lon
    for a, b in zip(lat, lon, strict=True):
        got = ellipsoidal_ground(session.mesh, session.frame, float(a), float(b))
        z = LEVELS - (tms_tile(LEVELS, a, b) == GAP[1:])
        bound = DEM_ERROR_M + triangle_bound(z) + height_step(z) + 0.01
        assert got is not None and abs(got - float(surface(a, b))) <= bound, (a, b, got)
