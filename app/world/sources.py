"""Tile sources of a world: imagery and terrain, each from an XYZ/TMS URL template, an OGC WMTS
capabilities URL, a local MBTiles, GeoPackage or PMTiles archive, or a GeoTIFF/COG (over HTTP,
read by range requests, or local).

Spelling (as `--imagery`, `--terrain` and a settings file's `[[world]]` write it):
- imagery: `https://host/{z}/{x}/{y}.jpg` (XYZ rows, from the north), `tms:https://...` or
  `{-y}` in place of `{y}` (TMS rows, from the south), `PATH.mbtiles` (rows are TMS there),
  `PATH.pmtiles` (PMTiles v3), `PATH.gpkg` (GeoPackage tiles in its own tile matrix set; a
  table other than the first by `#table=NAME`), a WMTS capabilities URL (a GetCapabilities
  request, a path ending in WMTSCapabilities.xml, or any URL behind `wmts:`; options after it:
  `#layer=NAME&tilematrixset=ID&style=S&format=F`, app.world.wmts), or a GeoTIFF/COG
  (`https://host/ortho.tif`, or a local .tif);
- terrain: the same tiles behind `terrain-rgb:` (Mapbox/MapTiler: height = -10000 + (R * 65536 +
  G * 256 + B) * 0.1 m) or `terrarium:` (Tilezen/AWS: height = R * 256 + G + B / 256 - 32768 m),
  or a DEM GeoTIFF/COG as it is (`https://host/dem.tif`: its first band's heights, m), or
  Cesium quantized-mesh by its layer.json (`https://host/terrain/layer.json`, or
  `quantized-mesh:https://host/terrain`, the folder that holds it: app.world.quantized).
  Heights are taken as above the EGM2008 geoid unless the source says otherwise (`datum`);
  quantized-mesh heights as above the WGS84 ellipsoid, as the format has them.
Either may instead be a well-known provider's name (`Esri.WorldImagery`, `AWS.Terrarium`:
app.world.providers), its template, levels and attribution taken from the catalogue.
A template may hold `{key}`, and header values too: the key comes from an environment variable
(`key_env`) or the settings, is sent with every request and is never part of a label, a message
or a file written (`TileSource.redact`).
"""

from __future__ import annotations

import os
import urllib.parse
from dataclasses import dataclass, field

import numpy as np

from app.core.errors import GeofuseError
from app.world import providers

QUANTIZED_MESH = "quantized-mesh"  # the encoding and the form of a layer.json's terrain
ENCODINGS = ("terrain-rgb", "terrarium", QUANTIZED_MESH)
DATUMS = ("egm2008", "egm96", "ellipsoid")
DEFAULT_DATUM = "egm2008"
MAX_ZOOM = {"imagery": 19, "terrain": 15}
QUANTIZED_MAX_ZOOM = 24  # a layer.json's own maxzoom and availability decide, not this
FORMS = ("xyz", "wmts", "mbtiles", "pmtiles", "gpkg", "cog", QUANTIZED_MESH)  # how tiles are had
LAYER_JSON = "layer.json"
ARCHIVES = {".mbtiles": "mbtiles", ".pmtiles": "pmtiles", ".gpkg": "gpkg"}
GEOTIFF_SUFFIXES = (".tif", ".tiff")
SECRET_PARAMS = ("key", "token", "access_token", "apikey", "api_key", "sessiontoken")
TERRARIUM_NODATA = -32768.0  # (0, 0, 0): no height there
TERRAIN_RGB_NODATA_BELOW = -9999.0  # (0, 0, 0) decodes to -10000 m: no height there


class SourceError(GeofuseError):
    """A tile source spelt wrongly, or missing what it needs (its key's variable)."""


