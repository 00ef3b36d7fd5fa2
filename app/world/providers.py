"""Well-known tile providers by name, with what their terms ask: `--imagery Esri.WorldImagery`,
`--terrain AWS.Terrarium`, or the same names in a settings file's `[[world]]` table.

Imagery providers come from xyzservices (the catalogue leaflet-providers keeps, about 900 of
them, each with its URL template, levels and attribution); the few it does not carry, terrain
tiles above all, are in OWN below, with the attribution their terms require. A provider whose
template holds a key placeholder (xyzservices' `requires_token`) takes its key from the settings
(`key_env`, `key`) or from the environment variable ROOT_KEY (MAPTILER_KEY for
MapTiler.Satellite): it is put for `{key}` when tiles are asked for and never written
(app.world.sources.TileSource.redact).

Providers whose usage policy forbids bulk download (NO_BULK: OpenStreetMap's own tile servers,
Esri's ArcGIS Online basemaps) are named so, and `geofuse cache` refuses them
(app.world.prefetch.refuse_bulk). Pure: no network here.
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Iterator
from dataclasses import dataclass

import xyzservices.providers as xyz
from xyzservices.lib import QUERY_NAME_TRANSLATION, TileProvider

from app.world import defaults

TOKEN_MARK = "<insert your"  # how xyzservices marks a key's placeholder (requires_token)
KEY = "{key}"  # where app.world.sources puts a source's key
WEB_MERCATOR = "EPSG:3857"
NAME_SUFFIXES_NOT = (".mbtiles", ".pmtiles", ".gpkg", ".tif", ".tiff")  # files, never names

# Hosts whose tile usage policy forbids bulk download, and why (matched with their subdomains).
NO_BULK = {
    "tile.openstreetmap.org": "OpenStreetMap's tile servers forbid bulk download (their tile usage policy)",
    "tile.osm.org": "OpenStreetMap's tile servers forbid bulk download (their tile usage policy)",
    "arcgisonline.com": "Esri's terms allow its ArcGIS Online basemaps offline only through its own "
    "products (no scraping, downloading or storing)",
}

AWS_TERRAIN_CREDIT = (
    "Terrain Tiles (Mapzen, on the Registry of Open Data on AWS): U.S. Geological Survey "
    "(3DEP, SRTM, GMTED2010), U.S. National Oceanic and Atmospheric Administration (ETOPO1), "
    "Copernicus EU-DEM and the other sources listed in tilezen/joerd docs/attribution.md"
)
EOX_2016_CREDIT = (
    "EOxCloudless https://cloudless.eox.at by EOX IT Services GmbH "
    "(Contains modified Copernicus Sentinel data 2016 & 2017), CC BY 4.0"
)


@dataclass(frozen=True)
class Provider:
    """One provider. kind: 'imagery' or 'terrain'; url: its XYZ template, with {key} where a
    key goes; attribution: the credit its terms ask for (plain text), html_attribution the same
    with its links; max_zoom: its finest level (None: not said); encoding and datum: a terrain's
    ('terrarium' heights above 'egm96'...); key_env: the environment variable that holds its key
    (None: it needs none); terms: one line on what they allow, where known."""

    name: str
    kind: str
    url: str
    attribution: str
    max_zoom: int | None = None
    encoding: str | None = None
    datum: str | None = None
    key_env: str | None = None
    html_attribution: str = ""
    terms: str = ""

    @property
    def spelling(self) -> str:
        """The source as app.world.sources.parse_source spells it (terrain: its encoding first)."""
        return f"{self.encoding}:{self.url}" if self.encoding else self.url

    @property
    def bulk_refused(self) -> str:
        """Why `geofuse cache` refuses it ('' where its terms do not forbid bulk download)."""
        return bulk_refusal(self.url)


# Providers xyzservices does not carry: open terrain tiles, and the imagery the defaults use
# (app.world.defaults says why each was chosen).
OWN = (
    Provider(
        "AWS.Terrarium",
        "terrain",
        "https://s3.amazonaws.com/elevation-tiles-prod/terrarium/{z}/{x}/{y}.png",
        AWS_TERRAIN_CREDIT,
        15,
        "terrarium",
        "egm96",  # SRTM, GMTED2010 and ETOPO1 heights are above EGM96 (3DEP's: NAVD88)
        terms="open data, no key; credit the sources (tilezen/joerd docs/attribution.md)",
    ),
    Provider(
        "EOX.Sentinel2Cloudless2016",
        "imagery",
        "https://tiles.maps.eox.at/wmts/1.0.0/s2cloudless_3857/default/g/{z}/{y}/{x}.jpg",
        EOX_2016_CREDIT,
        14,  # 10 m Sentinel-2 pixels: zoom 14 is 9.6 m a pixel at the equator
        terms="the 2016 layer under CC BY 4.0 with its credit (later years: CC BY-NC-SA 4.0)",
    ),
)


def key_env(name: str) -> str:
    """The environment variable that holds a provider's key: ROOT_KEY (MAPTILER_KEY)."""
    root = name.split(".", 1)[0]
    return "".join(c if c.isalnum() else "_" for c in root).upper() + "_KEY"


