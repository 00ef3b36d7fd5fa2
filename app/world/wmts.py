"""OGC WMTS 1.0.0: a capabilities document (read with owslib) -> the tile grid of the chosen
layer's TileMatrixSet and the URL of each of its tiles, KVP or REST.

The layer: the document's first, or `#layer=NAME` after the capabilities URL; its matrix set:
the first the layer links, or `#tilematrixset=ID`; its style: the default one, or `#style=S`;
its format: the first, or `#format=image/png` (several joined by `&`). Tile maths from each
TileMatrix as the standard gives it: a pixel is ScaleDenominator x 0.28 mm on the ground, in
CRS units of metresPerUnit (a degree: 2 pi a / 360); TopLeftCorner in the CRS's axis order
(latitude first for EPSG:4326), read here into (x, y); TileWidth, MatrixWidth as given. The
tiles are asked for as the capabilities URL was: by KVP GetTile where it was a KVP request (a
`request=GetCapabilities` query) and the service offers KVP, else by the layer's REST
ResourceURL template, else whichever the service offers. Query parameters of the capabilities
URL that carry a key (app.world.sources.SECRET_PARAMS) go with every tile request too.
"""

from __future__ import annotations

import urllib.parse
from dataclasses import dataclass

from owslib.wmts import WebMapTileService

from app.world.grids import Matrix, TileGrid, crs_of, metres_per_unit
from app.world.sources import SECRET_PARAMS, split_options

PIXEL_M = 0.28e-3  # the standard's rendering pixel, m (OGC 07-057r7, 6.1)
KVP_PARAMS = ("layer", "style", "format", "tilematrixset")


class WmtsError(ValueError):
    """A capabilities document that cannot be used: not WMTS, no such layer or matrix set, no
    way to ask for tiles. Its text names what is missing."""


@dataclass(frozen=True)
class WmtsLayer:
    """A layer's tiles: its grid (app.world.grids) and the URL template of a tile, with
    {TileMatrix}, {TileRow}, {TileCol} left to fill (and {key}, where the source holds one)."""

    layer: str
    matrix_set: str
    format: str
    grid: TileGrid
    template: str
    encoding: str  # "KVP" or "REST"

    def url(self, z: int, x: int, y: int) -> str:
        """The URL of column x, row y (from the top) of level z (the grid's index)."""
        return (
            self.template.replace("{TileMatrix}", urllib.parse.quote(self.grid.matrices[z].ident))
            .replace("{TileRow}", str(y))
            .replace("{TileCol}", str(x))
        )


def matrix_set_grid(tms) -> TileGrid:
    """A TileGrid of an owslib TileMatrixSet (its matrices sorted coarsest first)."""
    try:
        crs = crs_of(tms.crs)
    except Exception as exc:  # pyproj's CRSError and what PROJ raises for a URN it misreads
        raise WmtsError(f"tile matrix set {tms.identifier}: unknown CRS {tms.crs!r}") from exc
    mpu = metres_per_unit(crs)
    lat_first = crs.axis_info[0].direction.lower() in ("north", "south")
    matrices = []
    for m in tms.tilematrix.values():
        a, b = m.topleftcorner
        left, top = (b, a) if lat_first else (a, b)
        matrices.append(
            Matrix(
                m.identifier,
                m.scaledenominator * PIXEL_M / mpu,
                left,
                top,
                m.tilewidth,
                m.tileheight,
                m.matrixwidth,
                m.matrixheight,
            )
        )
    if not matrices:
        raise WmtsError(f"tile matrix set {tms.identifier} has no tile matrix")
    matrices.sort(key=lambda m: -m.res)
    return TileGrid(crs.to_wkt(), tuple(matrices), tms.identifier)