@dataclass(frozen=True)
class TileSource:
    """One tile source. kind: 'imagery' or 'terrain'; location: a URL template (with {z}, {x},
    {y} or {-y}, perhaps {key}), a layer.json URL or an MBTiles path; encoding: a terrain's
    'terrain-rgb', 'terrarium' or 'quantized-mesh' (None for imagery); scheme: 'xyz' or 'tms'
    rows; datum: a terrain's heights are above this ('egm2008', 'egm96', 'ellipsoid'); headers:
    (name, value) sent with every request, values perhaps holding {key}; key: the secret put for
    {key} (never shown); max_zoom: the finest level the source serves; form: how its tiles are
    had (FORMS; worked out from the location when not given)."""

    kind: str
    location: str
    encoding: str | None = None
    scheme: str = "xyz"
    attribution: str = ""
    datum: str = DEFAULT_DATUM
    headers: tuple[tuple[str, str], ...] = ()
    key: str | None = field(default=None, repr=False)
    max_zoom: int = 19
    form: str = ""

    def __post_init__(self) -> None:
        if not self.form:
            object.__setattr__(self, "form", location_form(self.location))

    @property
    def is_mbtiles(self) -> bool:
        return self.form == "mbtiles"

    @property
    def is_local(self) -> bool:
        """A file on this machine (an archive or a GeoTIFF), not an http(s) URL."""
        return not self.location.lower().startswith(("http://", "https://"))

    @property
    def web_mercator(self) -> bool:
        """Tiles addressed as XYZ Web Mercator (z, x, y): XYZ/TMS templates, MBTiles, PMTiles."""
        return self.form in ("xyz", "mbtiles", "pmtiles")

    def fill(self, url: str) -> str:
        """`url` with the key put for {key}."""
        return url.replace("{key}", urllib.parse.quote(self.key or "", safe=""))

    def url(self, z: int, x: int, y: int) -> str:
        """The request's URL for XYZ tile (z, x, y), the key put in."""
        row = (1 << z) - 1 - y if self.scheme == "tms" else y
        url = (
            self.location.replace("{z}", str(z))
            .replace("{x}", str(x))
            .replace("{y}", str(row))
            .replace("{-y}", str((1 << z) - 1 - y))
        )
        return self.fill(url)

    def request_headers(self) -> dict[str, str]:
        """The headers sent with every request, the key put in."""
        return {k: v.replace("{key}", self.key or "") for k, v in self.headers}

    @property
    def secrets(self) -> tuple[str, ...]:
        """What must never be written: the key, and any secret query value in the template."""
        out = [self.key] if self.key else []
        query = urllib.parse.urlsplit(self.location).query
        out += [
            v
            for k, v in urllib.parse.parse_qsl(query)
            if k.lower() in SECRET_PARAMS and v and "{" not in v
        ]
        return tuple(out)

    def redact(self, text: str) -> str:
        """`text` with every secret of this source replaced by '***'."""
        for secret in self.secrets:
            text = text.replace(secret, "***").replace(urllib.parse.quote(secret, safe=""), "***")
        return text

    @property
    def label(self) -> str:
        """The source as messages name it: its host and path (a file by its name), no query."""
        if self.is_local:
            return self.location.replace("\\", "/").rsplit("/", 1)[-1]
        parts = urllib.parse.urlsplit(self.location)
        layer = split_options(self.location)[1].get("layer") if self.form == "wmts" else None
        return self.redact(f"{parts.netloc}{parts.path}" + (f" layer {layer}" if layer else ""))

    @property
    def identity(self) -> str:
        """What names the source's tiles in the cache: its template or file as given, with
        {key} unfilled and any literal secret redacted, its encoding and scheme."""
        return self.redact(f"{self.kind}|{self.encoding}|{self.scheme}|{self.location}")


