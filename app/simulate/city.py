"""Write city models: LoD2 buildings as CityJSON, CityJSON Sequences and CityGML 2.0/3.0.

Used by the tests (a few buildings at known coordinates in a compound CRS; a district of 100,000
for bounded memory), by `geofuse simulate city` (the sample site's buildings as the LoD2 model a
city would publish: no texture, UTM and EGM2008 heights) and the demos. A building is a prism
with a flat roof: a footprint of four corners counter-clockwise seen from above, in the CRS's
horizontal units (`Building.box` for an axis-aligned rectangle), a ground height and a roof
height in its vertical datum; its LoD2 solid has a ground, a roof and four walls with their
semantics, outward-facing (exterior rings counter-clockwise seen from outside).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from app.geodesy.crs import utm_zone
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.simulate.stadium import BUILDINGS, GROUND_HALF, HALL_MAX, HALL_MIN


@dataclass(frozen=True)
class Building:
    """A flat-roofed prism. footprint: four (x, y) corners counter-clockwise seen from above,
    CRS units; ground_z, roof_z: heights in the CRS's vertical datum; attributes as CityJSON
    holds them."""

    id: str
    footprint: tuple[tuple[float, float], ...]
    ground_z: float
    roof_z: float
    attributes: dict | None = None

    @classmethod
    def box(
        cls,
        id: str,
        rect: tuple[float, float, float, float],
        ground_z: float,
        roof_z: float,
        attributes: dict | None = None,
    ) -> Building:
        """An axis-aligned box over rect = (x0, y0, x1, y1)."""
        x0, y0, x1, y1 = rect
        return cls(id, ((x0, y0), (x1, y0), (x1, y1), (x0, y1)), ground_z, roof_z, attributes)

    def corners(self) -> np.ndarray:
        """(8, 3): the four ground corners, then the roof's above them."""
        ring = self.footprint
        return np.array(
            [(x, y, self.ground_z) for x, y in ring] + [(x, y, self.roof_z) for x, y in ring]
        )


# The solid's faces as corner indices (outward, counter-clockwise seen from outside), with kinds
FACES = (
    ((0, 3, 2, 1), "GroundSurface"),
    ((4, 5, 6, 7), "RoofSurface"),
    ((0, 1, 5, 4), "WallSurface"),
    ((1, 2, 6, 5), "WallSurface"),
    ((2, 3, 7, 6), "WallSurface"),
    ((3, 0, 4, 7), "WallSurface"),
)
SEMANTIC_TYPES = ("GroundSurface", "RoofSurface", "WallSurface")


def district(
    count: int, origin_xy: tuple[float, float], spacing: float = 30.0, seed: int = 0
) -> Iterable[Building]:
    """`count` buildings on a square grid `spacing` apart from origin_xy, 8-20 m wide, 6-30 m
    tall, ground at 0-5 m: a district to open with bounded memory."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(count)))
    for i in range(count):
        x = origin_xy[0] + (i % side) * spacing
        y = origin_xy[1] + (i // side) * spacing
        w, d = rng.uniform(8.0, 20.0, 2)
        ground = float(rng.uniform(0.0, 5.0))
        yield Building.box(
            f"b{i}",
            (round(x, 3), round(y, 3), round(x + w, 3), round(y + d, 3)),
            round(ground, 3),
            round(ground + float(rng.uniform(6.0, 30.0)), 3),
            {"measuredHeight": 10.0, "function": "residential"},
        )


def _object(b: Building, first_vertex: int, lod: str = "2.2") -> dict:
    faces = [[[first_vertex + i for i in f]] for f, _ in FACES]
    return {
        "type": "Building",
        "attributes": dict(b.attributes or {}),
        "geometry": [
            {
                "type": "Solid",
                "lod": lod,
                "boundaries": [faces],
                "semantics": {
                    "surfaces": [{"type": t} for t in SEMANTIC_TYPES],
                    "values": [[SEMANTIC_TYPES.index(k) for _, k in FACES]],
                },
            }
        ],
    }


def _quantised(corners: np.ndarray, scale: float, translate: np.ndarray) -> list[list[int]]:
    return np.round((corners - translate) / scale).astype(np.int64).tolist()


@dataclass(frozen=True)
class Relief:
    """Flat terrain: a quadrilateral ring (four (x, y) corners counter-clockwise from above) at
    height z, as a TINRelief of two triangles."""

    id: str
    ring: tuple[tuple[float, float], ...]
    z: float

    def object(self, first_vertex: int) -> tuple[dict, list[tuple[float, float, float]]]:
        a, b, c, d = (first_vertex + i for i in range(4))
        geometry = {
            "type": "CompositeSurface",
            "lod": "1",
            "boundaries": [[[a, b, c]], [[a, c, d]]],
        }
        return {"type": "TINRelief", "geometry": [geometry]}, [(x, y, self.z) for x, y in self.ring]


def _entries(
    buildings: Iterable[Building], relief: Relief | None, scale: float, translate: np.ndarray
) -> Iterable[tuple[str, dict, list[list[int]]]]:
    """(id, CityJSON object, its quantised vertices) of each building and the relief, the
    objects' vertex indices counted on from the ones before."""
    count = 0
    for b in buildings:
        vertices = _quantised(b.corners(), scale, translate)
        yield b.id, _object(b, count), vertices
        count += len(vertices)
    if relief is not None:
        obj, corners = relief.object(count)
        yield relief.id, obj, _quantised(np.array(corners), scale, translate)


