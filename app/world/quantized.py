"""Cesium quantized-mesh-1.0 terrain: a `layer.json` read into the tile grid it addresses, the
URL of each tile and which tiles the server has; a tile's bytes decoded into its mesh and its
triangles sampled into a height grid. Pure (json, gzip, struct, numpy); the fetching, the cache
and the faults are app.world.fetch's.

The tile (github.com/CesiumGS/quantized-mesh, little-endian throughout):
- header, 88 bytes: the tile's centre (3 x float64, ECEF m), its lowest and highest heights
  (2 x float32, m above the WGS84 ellipsoid), a bounding sphere (centre 3 x float64, radius
  float64, ECEF m) and the horizon occlusion point (3 x float64, ellipsoid-scaled ECEF);
- vertex data: a uint32 count n, then n u, n v and n height values (uint16 each), each array
  delta- and zig-zag-encoded, decoding to 0..32767: u across the tile west to east, v south to
  north (linear in longitude and latitude, whatever the projection), height from the lowest to
  the highest;
- indices: 32-bit where n > 65536 (after padding to a 4-byte boundary), else 16-bit: a uint32
  triangle count and three indices a triangle, high-water-mark encoded; then the vertices on
  the west, south, east and north edges (a uint32 count each, indices not encoded);
- extensions to the end: a uint8 id, a uint32 length and that many bytes each (1: oct-encoded
  vertex normals, 2: a water mask, 4: metadata, a uint32 length and JSON whose `available`
  lists the tile ranges of the next levels). A tile may be gzipped (as static servers keep
  them, with or without Content-Encoding: gzip).

The layer (layer.json): `format` quantized-mesh-1.x; `tiles` URL templates with {z}, {x}, {y},
{version}, relative to the layer.json's URL, whose query goes with every tile (as CesiumJS
does); `projection` EPSG:4326 (the default: geodetic, level 0 is 2 x 1 tiles of 180 deg) or
EPSG:3857 (Web Mercator, one tile at level 0); `scheme` tms (the default: rows counted from the
south) or slippyMap (from the north); `available`: per level, the ranges of tiles (startX,
startY, endX, endY, in the scheme's rows) the server has; `metadataAvailability` m: the ranges of
levels L+1..L+m are in the metadata extension of the tiles of level L (L a multiple of m), asked
for only then; `extensions` offered; `maxzoom`. Tiles the layer says are not there are never
asked for.
"""

from __future__ import annotations

import json
import math
import struct
import urllib.parse
from dataclasses import dataclass, field

import numpy as np

from app.core.compression import DamagedGzip, gunzipped
from app.world.grids import Matrix, TileGrid, to_lonlat
from app.world.tiles import HALF_WORLD_M

QUANT_MAX = 32767  # u, v and height run 0..QUANT_MAX
HEADER = struct.Struct("<3d2f4d3d")  # centre, min/max height, sphere, horizon point: 88 bytes
INDEX_32_ABOVE = 65536  # more vertices than this: 32-bit indices
EXT_METADATA = 4  # the one extension read (1: oct-encoded normals, 2: a water mask: read past)
USED_EXTENSIONS = ("metadata",)  # what is asked for, where offered: availability; not normals
NOMINAL_PX = 65  # a tile's resolution for choosing levels: CesiumJS rates tiles as 65-px heightmaps
SAMPLES = 256  # samples a side of the height grid a tile is sampled into
DEFAULT_MAX_LEVEL = 20  # a layer.json saying neither maxzoom nor available
PROJECTIONS = ("EPSG:4326", "EPSG:3857")
SCHEMES = ("tms", "slippyMap")
CANDIDATES_A_CHUNK = 1 << 22  # (triangle, sample) pairs tested at once while sampling
ACCEPT = "application/vnd.quantized-mesh{ext},application/octet-stream;q=0.9,*/*;q=0.01"


class QuantizedMeshError(ValueError):
    """A tile or a layer.json that cannot be read; its text says what and where (never a URL:
    the caller names the source)."""


