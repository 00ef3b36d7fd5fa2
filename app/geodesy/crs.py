"""Coordinate reference systems as files name them, and their vertical datum.

City models and DEMs declare their CRS in many spellings: `EPSG:7415`, an OGC URL
(`https://www.opengis.net/def/crs/EPSG/0/7415`), an OGC URN (`urn:ogc:def:crs:EPSG::25832`), a
compound of two (`urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::7837`, `EPSG:32632+3855`, the OGC
`crs-compound?1=...&2=...` URL) or the German AdV's (`urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH`).
`parse_crs` reads them all into a pyproj CRS; `vertical_datum` says which of the datums geofuse
converts exactly (app.geodesy.geoid) the heights are above.
"""

from __future__ import annotations

import re

import pyproj

from app.geodesy import geoid

# AdV (Germany) CRS names: horizontal and vertical parts -> EPSG codes
ADV_CRS = {
    "ETRS89_UTM32": 25832,
    "ETRS89_UTM33": 25833,
    "DE_DHHN2016_NH": 7837,
    "DE_DHHN92_NH": 5783,
}


def _single(text: str) -> int | None:
    """The EPSG code of one CRS reference (EPSG:n, an OGC URL or URN), None if not one."""
    m = re.search(r"EPSG(?:/\d+(?:\.\d+)*/|::?|:[\d.]*:)(\d+)\s*$", text.strip(), re.IGNORECASE)
    if m is None:
        m = re.fullmatch(r"\s*(\d+)\s*", text)
    return int(m.group(1)) if m else None


def _codes(text: str) -> list[int] | None:
    """The EPSG codes of a reference, one or two (horizontal, vertical); None if unrecognised."""
    t = text.strip()
    if "crs-compound" in t:
        parts = re.findall(r"\d=([^&]+)", t)
    elif t.lower().startswith("urn:ogc:def:crs,"):
        parts = t.split(",")[1:]
    elif t.lower().startswith("urn:adv:crs:"):
        names = t[len("urn:adv:crs:") :].split("*")
        codes = [ADV_CRS.get(n) for n in names]
        return None if None in codes else codes  # type: ignore[return-value]
    elif "+" in t:
        head, _, tail = t.partition("+")
        parts = [head, tail]
    else:
        parts = [t]
    codes = [_single(p) for p in parts]
    return None if not codes or None in codes else codes  # type: ignore[return-value]


def parse_crs(text: str) -> pyproj.CRS:
    """A pyproj CRS from any spelling above; a compound of two codes when two are given.
    Raises ValueError naming the text when it is not understood or unknown to PROJ."""
    codes = _codes(text)
    try:
        if codes is None:
            return pyproj.CRS.from_user_input(text)
        if len(codes) == 1:
            return pyproj.CRS.from_epsg(codes[0])
        parts = [pyproj.CRS.from_epsg(c) for c in codes]
        name = " + ".join(p.name for p in parts)
        return pyproj.crs.CompoundCRS(name, parts)
    except pyproj.exceptions.CRSError as exc:
        raise ValueError(f"unknown CRS {text!r} (expected an EPSG code, URL or URN)") from exc


def utm_zone(lat_deg: float, lon_deg: float) -> pyproj.CRS:
    """The WGS 84 UTM zone's CRS at a place (EPSG:326zz north of the equator, 327zz south)."""
    zone = int((lon_deg + 180.0) // 6) + 1
    return pyproj.CRS.from_epsg((32600 if lat_deg >= 0 else 32700) + zone)


def of_raster(crs: object) -> pyproj.CRS:
    """A rasterio CRS (a GeoTIFF's: anything with `to_wkt()`) as pyproj's."""
    return pyproj.CRS.from_wkt(crs.to_wkt())


def horizontal(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a CRS (the CRS itself when not compound)."""
    return crs.sub_crs_list[0] if crs.is_compound else crs


def vertical_part(crs: pyproj.CRS) -> pyproj.CRS | None:
    """The vertical CRS of a compound, None when the CRS has none."""
    parts = crs.sub_crs_list if crs.is_compound else [crs]
    return next((p for p in parts if p.is_vertical), None)


def vertical_datum(crs: pyproj.CRS) -> str | None:
    """'egm96', 'egm2008' or 'ellipsoid' when heights in this CRS are above one of them (a
    geographic 3D CRS: the ellipsoid); None when it names no vertical datum or another one
    (NAP, DHHN2016, NAVD88: see `vertical_name`)."""
    part = vertical_part(crs)
    if part is not None:
        code = part.to_epsg()
        if code in geoid.EPSG_VERTICAL:
            return geoid.EPSG_VERTICAL[code]
        name = part.name.lower()
        if "egm2008" in name or "egm08" in name:
            return "egm2008"
        if "egm96" in name:
            return "egm96"
        return None
    h = horizontal(crs)
    if h.to_epsg() == 4979 or (h.is_geographic and len(h.axis_info) == 3):
        return "ellipsoid"
    return None


def vertical_name(crs: pyproj.CRS) -> str | None:
    """The vertical datum's name as the CRS gives it (e.g. 'NAP height'), None if it has none."""
    part = vertical_part(crs)
    return None if part is None else part.name