def cityjson(
    buildings: Iterable[Building],
    crs: str,
    version: str = "2.0",
    scale: float = 0.001,
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0),
    relief: Relief | None = None,
) -> dict:
    """A CityJSON document (as a dict) of the buildings (and a relief), vertices quantised by
    `scale` about `translate` (the file's `transform`); crs: the `referenceSystem` as written."""
    t = np.asarray(translate, np.float64)
    objects, vertices = {}, []
    for oid, obj, v in _entries(buildings, relief, scale, t):
        objects[oid] = obj
        vertices += v
    return {
        "type": "CityJSON",
        "version": version,
        "transform": {"scale": [scale] * 3, "translate": t.tolist()},
        "metadata": {"referenceSystem": crs},
        "CityObjects": objects,
        "vertices": vertices,
    }


def write_cityjson(path: Path, buildings: Iterable[Building], crs: str, **options) -> Path:
    """The buildings (and a relief) as a CityJSON file (as `cityjson` makes it, same options),
    written object by object and then the vertices, so that a district of any size is written
    in little memory."""
    head = cityjson([], crs, **{**options, "relief": None})
    del head["CityObjects"], head["vertices"]
    scale, t = head["transform"]["scale"][0], np.asarray(head["transform"]["translate"])
    with path.open("w") as f:
        f.write(json.dumps(head)[:-1] + ', "CityObjects": {')
        vertices: list[list[int]] = []
        for i, (oid, obj, v) in enumerate(_entries(buildings, options.get("relief"), scale, t)):
            f.write(f"{',' if i else ''}{json.dumps(oid)}:{json.dumps(obj, separators=(',', ':'))}")
            vertices += v
        f.write('}, "vertices": ' + json.dumps(vertices, separators=(",", ":")) + "}")
    return path