@dataclass(frozen=True)
class QuantizedMesh:
    """One decoded tile. u, v, h: (n,) int32 0..QUANT_MAX (u west to east, v south to north,
    h lowest to highest); triangles: (t, 3) int64 vertex indices; west, south, east, north:
    the vertices on each edge; extensions: id -> bytes, in the tile's order; center,
    sphere_center: ECEF m; min_height, max_height, sphere_radius: m; horizon_point: the
    ellipsoid-scaled ECEF point."""

    center: tuple[float, float, float]
    min_height: float
    max_height: float
    sphere_center: tuple[float, float, float]
    sphere_radius: float
    horizon_point: tuple[float, float, float]
    u: np.ndarray
    v: np.ndarray
    h: np.ndarray
    triangles: np.ndarray
    west: np.ndarray
    south: np.ndarray
    east: np.ndarray
    north: np.ndarray
    extensions: dict[int, bytes] = field(default_factory=dict)

    @property
    def heights(self) -> np.ndarray:
        """(n,) float64 m above the WGS84 ellipsoid of each vertex."""
        span = float(self.max_height) - float(self.min_height)
        return float(self.min_height) + span * self.h.astype(np.float64) / QUANT_MAX

    @property
    def metadata(self) -> dict | None:
        """The metadata extension's JSON, None without one. Raises QuantizedMeshError for one
        that does not read."""
        data = self.extensions.get(EXT_METADATA)
        if data is None:
            return None
        if len(data) < 4:
            raise QuantizedMeshError("its metadata extension is shorter than its length field")
        (n,) = struct.unpack_from("<I", data)
        if 4 + n > len(data):
            raise QuantizedMeshError("its metadata extension's JSON runs past the extension")
        try:
            doc = json.loads(data[4 : 4 + n].decode("utf-8")) if n else {}
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise QuantizedMeshError(f"its metadata extension is not JSON ({exc})") from None
        if not isinstance(doc, dict):
            raise QuantizedMeshError("its metadata extension is not a JSON object")
        return doc


def _gunzip(data: bytes) -> bytes:
    """`data` gunzipped where it starts as gzip does (servers keep tiles gzipped)."""
    try:
        return gunzipped(data)
    except DamagedGzip as exc:
        raise QuantizedMeshError(f"gzipped, but does not gunzip ({exc})") from None


def _zigzag_deltas(raw: np.ndarray) -> np.ndarray:
    """uint16 zig-zag-encoded deltas -> the running values (int32)."""
    r = raw.astype(np.int64)
    return np.cumsum((r >> 1) ^ -(r & 1)).astype(np.int32)


def _high_water_mark(codes: np.ndarray) -> np.ndarray:
    """High-water-mark-encoded indices -> indices: index = highest - code, the highest growing
    by one after each code 0."""
    c = codes.astype(np.int64)
    zero = (c == 0).astype(np.int64)
    return np.cumsum(zero) - zero - c