def parse_source(
    text: str,
    kind: str,
    attribution: str = "",
    datum: str | None = None,
    headers: dict[str, str] | None = None,
    key: str | None = None,
    max_zoom: int | None = None,
) -> TileSource:
    """A TileSource from its spelling (module docstring). kind: 'imagery' or 'terrain'. Raises
    SourceError saying what is expected."""
    text = text.strip()
    named = providers.find(text)  # a well-known provider by its name (app.world.providers)
    if named is not None:
        return _provider_source(named, kind, attribution, datum, headers, key, max_zoom)
    encoding = None
    scheme = "xyz"
    for prefix in ENCODINGS:
        if text.lower().startswith(prefix + ":"):
            encoding, text = prefix, text[len(prefix) + 1 :]
    form = ""
    if text.lower().startswith("tms:"):
        scheme, text = "tms", text[4:]
    elif text.lower().startswith("wmts:"):
        form, text = "wmts", text[5:]
    what = f"{kind} source"
    is_url = text.lower().startswith(("http://", "https://"))
    if form == "wmts" and not is_url:
        raise SourceError(f"{what} {_shown(text)!r}: wmts: goes before a capabilities URL")
    if encoding == QUANTIZED_MESH:
        if not is_url:
            raise SourceError(
                f"{what} {_shown(text)!r}: quantized-mesh: goes before the http(s) URL of a "
                "layer.json or of the folder that holds it"
            )
        text, form = layer_json_url(text), QUANTIZED_MESH
    try:
        form = form or location_form(text)
    except SourceError as exc:
        raise SourceError(f"{what} {_shown(text)!r}: {exc}") from None
    if form == QUANTIZED_MESH:
        if kind == "imagery":
            raise SourceError(
                f"{what}: a quantized-mesh layer.json is terrain (--terrain), not imagery"
            )
        if encoding not in (None, QUANTIZED_MESH):
            raise SourceError(f"{what}: a quantized-mesh layer.json holds meshes: drop {encoding}:")
        encoding = QUANTIZED_MESH
    if kind == "terrain" and encoding is None and form != "cog":
        raise SourceError(
            f"{what} {_shown(text)!r}: name its encoding, e.g. terrain-rgb:URL or terrarium:URL "
            "(PNG tiles; a local .mbtiles, .pmtiles or .gpkg of them, or a WMTS of them, too), "
            "or give a DEM GeoTIFF (.tif) or a quantized-mesh layer.json URL"
        )
    if kind == "terrain" and encoding is not None and form == "cog":
        raise SourceError(f"{what}: a DEM GeoTIFF holds heights: drop {encoding}:")
    if kind == "imagery" and encoding is not None:
        raise SourceError(f"{what}: {encoding}: is for terrain (--terrain), not imagery")
    if form == "xyz" and (
        "{z}" not in text or "{x}" not in text or ("{y}" not in text and "{-y}" not in text)
    ):
        raise SourceError(
            f"{what} {_shown(text)!r}: a URL template needs {{z}}, {{x}} and {{y}} (or {{-y}}); "
            "a WMTS is named by its capabilities URL (or wmts:URL), a COG by its .tif URL"
        )
    if form == "mbtiles":
        scheme = "tms"  # MBTiles rows count from the south (the spec's TMS)
    datum = (datum or ("ellipsoid" if form == QUANTIZED_MESH else DEFAULT_DATUM)).lower()
    if datum not in DATUMS:
        raise SourceError(f"{what}: datum {datum!r} unknown (expected one of {', '.join(DATUMS)})")
    if ("{key}" in text or any("{key}" in v for v in (headers or {}).values())) and not key:
        raise SourceError(
            f"{what} {_shown(text)!r}: the template holds {{key}} but no key is given (key_env names the environment variable that holds it)"
        )
    return TileSource(
        kind,
        text,
        encoding,
        scheme,
        attribution,
        datum,
        tuple((headers or {}).items()),
        key,
        max_zoom
        if max_zoom is not None
        else QUANTIZED_MAX_ZOOM
        if form == QUANTIZED_MESH
        else MAX_ZOOM[kind],
        form,
    )


def _provider_source(
    p: providers.Provider,
    kind: str,
    attribution: str,
    datum: str | None,
    headers: dict[str, str] | None,
    key: str | None,
    max_zoom: int | None,
) -> TileSource:
    """A provider of the catalogue as a source: its template, finest level, credit (the one
    given replaces it) and terrain encoding; its key the one given, else its environment
    variable's (providers.key_env)."""
    if p.kind != kind:
        raise SourceError(f"{kind} source {p.name}: it is {p.kind} (--{p.kind} {p.name})")
    if p.key_env and not key:
        key = os.environ.get(p.key_env) or None
        if key is None:
            raise SourceError(
                f"{kind} source {p.name}: it needs a key: set the environment variable "
                f"{p.key_env} (or name another in key_env of its [[world]] table)"
            )
    return parse_source(
        p.spelling,
        kind,
        attribution or p.attribution,
        datum or p.datum,
        headers,
        key,
        max_zoom if max_zoom is not None else p.max_zoom,
    )