def bulk_refusal(url: str) -> str:
    """Why a source at `url` may not be pre-fetched in bulk ('' where nothing forbids it)."""
    host = (urllib.parse.urlsplit(url).hostname or "").lower()
    for h, why in NO_BULK.items():
        if host == h or host.endswith("." + h):
            return why
    return ""


def looks_like_name(text: str) -> bool:
    """Whether `text` may name a provider: no URL, no path, no prefix, no file suffix."""
    t = text.strip()
    return (
        bool(t) and not any(c in t for c in "/\\:{}") and not t.lower().endswith(NAME_SUFFIXES_NOT)
    )


def _from_xyz(tp: TileProvider) -> Provider | None:
    """A Provider of an xyzservices TileProvider; None where it cannot be one here (not in Web
    Mercator, more than one key, a placeholder it does not fill)."""
    if tp.get("crs", WEB_MERCATOR) != WEB_MERCATOR:
        return None
    tokens = [
        k for k, v in tp.items() if isinstance(v, str) and TOKEN_MARK in v and k in tp.get("url")
    ]
    if len(tokens) > 1:
        return None
    try:
        url = tp.build_url(**{t: KEY for t in tokens})
    except (KeyError, ValueError, IndexError):
        return None
    return Provider(
        tp.name,
        "imagery",
        url,
        str(tp.get("attribution") or ""),
        int(tp["max_zoom"]) if tp.get("max_zoom") is not None else None,
        key_env=key_env(tp.name) if tokens else None,
        html_attribution=str(tp.get("html_attribution") or ""),
    )


def _clean(name: str) -> str:
    return name.translate(QUERY_NAME_TRANSLATION).lower()


def find(name: str) -> Provider | None:
    """The provider called `name` (case, dots, spaces and dashes aside: 'Esri.WorldImagery',
    'esri worldimagery'), from OWN, else from xyzservices; None where none is, or where
    `name` is a URL or a file rather than a name."""
    if not looks_like_name(name):
        return None
    wanted = _clean(name)
    for p in OWN:
        if _clean(p.name) == wanted:
            return p
    try:
        tp = xyz.query_name(name)
    except ValueError:
        return None
    return _from_xyz(tp)


def catalogue(contains: str = "") -> Iterator[Provider]:
    """Every provider (OWN first, then xyzservices' in its order) whose name holds `contains`
    (case aside); those that cannot be used here (_from_xyz) left out."""
    needle = contains.lower()
    for p in OWN:
        if needle in p.name.lower():
            yield p
    for name, tp in xyz.flatten().items():
        if needle in name.lower():
            p = _from_xyz(tp)
            if p is not None:
                yield p


def describe(p: Provider) -> str:
    """One line for `geofuse cache --providers`: name, kind, levels, key, bulk, credit."""
    zoom = f"to z{p.max_zoom}" if p.max_zoom is not None else "z?"
    key = f"key in {p.key_env}" if p.key_env else "no key"
    bulk = "; no bulk download" if p.bulk_refused else ""
    kind = f"terrain ({p.encoding})" if p.kind == "terrain" else "imagery"
    used = (
        " (used with nothing configured)" if p.name in (defaults.IMAGERY, defaults.TERRAIN) else ""
    )
    return (
        f"{p.name}{used}  {kind}, {zoom}, {key}{bulk}: {p.attribution or '(no attribution given)'}"
    )