def read_layer(document: bytes, location: str) -> WmtsLayer:
    """The layer a capabilities URL (with its `#...` options) chooses, from its document.
    Raises WmtsError saying what is wrong (never naming the URL: the caller names the source)."""
    url, options = split_options(location)
    try:
        service = WebMapTileService(url, xml=document)
    except Exception as exc:  # lxml's XMLSyntaxError, owslib's ValueError/KeyError/ServiceException
        detail = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise WmtsError(f"not a readable WMTS capabilities document ({detail})") from exc
    if not service.contents:
        raise WmtsError("the capabilities name no layer")
    name = options.get("layer") or next(iter(service.contents))
    if name not in service.contents:
        raise WmtsError(f"no layer {name!r} (it offers {', '.join(list(service.contents)[:10])})")
    layer = service.contents[name]
    links = list(layer.tilematrixsetlinks)
    set_id = options.get("tilematrixset") or (links[0] if links else None)
    if set_id is None or set_id not in service.tilematrixsets:
        offered = ", ".join(links) or "none"
        raise WmtsError(f"layer {name}: no tile matrix set {set_id!r} (it links {offered})")
    grid = matrix_set_grid(service.tilematrixsets[set_id])
    style = options.get("style") or next(
        (s for s, v in layer.styles.items() if v.get("isDefault")),
        next(iter(layer.styles), "default"),
    )
    fmt = options.get("format") or (layer.formats[0] if layer.formats else "image/png")
    dims = {
        k: v.get("default") or (v.get("values") or [""])[0] for k, v in layer.dimensions.items()
    }
    kvp = _kvp_href(service)
    rest = next(
        (
            r["template"]
            for r in layer.resourceURLs
            if r.get("resourceType") == "tile" and r.get("format") == fmt
        ),
        next((r["template"] for r in layer.resourceURLs if r.get("resourceType") == "tile"), None),
    )
    asked_kvp = "request" in {
        k.lower() for k, _ in urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query)
    }
    if kvp is not None and (asked_kvp or rest is None):
        fixed = {"layer": name, "style": style, "format": fmt, "tilematrixset": set_id}
        query = "&".join(
            ["SERVICE=WMTS", "REQUEST=GetTile", "VERSION=1.0.0"]
            + [f"{k.upper()}={urllib.parse.quote(fixed[k], safe='')}" for k in KVP_PARAMS]
            + [f"{k}={urllib.parse.quote(str(v), safe='')}" for k, v in dims.items()]
            + ["TILEMATRIX={TileMatrix}", "TILEROW={TileRow}", "TILECOL={TileCol}"]
        )
        template, encoding = kvp + ("&" if "?" in kvp else "?") + query, "KVP"
        template = template.replace("?&", "?")
    elif rest is not None:
        template = urllib.parse.urljoin(url, rest)
        for k, v in {"Style": style, "TileMatrixSet": set_id, "Layer": name, **dims}.items():
            template = template.replace("{" + k + "}", urllib.parse.quote(str(v), safe=""))
        left = [p for p in ("{TileMatrix}", "{TileRow}", "{TileCol}") if p not in template]
        if left:
            raise WmtsError(f"layer {name}: its ResourceURL template lacks {', '.join(left)}")
        encoding = "REST"
    else:
        raise WmtsError(
            f"layer {name}: the service offers neither KVP GetTile nor a tile ResourceURL"
        )
    return WmtsLayer(name, set_id, fmt, grid, _with_secrets(template, url), encoding)


def _kvp_href(service: WebMapTileService) -> str | None:
    """The GetTile operation's HTTP GET address offering KVP, None without one."""
    for op in getattr(service, "operations", []):
        if getattr(op, "name", None) != "GetTile":
            continue
        for method in op.methods:
            if method.get("type", "").lower() != "get":
                continue
            encodings = [
                v for c in method.get("constraints", []) for v in (getattr(c, "values", None) or [])
            ]
            if not encodings or any(e.upper() == "KVP" for e in encodings):
                return method["url"]
    return None


def _with_secrets(template: str, capabilities_url: str) -> str:
    """The template with the capabilities URL's key-carrying query parameters added where it
    lacks them (a key asked for the capabilities is asked for every tile)."""
    given = urllib.parse.parse_qsl(urllib.parse.urlsplit(capabilities_url).query)
    have = {k.lower() for k, _ in urllib.parse.parse_qsl(urllib.parse.urlsplit(template).query)}
    extra = [(k, v) for k, v in given if k.lower() in SECRET_PARAMS and k.lower() not in have]
    if not extra:
        return template
    tail = "&".join(f"{k}={v}" for k, v in extra)  # as given: {key} stays a placeholder
    return template + ("&" if "?" in template else "?") + tail