def write_cityjsonseq(
    path: Path,
    buildings: Iterable[Building],
    crs: str,
    scale: float = 0.001,
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Path:
    """The buildings as a CityJSON Sequence (.city.jsonl): a header line, then one
    CityJSONFeature a line with its own vertices, written as they come (any count)."""
    t = np.asarray(translate, np.float64)
    header = cityjson([], crs, scale=scale, translate=translate)
    with path.open("w") as f:
        f.write(json.dumps(header) + "\n")
        for b in buildings:
            feature = {
                "type": "CityJSONFeature",
                "id": b.id,
                "CityObjects": {b.id: _object(b, 0)},
                "vertices": _quantised(b.corners(), scale, t),
            }
            f.write(json.dumps(feature, separators=(",", ":")) + "\n")
    return path


CITYGML_NS = {
    "2.0": {
        "core": "http://www.opengis.net/citygml/2.0",
        "bldg": "http://www.opengis.net/citygml/building/2.0",
        "gen": "http://www.opengis.net/citygml/generics/2.0",
    },
    "3.0": {
        "core": "http://www.opengis.net/citygml/3.0",
        "bldg": "http://www.opengis.net/citygml/building/3.0",
        "gen": "http://www.opengis.net/citygml/generics/3.0",
        "con": "http://www.opengis.net/citygml/construction/3.0",
    },
}
GML_NS = "http://www.opengis.net/gml"
GML32_NS = "http://www.opengis.net/gml/3.2"


def _poslist(points: np.ndarray) -> str:
    closed = np.vstack([points, points[:1]])
    return " ".join(f"{v:.3f}" for v in closed.ravel())


def _citygml_building(b: Building, version: str) -> str:
    corners = b.corners()
    surfaces = []
    for i, (face, kind) in enumerate(FACES):
        polygon = (
            f'<gml:Polygon gml:id="{b.id}_p{i}"><gml:exterior><gml:LinearRing gml:id="{b.id}_p{i}_r0">'
            f'<gml:posList srsDimension="3">{_poslist(corners[list(face)])}</gml:posList>'
            "</gml:LinearRing></gml:exterior></gml:Polygon>"
        )
        geometry = (
            f"<bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>{polygon}"
            "</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface>"
        )
        if version == "2.0":
            surfaces.append(
                f"<bldg:boundedBy><bldg:{kind}>{geometry}</bldg:{kind}></bldg:boundedBy>"
            )
        else:
            geometry = geometry.replace("bldg:lod2MultiSurface", "core:lod2MultiSurface")
            surfaces.append(f"<core:boundary><con:{kind}>{geometry}</con:{kind}></core:boundary>")
    attributes = "".join(
        f'<gen:stringAttribute name="{k}"><gen:value>{v}</gen:value></gen:stringAttribute>'
        if version == "2.0"
        else f"<core:genericAttribute><gen:StringAttribute><gen:name>{k}</gen:name><gen:value>{v}</gen:value></gen:StringAttribute></core:genericAttribute>"
        for k, v in (b.attributes or {}).items()
        if k != "measuredHeight"
    )
    height = ""
    if b.attributes and "measuredHeight" in b.attributes and version == "2.0":
        height = (
            f'<bldg:measuredHeight uom="m">{b.attributes["measuredHeight"]}</bldg:measuredHeight>'
        )
    return (
        f'<core:cityObjectMember><bldg:Building gml:id="{b.id}">{attributes}{height}'
        f"{''.join(surfaces)}</bldg:Building></core:cityObjectMember>"
    )


def write_citygml(
    path: Path, buildings: Iterable[Building], crs: str, version: str = "2.0"
) -> Path:
    """The buildings as CityGML 2.0 or 3.0 (LoD2 boundary surfaces with semantics), srsName
    `crs` on the envelope."""
    ns = CITYGML_NS[version]
    gml = GML_NS if version == "2.0" else GML32_NS
    xmlns = " ".join(f'xmlns:{k}="{v}"' for k, v in ns.items())
    with path.open("w") as f:
        f.write(
            f'<?xml version="1.0" encoding="UTF-8"?>\n<core:CityModel {xmlns} xmlns:gml="{gml}">'
        )
        f.write(f'<gml:boundedBy><gml:Envelope srsName="{crs}" srsDimension="3"/></gml:boundedBy>')
        for b in buildings:
            f.write(_citygml_building(b, version))
        f.write("</core:CityModel>\n")
    return path


def site_buildings(frame: LocalFrame) -> tuple[list[Building], Relief, str]:
    """The sample site's hall and buildings (app.simulate.stadium) as LoD2 buildings in the
    site's UTM zone with EGM2008 heights, as a city would publish them, and its ground as a
    relief: (buildings, relief, the compound CRS as `EPSG:h+3855`). Corners go ENU -> WGS84 ->
    UTM one by one, so the footprints keep their shape and place (UTM's grid is turned from
    true north)."""
    crs = utm_zone(frame.lat_deg, frame.lon_deg)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    boxes = [("hall", HALL_MIN, HALL_MAX, "stadium")] + [
        (f"building_{b.name}", b.min_corner, b.max_corner, "office") for b in BUILDINGS
    ]

    def placed(lo: tuple, hi: tuple) -> tuple[tuple[tuple[float, float], ...], float]:
        ring = np.array([(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])])
        geo = frame.enu_to_geodetic(np.column_stack([ring, np.full(4, lo[2])]))
        x, y = to_utm.transform(geo[:, 1], geo[:, 0])
        corners = tuple((round(float(a), 3), round(float(b), 3)) for a, b in zip(x, y, strict=True))
        return corners, round(float(np.mean(geo[:, 2] - undulation(geo[:, 0], geo[:, 1]))), 3)

    out = []
    for name, lo, hi, function in boxes:
        corners, ground = placed(lo, hi)
        height = round(hi[2] - lo[2], 2)
        out.append(
            Building(
                name,
                corners,
                ground,
                round(ground + height, 3),
                {"function": function, "measuredHeight": height},
            )
        )
    g = GROUND_HALF
    relief = Relief("ground", *placed((-g, -g, 0.0), (g, g, 0.0)))
    return out, relief, f"EPSG:{crs.to_epsg()}+3855"