class _Reader:
    """Little-endian reads of a tile, naming the part that is cut short."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def take(self, n: int, what: str) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            left = len(self.data) - self.pos
            raise QuantizedMeshError(
                f"cut short in {what} (needs {n} bytes at {self.pos}, has {left})"
            )
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def uint32(self, what: str) -> int:
        return struct.unpack("<I", self.take(4, what))[0]

    def array(self, dtype: str, n: int, what: str) -> np.ndarray:
        size = np.dtype(dtype).itemsize
        return np.frombuffer(self.take(n * size, what), dtype=dtype).copy()


def decode_mesh(data: bytes, little_endian_extensions: bool = True) -> QuantizedMesh:
    """A quantized-mesh-1.0 tile's bytes (perhaps gzipped) -> its QuantizedMesh, every
    extension kept as bytes and skipped by its length. little_endian_extensions: False for the
    legacy `vertexnormals` servers, whose extension lengths are big-endian. Raises
    QuantizedMeshError saying what does not read."""
    r = _Reader(_gunzip(bytes(data)))
    head = HEADER.unpack(r.take(HEADER.size, "the header"))
    min_h, max_h = float(head[3]), float(head[4])
    if not (math.isfinite(min_h) and math.isfinite(max_h)) or max_h < min_h:
        raise QuantizedMeshError(f"its height range {min_h}..{max_h} is not one")
    n = r.uint32("the vertex count")
    if n < 3:
        raise QuantizedMeshError(f"{n} vertices make no triangle")
    u = _zigzag_deltas(r.array("<u2", n, "the vertices' u"))
    v = _zigzag_deltas(r.array("<u2", n, "the vertices' v"))
    h = _zigzag_deltas(r.array("<u2", n, "the vertices' heights"))
    for name, a in (("u", u), ("v", v), ("height", h)):
        if a.min() < 0 or a.max() > QUANT_MAX:
            raise QuantizedMeshError(f"a vertex's {name} decodes outside 0..{QUANT_MAX}")
    wide = n > INDEX_32_ABOVE
    dtype = "<u4" if wide else "<u2"
    if wide and r.pos % 4:
        r.take(4 - r.pos % 4, "the padding before the indices")
    t = r.uint32("the triangle count")
    tri = _high_water_mark(r.array(dtype, 3 * t, "the triangle indices"))
    if t and (tri.min() < 0 or tri.max() >= n):
        raise QuantizedMeshError(f"a triangle index decodes outside 0..{n - 1}")
    edges = []
    for side in ("west", "south", "east", "north"):
        k = r.uint32(f"the {side} edge's count")
        e = r.array(dtype, k, f"the {side} edge's indices").astype(np.int64)
        if k and e.max() >= n:
            raise QuantizedMeshError(f"a {side} edge index is past the {n} vertices")
        edges.append(e)
    extensions: dict[int, bytes] = {}
    length_format = "<I" if little_endian_extensions else ">I"
    while r.pos < len(r.data):
        ext = r.take(1, "an extension's id")[0]
        (length,) = struct.unpack(length_format, r.take(4, f"extension {ext}'s length"))
        extensions[ext] = r.take(length, f"extension {ext} ({length} bytes)")
    return QuantizedMesh(
        tuple(head[0:3]),
        min_h,
        max_h,
        tuple(head[5:8]),
        float(head[8]),
        tuple(head[9:12]),
        u,
        v,
        h,
        tri.reshape(-1, 3),
        *edges,
        extensions=extensions,
    )


def sample_heights(mesh: QuantizedMesh, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Heights (m above the ellipsoid, float64, NaN where no triangle covers) of the mesh's
    triangles, linearly interpolated, at the grid of u (C,) by v (R,) positions, fractions
    0..1 of the tile (u west to east, v south to north): (R, C), row i at v[i]."""
    us = np.asarray(u, np.float64) * QUANT_MAX
    vs = np.asarray(v, np.float64) * QUANT_MAX
    u_order, v_order = np.argsort(us), np.argsort(vs)
    us_sorted, vs_sorted = us[u_order], vs[v_order]
    out = np.full((len(vs), len(us)), np.nan)
    tri = mesh.triangles
    px, py = mesh.u.astype(np.float64)[tri], mesh.v.astype(np.float64)[tri]  # (t, 3)
    coef = _plane_coefficients(px, py, mesh.heights[tri])
    c0 = np.searchsorted(us_sorted, px.min(axis=1), "left")
    c1 = np.searchsorted(us_sorted, px.max(axis=1), "right")
    r0 = np.searchsorted(vs_sorted, py.min(axis=1), "left")
    r1 = np.searchsorted(vs_sorted, py.max(axis=1), "right")
    c0, r0 = c0.astype(np.int32), r0.astype(np.int32)
    nc, nr = np.maximum(c1 - c0, 0).astype(np.int32), np.maximum(r1 - r0, 0).astype(np.int32)
    count = np.where(np.isfinite(coef[:, 0]), nc * nr, 0)  # degenerate triangles cover nothing
    ends = np.cumsum(count)
    start = 0
    while start < len(count):
        done = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, done + CANDIDATES_A_CHUNK, "right")), start + 1)
        k = count[start:stop]
        total = int(k.sum())
        if total:
            t = np.repeat(np.arange(start, stop, dtype=np.int32), k)
            local = np.arange(total, dtype=np.int32) - np.repeat(
                (np.cumsum(k) - k).astype(np.int32), k
            )
            col = c0[t] + local % nc[t]
            row = r0[t] + local // nc[t]
            x, y, c = us_sorted[col], vs_sorted[row], coef[t]
            l0 = c[:, 0] * x + c[:, 1] * y + c[:, 2]
            l1 = c[:, 3] * x + c[:, 4] * y + c[:, 5]
            inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l0 + l1 <= 1.0 + 1e-9)
            z = c[:, 6] * x + c[:, 7] * y + c[:, 8]
            out[v_order[row[inside]], u_order[col[inside]]] = z[inside]
        start = stop
    return out