def layer_json_url(url: str) -> str:
    """The layer.json URL of a quantized-mesh source spelt by its folder's URL (or by the
    layer.json's own), its query kept."""
    base, sep, query = url.partition("?")
    if not base.lower().endswith("/" + LAYER_JSON):
        base = base.rstrip("/") + "/" + LAYER_JSON
    return base + sep + query


def split_options(location: str) -> tuple[str, dict[str, str]]:
    """(location, {option: value}) of a location with `#name=value&...` options after it (a
    WMTS's layer, a GeoPackage's table); option names lower case."""
    base, _, fragment = location.partition("#")
    return base, {k.lower(): v for k, v in urllib.parse.parse_qsl(fragment)}


def is_capabilities(url: str) -> bool:
    """Whether an http(s) URL names a WMTS capabilities document rather than a tile template:
    a GetCapabilities request, or a path ending in WMTSCapabilities.xml or /wmts."""
    parts = urllib.parse.urlsplit(split_options(url)[0])
    query = {k.lower(): v.lower() for k, v in urllib.parse.parse_qsl(parts.query)}
    path = parts.path.lower().rstrip("/")
    return (
        query.get("request") == "getcapabilities"
        or path.endswith("wmtscapabilities.xml")
        or path.endswith("/wmts")
    )


def location_form(location: str) -> str:
    """Which of FORMS a location names (module docstring); raises SourceError for none."""
    text = location.strip()
    if text.lower().startswith(("http://", "https://")):
        if is_capabilities(text):
            return "wmts"
        path = urllib.parse.urlsplit(text).path.lower()
        if path.endswith("/" + LAYER_JSON):
            return QUANTIZED_MESH
        return "cog" if path.endswith(GEOTIFF_SUFFIXES) else "xyz"
    suffix = "." + split_options(text)[0].lower().rsplit(".", 1)[-1]
    if suffix in ARCHIVES:
        return ARCHIVES[suffix]
    if suffix in GEOTIFF_SUFFIXES:
        return "cog"
    raise SourceError(
        "expected an http(s) URL template with {z}/{x}/{y}, a WMTS capabilities URL, a "
        "quantized-mesh layer.json URL, a GeoTIFF/COG (.tif, local or http(s)) or a local "
        ".mbtiles, .pmtiles or .gpkg file"
    )


def _shown(text: str) -> str:
    """A location as an error names it: any secret query value redacted."""
    return TileSource("imagery", text, form="xyz").redact(text)


def decode_heights(rgb: np.ndarray, encoding: str) -> np.ndarray:
    """Heights (m, float64, NaN where the tile says none) of an (H, W, 3) uint8 tile."""
    c = np.asarray(rgb, np.float64)
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    if encoding == "terrain-rgb":
        h = -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1
        return np.where(h < TERRAIN_RGB_NODATA_BELOW, np.nan, h)
    if encoding == "terrarium":
        h = r * 256.0 + g + b / 256.0 - 32768.0
        return np.where(h <= TERRARIUM_NODATA, np.nan, h)
    raise ValueError(f"unknown terrain encoding {encoding!r}")


def encode_heights(heights: np.ndarray, encoding: str) -> np.ndarray:
    """(H, W, 3) uint8 of heights (m): the inverse of decode_heights (to 0.1 m for Terrain-RGB,
    1/256 m for Terrarium); for writing tiles (tests, pre-fetched archives)."""
    h = np.asarray(heights, np.float64)
    if encoding == "terrain-rgb":
        v = np.round((h + 10000.0) * 10.0).astype(np.int64)
        return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=-1).astype(np.uint8)
    if encoding == "terrarium":
        v = np.round((h + 32768.0) * 256.0).astype(np.int64)
        return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], axis=-1).astype(np.uint8)
    raise ValueError(f"unknown terrain encoding {encoding!r}")