def _plane_coefficients(px: np.ndarray, py: np.ndarray, hz: np.ndarray) -> np.ndarray:
    """(t, 9) per triangle of corners (px, py) (t, 3) with heights hz (t, 3): the first two
    barycentric coordinates and the height as affine functions a * x + b * y + c of a position
    (x, y), (a, b, c) each; NaN for a triangle of no area."""
    den = (py[:, 1] - py[:, 2]) * (px[:, 0] - px[:, 2]) + (px[:, 2] - px[:, 1]) * (
        py[:, 0] - py[:, 2]
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        den = np.where(den != 0, den, np.nan)
        a0, b0 = (py[:, 1] - py[:, 2]) / den, (px[:, 2] - px[:, 1]) / den
        a1, b1 = (py[:, 2] - py[:, 0]) / den, (px[:, 0] - px[:, 2]) / den
    c0 = -(a0 * px[:, 2] + b0 * py[:, 2])
    c1 = -(a1 * px[:, 2] + b1 * py[:, 2])
    d0, d1 = hz[:, 0] - hz[:, 2], hz[:, 1] - hz[:, 2]
    return np.stack(
        [
            a0,
            b0,
            c0,
            a1,
            b1,
            c1,
            a0 * d0 + a1 * d1,
            b0 * d0 + b1 * d1,
            hz[:, 2] + c0 * d0 + c1 * d1,
        ],
        axis=1,
    )


@dataclass
class QuantizedLayer:
    """A layer.json read: its grid (app.world.grids; level z is index z, rows from the top), the
    absolute URL template of a tile ({z}, {x}, {y} left to fill), its scheme, the extensions it
    offers and those asked for, its attribution, and which tiles it has: ranges per level in
    grid rows (x0, y0, x1, y1 inclusive), from `available` and from the metadata of the tiles
    read so far (add_metadata)."""

    grid: TileGrid
    template: str
    scheme: str = "tms"
    offered: tuple[str, ...] = ()
    requested: tuple[str, ...] = ()
    attribution: str = ""
    metadata_levels: int | None = None
    little_endian_extensions: bool = True
    everywhere: bool = False  # no availability said at all: every tile up to the finest level
    ranges: list[list[tuple[int, int, int, int]]] = field(default_factory=list)
    loaded: set[tuple[int, int, int]] = field(default_factory=set)

    @property
    def max_level(self) -> int:
        return len(self.grid.matrices) - 1

    @property
    def accept(self) -> str:
        """The Accept header of a tile request, naming the extensions asked for."""
        return ACCEPT.format(
            ext=";extensions=" + "-".join(self.requested) if self.requested else ""
        )

    def server_row(self, z: int, y: int) -> int:
        """The row the server names for grid row y (from the top) of level z."""
        return self.grid.matrices[z].rows - 1 - y if self.scheme == "tms" else y

    def url(self, z: int, x: int, y: int) -> str:
        """The URL of tile column x, grid row y (from the top) of level z."""
        return (
            self.template.replace("{z}", str(z))
            .replace("{x}", str(x))
            .replace("{y}", str(self.server_row(z, y)))
        )

    def _listed(self, z: int, x: int, y: int) -> bool:
        if z >= len(self.ranges):
            return False
        return any(x0 <= x <= x1 and y0 <= y <= y1 for x0, y0, x1, y1 in self.ranges[z])

    def availability_tile(self, z: int, x: int, y: int) -> tuple[int, int, int] | None:
        """The tile whose metadata says whether (z, x, y) is there: the one of the level below
        z that is a multiple of metadataAvailability (z - m where z is one); None at level 0 or
        without metadataAvailability."""
        m = self.metadata_levels
        if not m or z == 0:
            return None
        p = z - m if z % m == 0 else (z // m) * m
        k = z - p
        return p, x >> k, y >> k

    def available(self, z: int, x: int, y: int) -> bool | None:
        """Whether the server has tile (z, x, y) (grid rows from the top); None while that
        depends on the metadata of a tile not read yet (to_load names it)."""
        if z > self.max_level or not (0 <= x < self.grid.matrices[z].cols):
            return False
        if not (0 <= y < self.grid.matrices[z].rows):
            return False
        if self.everywhere or self._listed(z, x, y):
            return True
        return None if self.to_load(z, x, y) is not None else False

    def to_load(self, z: int, x: int, y: int) -> tuple[int, int, int] | None:
        """The nearest availability tile above (z, x, y) that is there but whose metadata has not
        been read; None when none is left to read."""
        t = self.availability_tile(z, x, y)
        while t is not None:
            if t not in self.loaded and (self.everywhere or self._listed(*t)):
                return t
            t = self.availability_tile(*t)
        return None

    def add_metadata(self, z: int, x: int, y: int, metadata: dict | None) -> None:
        """The ranges of levels z+1.. that tile (z, x, y)'s metadata lists, added; the tile
        marked read (with or without metadata). Raises QuantizedMeshError for ranges that do
        not read."""
        self.loaded.add((z, x, y))
        if metadata and "available" in metadata:
            for offset, level in enumerate(metadata["available"]):
                self._add_level(z + offset + 1, level, "its metadata's available")

    def _add_level(self, z: int, level, where: str) -> None:
        if z > self.max_level:
            return
        if not isinstance(level, list):
            raise QuantizedMeshError(f"{where}: level {z} is not a list of ranges")
        while len(self.ranges) <= z:
            self.ranges.append([])
        rows = self.grid.matrices[z].rows
        for rng in level:
            try:
                x0, x1 = int(rng["startX"]), int(rng["endX"])
                s0, s1 = int(rng["startY"]), int(rng["endY"])
            except (KeyError, TypeError, ValueError):
                raise QuantizedMeshError(
                    f"{where}: level {z} has a range without startX, startY, endX and endY"
                ) from None
            y0, y1 = (rows - 1 - s1, rows - 1 - s0) if self.scheme == "tms" else (s0, s1)
            self.ranges[z].append((x0, y0, x1, y1))


def quantized_grid(projection: str, levels: int) -> TileGrid:
    """The tiling of a quantized-mesh layer in `projection` (PROJECTIONS), levels 0..levels:
    EPSG:4326 geodetic (2^(z+1) x 2^z tiles of 180 / 2^z deg), EPSG:3857 Web Mercator (2^z x
    2^z); each matrix NOMINAL_PX pixels a tile, rows from the top."""
    if projection == "EPSG:3857":
        span = 2.0 * HALF_WORLD_M
        matrices = [
            Matrix(str(z), span / (1 << z) / NOMINAL_PX, -HALF_WORLD_M, HALF_WORLD_M,
                   NOMINAL_PX, NOMINAL_PX, 1 << z, 1 << z)
            for z in range(levels + 1)
        ]  # fmt: skip
    else:
        matrices = [
            Matrix(str(z), 180.0 / (1 << z) / NOMINAL_PX, -180.0, 90.0, NOMINAL_PX, NOMINAL_PX,
                   2 << z, 1 << z)
            for z in range(levels + 1)
        ]  # fmt: skip
    return TileGrid(projection, tuple(matrices), f"quantized-mesh {projection}")


def tile_template(layer_url: str, template: str) -> str:
    """A layer.json's tile template made absolute against the layer.json's URL, with the
    layer.json's query parameters it lacks added (as given: a {key} stays a placeholder)."""
    base, _, query = layer_url.partition("?")
    out = urllib.parse.urljoin(base, template.strip())
    have = {k.lower() for k, _ in urllib.parse.parse_qsl(urllib.parse.urlsplit(out).query)}
    extra = [p for p in query.split("&") if p and p.split("=", 1)[0].lower() not in have]
    if not extra:
        return out
    return out + ("&" if "?" in out else "?") + "&".join(extra)


def read_layer(document: bytes, layer_url: str, max_level: int | None = None) -> QuantizedLayer:
    """The QuantizedLayer of a layer.json's bytes (perhaps gzipped), fetched from layer_url
    (tiles are relative to it); levels no finer than max_level. Raises QuantizedMeshError saying
    what is wrong (never naming the URL: the caller names the source)."""
    try:
        doc = json.loads(_gunzip(document).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise QuantizedMeshError(f"not a readable layer.json ({exc})") from None
    if not isinstance(doc, dict):
        raise QuantizedMeshError("not a layer.json (not a JSON object)")
    fmt = str(doc.get("format", ""))
    if not fmt.startswith("quantized-mesh-1."):
        said = f"format {fmt!r}" if fmt else "no format"
        raise QuantizedMeshError(f"layer.json says {said} (expected quantized-mesh-1.0)")
    tiles = doc.get("tiles")
    if not isinstance(tiles, list) or not tiles or not all(isinstance(t, str) for t in tiles):
        raise QuantizedMeshError("layer.json names no tile URL template (tiles)")
    projection = str(doc.get("projection") or "EPSG:4326").upper()
    if projection not in PROJECTIONS:
        raise QuantizedMeshError(
            f"layer.json's projection {projection} is not one of {', '.join(PROJECTIONS)}"
        )
    scheme = str(doc.get("scheme") or "tms")
    if scheme not in SCHEMES:
        raise QuantizedMeshError(f"layer.json's scheme {scheme!r} is not tms or slippyMap")
    available = doc.get("available")
    if available is not None and not isinstance(available, list):
        raise QuantizedMeshError("layer.json's available is not a list of levels")
    meta = doc.get("metadataAvailability")
    offered = tuple(str(e) for e in doc.get("extensions") or ())
    meta = int(meta) if isinstance(meta, int) and meta > 0 and "metadata" in offered else None
    top = doc.get("maxzoom")
    if not isinstance(top, int):
        top = len(available) - 1 if available else DEFAULT_MAX_LEVEL
    top = max(0, min(top, max_level if max_level is not None else top))
    version = str(doc.get("version") or "1.0.0")
    template = tile_template(layer_url, tiles[0].replace("{version}", version))
    layer = QuantizedLayer(
        quantized_grid(projection, top),
        template,
        scheme,
        offered,
        tuple(e for e in USED_EXTENSIONS if e in offered and meta),
        str(doc.get("attribution") or ""),
        meta,
        # the legacy 'vertexnormals' wrote its length big-endian; octvertexnormals replaced it
        not ("vertexnormals" in offered and "octvertexnormals" not in offered),
        everywhere=available is None and meta is None,
    )
    for z, level in enumerate(available or ()):
        layer._add_level(z, level, "layer.json's available")
    if meta and not layer._listed(0, 0, 0):
        layer._add_level(0, [{"startX": 0, "startY": 0, "endX": 1, "endY": 0}], "level 0")
    return layer


def tile_heights(layer: QuantizedLayer, mesh: QuantizedMesh, z: int, x: int, y: int,
                 size: int = SAMPLES) -> np.ndarray:  # fmt: skip
    """(size, size) heights (m above the ellipsoid) of tile (z, x, y) (grid rows from the top)
    at the centres of its grid's pixels of `size` a side, north row first: the mesh's v is
    linear in latitude, so a Web Mercator tile's rows are sampled at their latitudes."""
    m = layer.grid.matrices[z]
    frac = (np.arange(size) + 0.5) / size
    u = frac
    if layer.grid.crs == "EPSG:3857":
        _, ymin, _, ymax = m.tile_bounds(x, y)
        ys = np.concatenate([[ymin, ymax], ymax - frac * (ymax - ymin)])
        _, lat = to_lonlat(layer.grid.crs, np.zeros_like(ys), ys)
        v = (lat[2:] - lat[0]) / (lat[1] - lat[0])
    else:
        v = 1.0 - frac
    return sample_heights(mesh, u, v)
