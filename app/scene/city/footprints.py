"""Building footprints extruded to LoD1 blocks: what the OpenStreetMap (app.scene.city.osm) and
GeoParquet (app.scene.city.overture) readers share, after each has turned its file into
`Footprint`s (a polygon in longitude, latitude and the tags).

A footprint becomes a `CityObject` of type Building (BuildingPart for a `building:part`), LoD
"1", in EPSG:4979 (x longitude, y latitude in degrees, z ellipsoidal height in metres): a wall
quad for each edge of each of its rings (courtyards' too), a flat roof at its top and a floor at
its bottom, of kinds wall, roof and ground (floor where it is raised by min_height).

Heights (`vertical_extent`, OSM's Simple 3D Buildings keys or Overture's columns): the top from
`height` (or `building:height`), else `building:levels` (+ `roof:height`, else `roof:levels`)
at LEVEL_M a level, else DEFAULT_LEVELS levels; the bottom from `min_height`, else
`building:min_level` levels, else the ground. Lengths are metres unless they say feet
(`40'`, `40 ft`, `12'6"`). How many buildings took each rule is said in the layer's note.

Each building stands on the ground under it: the lowest height of `Ground` (the terrain of the
scene's other layers, or an assumed flat ground) at its footprint's vertices; where none is
there, the ground's assumed height, and that is counted too. An outline whose parts are drawn
(a `building:part` inside it) is left out: the parts replace it, with its tags under theirs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.polygon import orient
from shapely.strtree import STRtree

from app.core.errors import SceneError
from app.geodesy.enu import LocalFrame
from app.scene.city.model import CityObject, Surface, footprint_centre, triangle_indices
from app.scene.ground import ground_heights
from app.scene.mesh import MeshData

LEVEL_M = 3.0  # one storey, metres
DEFAULT_LEVELS = 3  # a building that says neither height nor levels
DEFAULT_HEIGHT_M = DEFAULT_LEVELS * LEVEL_M
MAX_HEIGHT_M = 1000.0  # taller than any building: a height above this is a typing error
MAX_LEVELS = 300.0
FOOT_M = 0.3048
INCH_M = 0.0254
CRS = "EPSG:4979"  # footprints are placed in longitude, latitude (deg), ellipsoidal height (m)

Keep = Callable[[np.ndarray], bool]  # a footprint's horizontal centre (lon, lat deg) -> read it?
Heights = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (lat, lon) deg -> ellipsoidal m, NaN


@dataclass(frozen=True)
class HeightKeys:
    """The keys a format gives a building's vertical extent under (OSM tags, Overture columns);
    None where it has no such key."""

    height: tuple[str, ...]
    levels: str
    roof_height: str | None
    roof_levels: str | None
    min_height: str
    min_level: str


OSM_KEYS = HeightKeys(
    ("height", "building:height"),
    "building:levels",
    "roof:height",
    "roof:levels",
    "min_height",
    "building:min_level",
)
OVERTURE_KEYS = HeightKeys(
    ("height",), "num_floors", "roof_height", None, "min_height", "min_floor"
)
HEIGHT_TAGS = {  # not inherited by a part from its outline: its own extent is its own
    *OSM_KEYS.height,
    *OVERTURE_KEYS.height,
    "building:levels",
    "num_floors",
    "roof:height",
    "roof_height",
    "roof:levels",
    "min_height",
    "building:min_level",
    "min_floor",
}

_METRES = re.compile(r"^(\d+(?:\.\d*)?|\.\d+)\s*(?:m|metres?|meters?)?$", re.IGNORECASE)
_FEET = re.compile(
    r"^(\d+(?:\.\d*)?)\s*(?:'|ft|feet|foot)\s*(?:(\d+(?:\.\d*)?)\s*(?:\"|''|in|inch|inches))?$",
    re.IGNORECASE,
)


def _number(value: object) -> float | None:
    """A finite non-negative number given as one (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        return None
    v = float(value)
    return v if math.isfinite(v) and v >= 0.0 else None


def parse_length(value: object) -> float | None:
    """A length in metres from a tag ("12", "12 m", "12.5m", "12,5", "40'", "40 ft", "12'6\"")
    or a number; None for anything else (negative, "tall", a list "12;15", taller than
    MAX_HEIGHT_M)."""
    v = _number(value)
    if v is None and isinstance(value, str):
        text = value.strip()
        if "," in text and "." not in text:  # a decimal comma
            text = text.replace(",", ".")
        if m := _METRES.match(text):
            v = float(m.group(1))
        elif m := _FEET.match(text):
            v = float(m.group(1)) * FOOT_M + float(m.group(2) or 0.0) * INCH_M
    return v if v is not None and v <= MAX_HEIGHT_M else None


def parse_levels(value: object) -> float | None:
    """A count of storeys ("4", "4.5", 4) or None (negative, "many", more than MAX_LEVELS)."""
    v = _number(value)
    if v is None and isinstance(value, str):
        try:
            v = _number(float(value.strip().replace(",", ".")))
        except ValueError:
            v = None
    return v if v is not None and v <= MAX_LEVELS else None


@dataclass(frozen=True)
class Extent:
    """A building's vertical extent above the ground it stands on (m): bottom, top; rule: the
    key the top came from ("default" for none); faults: (kind, key=value) of tags that could
    not be used."""

    bottom_m: float
    top_m: float
    rule: str
    faults: tuple[tuple[str, str], ...] = ()


def _given(tags: dict, key: str | None) -> bool:
    if key is None or key not in tags:
        return False
    v = tags[key]
    return v is not None and not (isinstance(v, float) and math.isnan(v)) and v != ""


def vertical_extent(tags: dict, keys: HeightKeys = OSM_KEYS) -> Extent:
    """The extent (module docstring) from a building's tags under `keys`. A value that is there
    but unreadable is a fault, and the next rule is taken."""
    faults: list[tuple[str, str]] = []

    def read(key: str | None, parse: Callable[[object], float | None]) -> float | None:
        if not _given(tags, key):
            return None
        v = parse(tags[key])
        if v is None:
            faults.append(("unreadable", f"{key}={tags[key]!r}"))
        return v

    top, rule = None, "default"
    for key in keys.height:
        top = read(key, parse_length)
        if top is not None:
            rule = key
            break
    if top is None:
        levels = read(keys.levels, parse_levels)
        if levels is not None:
            roof = read(keys.roof_height, parse_length)
            if roof is None:
                roof = (read(keys.roof_levels, parse_levels) or 0.0) * LEVEL_M
            top, rule = levels * LEVEL_M + roof, keys.levels
    if top is None or top <= 0.0:
        if top is not None:
            faults.append(("zero height", f"{rule}={tags[rule]!r}"))
        top, rule = DEFAULT_HEIGHT_M, "default"
    bottom = read(keys.min_height, parse_length)
    if bottom is None:
        bottom = (read(keys.min_level, parse_levels) or 0.0) * LEVEL_M
    if bottom >= top:
        faults.append(("bottom above top", f"bottom {bottom:g} m, top {top:g} m"))
        bottom = 0.0
    return Extent(bottom, top, rule, tuple(faults))


@dataclass(frozen=True)
class Ground:
    """What footprints stand on. heights: (lat, lon) deg (N,) -> (N,) ellipsoidal heights (m)
    of the surface there, NaN where there is none; what: its name for the note; assumed_h: the
    ellipsoidal height (m) a building takes where `heights` has none."""

    heights: Heights
    what: str
    assumed_h: float


def terrain_ground(mesh: MeshData, frame: LocalFrame, what: str, assumed_h: float) -> Ground:
    """The lowest surface of `mesh` (ENU in `frame`: a DEM, a world, a tileset, a model) as
    ellipsoidal heights (app.scene.ground.ground_heights, all points at once)."""

    def heights(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(frame.geodetic_to_enu(lat, lon, np.zeros(len(lat))))[:, :2]
        z = ground_heights(mesh, xy)
        out = np.full(len(xy), np.nan)
        ok = np.isfinite(z)
        if ok.any():
            out[ok] = frame.enu_to_geodetic(np.column_stack([xy[ok], z[ok]]))[:, 2]
        return out

    return Ground(heights, what, assumed_h)


def flat_ground(frame: LocalFrame, z_enu: float, assumed_h: float, what: str) -> Ground:
    """The plane z = z_enu (m) of `frame` (the assumed ground is drawn as one) as ellipsoidal
    heights: it lies over the whole Earth's tangent plane, so no point lacks it."""

    def heights(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(frame.geodetic_to_enu(lat, lon, np.zeros(len(lat))))[:, :2]
        enu = np.column_stack([xy, np.full(len(xy), float(z_enu))])
        return np.atleast_2d(frame.enu_to_geodetic(enu))[:, 2]

    return Ground(heights, what, assumed_h)


@dataclass
class Footprint:
    """One building outline or part: id ('way/12', 'relation/3', an Overture id), its tags
    (attributes), its polygon(s) in longitude, latitude (deg; valid, holes included); part: a
    building:part (drawn inside its outline); parent: the outline it lies in, once known;
    own_tags: where `tags` took the outline's, the part's own (its extent comes from them)."""

    id: str
    tags: dict
    shape: Polygon | MultiPolygon
    part: bool = False
    parent: str | None = None
    own_tags: dict | None = None  # a part's own tags, where it took its outline's under them


@dataclass
class Faults:
    """What could not be drawn as given, by kind: the ids of the buildings (said once a kind,
    with the count and the first id)."""

    ids: dict[str, list[str]] = field(default_factory=dict)

    def add(self, kind: str, fid: str) -> None:
        self.ids.setdefault(kind, []).append(fid)

    def total(self, kinds: tuple[str, ...]) -> int:
        return sum(len(self.ids.get(k, ())) for k in kinds)


FAULT_TEXT = {  # kind -> (what, what was done), said with the count and the first id
    "not closed": ("building ways that do not end where they start (not rings)", "skipped"),
    "missing nodes": (
        "buildings with nodes missing from the file (an extract cut at its edge)",
        "skipped",
    ),
    "missing members": ("multipolygon buildings with member ways missing from the file", "skipped"),
    "open rings": (
        "multipolygon buildings whose ways do not join into closed rings",
        "those rings left out",
    ),
    "no outer": ("multipolygon buildings without a closed outer ring", "skipped"),
    "invalid": (
        "footprints that are not valid polygons (a ring crossing itself, a hole outside)",
        "repaired (GEOS make_valid)",
    ),
    "no area": ("footprints without area", "skipped"),
    "not a polygon": ("footprints that are not polygons", "skipped"),
    "unreadable": (
        "buildings with a height or levels that is not a length",
        "the next rule taken",
    ),
    "zero height": ("buildings with a height of 0", "the default taken"),
    "bottom above top": (
        "buildings with min_height or building:min_level at or above their top",
        "drawn from the ground",
    ),
}
SKIPPED = ("not closed", "missing nodes", "missing members", "no outer", "no area", "not a polygon")


def valid_shape(
    shape: Polygon | MultiPolygon, fid: str, faults: Faults
) -> Polygon | MultiPolygon | None:
    """A footprint as valid polygons with repeated vertices removed: an invalid one made valid
    (its polygonal part) and counted, one without area counted and None."""
    shape = shapely.remove_repeated_points(shape)
    if not shape.is_valid:
        faults.add("invalid", f"{fid} ({shapely.is_valid_reason(shape).split('[')[0]})")
        fixed = shapely.make_valid(shape)
        polys = [
            p
            for g in getattr(fixed, "geoms", [fixed])
            for p in getattr(g, "geoms", [g])
            if isinstance(p, Polygon) and p.area > 0
        ]
        shape = MultiPolygon(polys) if len(polys) > 1 else polys[0] if polys else Polygon()
    if shape.is_empty or not shape.area > 0:
        faults.add("no area", fid)
        return None
    return shape


def rings_of(shape: Polygon | MultiPolygon) -> list[list[np.ndarray]]:
    """Each polygon's rings (N, 2) lon, lat, not closed: the exterior counter-clockwise (seen
    from above), holes clockwise."""
    out = []
    for poly in getattr(shape, "geoms", [shape]):
        poly = orient(poly, 1.0)
        rings = [poly.exterior, *poly.interiors]
        out.append([np.asarray(r.coords, np.float64)[:-1, :2] for r in rings])
    return out


QUAD = np.array([[0, 1, 2], [0, 2, 3]])  # a wall quad (bottom a, bottom b, top b, top a)


def extrude(polygons: list[list[np.ndarray]], z0: float, z1: float, floor: str) -> list[Surface]:
    """The LoD1 block of a footprint (rings_of) from ellipsoidal height z0 to z1 (m), in
    EPSG:4979: a roof a polygon (kind roof, facing up), a floor under it (kind `floor`, facing
    down), and the walls as one surface of a quad per ring edge (kind wall, facing out of the
    building: into a courtyard for a hole's)."""
    out, quads = [], []
    for rings in polygons:
        roof = Surface([np.column_stack([r, np.full(len(r), z1)]) for r in rings], "roof")
        tri = roof.indices = triangle_indices(roof)
        out.append(roof)
        below = [np.column_stack([r, np.full(len(r), z0)]) for r in rings]
        out.append(Surface(below, floor, indices=tri[:, ::-1]))
        for r in rings:
            q = np.empty((len(r), 4, 3))
            q[:, 0, :2], q[:, 1, :2] = r, np.roll(r, -1, axis=0)
            q[:, 2, :2], q[:, 3, :2] = q[:, 1, :2], q[:, 0, :2]
            q[:, :2, 2], q[:, 2:, 2] = z0, z1
            quads.append(q)
    walls = np.concatenate(quads)
    first = 4 * np.arange(len(walls))
    indices = (first[:, None, None] + QUAD).reshape(-1, 3)
    out.append(Surface([walls.reshape(-1, 3)], "wall", indices=indices))
    return out


def near(coords: np.ndarray, keep: Keep) -> bool:
    """Whether a footprint's vertices (N, 2) lon, lat (NaN: missing, left out) lie where the
    reader reads: its centre tested by `keep`; False where none is known."""
    ok = np.isfinite(coords).all(axis=1)
    return bool(ok.any()) and keep(footprint_centre(coords[ok]))


class FootprintReader:
    """The reader interface app.scene.city.read uses, for footprint files: `crs`, `count`,
    `notes` (warnings), `infos` (the layer's note: heights and ground), `objects(keep)`; no
    textures or themes. Subclasses give `format`, `version` and `_footprints(keep)`: the
    valid footprints near the track (those near it that are not, counted in `faults`), with
    `count` the buildings in the file."""

    format = "footprints"
    crs = CRS
    theme = None
    texture_uris: list[str] = []
    keys = OSM_KEYS

    def __init__(self, path: str | Path, ground: Ground) -> None:
        self.path = Path(path)
        self.ground = ground
        self.version = ""
        self.count = 0
        self.notes: list[str] = []
        self.infos: list[str] = []
        self.themes: set[str] = set()
        self.faults = Faults()

    def texture_files(self) -> list[Path | None]:
        return []

    def _footprints(self, keep: Keep) -> Iterator[Footprint]:
        raise NotImplementedError

    def objects(self, keep: Keep | None = None) -> Iterator[CityObject]:
        """The footprints near the track (keep: their centre, lon, lat) as LoD1 CityObjects,
        their ground sampled all at once. Raises SceneError where the file holds no building,
        or none that could be drawn."""
        found = list(self._footprints(keep or (lambda centre: True)))
        if self.count == 0:
            raise SceneError(
                self.path,
                "no building in it (expected ways or multipolygons tagged building=* or "
                "building:part=*, or rows of building polygons)",
            )
        skipped = self.faults.total(SKIPPED)
        if not found and skipped:
            self._say_faults()
            raise SceneError(
                self.path,
                f"none of its buildings near the track could be drawn ({skipped} skipped: "
                + "; ".join(self.notes)
                + ")",
            )
        drawn, replaced = _without_outlines_of_parts(found)
        extents = [vertical_extent(fp.own_tags or fp.tags, self.keys) for fp in drawn]
        polygons = [rings_of(fp.shape) for fp in drawn]
        bases, assumed = self._bases(polygons)
        for fp, extent, rings, base in zip(drawn, extents, polygons, bases, strict=True):
            for kind, what in extent.faults:
                self.faults.add(kind, f"{fp.id} {what}")
            floor = "floor" if extent.bottom_m > 0 else "ground"
            surfaces = extrude(rings, base + extent.bottom_m, base + extent.top_m, floor)
            yield CityObject(
                fp.id,
                "BuildingPart" if fp.part else "Building",
                fp.tags,
                surfaces,
                footprint_centre(np.concatenate([r for p in rings for r in p])),
                "1",
                fp.parent,
            )
        self._say_faults()
        self._say_heights(extents, assumed, replaced, sum(fp.part for fp in drawn))

    def _bases(self, polygons: list[list[list[np.ndarray]]]) -> tuple[np.ndarray, int]:
        """(each footprint's ground (polygons: rings_of each): the lowest ellipsoidal height
        under its vertices, m; how many had none and took the assumed height)."""
        if not polygons:
            return np.zeros(0), 0
        vertices = [np.concatenate([r for rings in p for r in rings]) for p in polygons]
        allv = np.concatenate(vertices)
        h = self.ground.heights(allv[:, 1], allv[:, 0])
        starts = np.concatenate([[0], np.cumsum([len(v) for v in vertices])[:-1]])
        with np.errstate(invalid="ignore"):
            lowest = np.fmin.reduceat(h, starts)
        missing = ~np.isfinite(lowest)
        lowest[missing] = self.ground.assumed_h
        return lowest, int(missing.sum())

    def _say_faults(self) -> None:
        for kind, ids in self.faults.ids.items():
            what, done = FAULT_TEXT[kind]
            note = f"{self.path.name}: {what}: {len(ids)} (first {ids[0]}), {done}"
            if note not in self.notes:
                self.notes.append(note)
        self.faults.ids.clear()

    def _say_heights(self, extents: list[Extent], assumed: int, replaced: int, parts: int) -> None:
        rules: dict[str, int] = {}
        for e in extents:
            rules[e.rule] = rules.get(e.rule, 0) + 1
        said = []
        for key in (*self.keys.height, self.keys.levels):
            if rules.get(key):
                per = f" at {LEVEL_M:g} m a level" if key == self.keys.levels else ""
                said.append(f"{rules[key]} from {key}{per}")
        if rules.get("default"):
            said.append(
                f"{rules['default']} assumed {DEFAULT_HEIGHT_M:g} m ({DEFAULT_LEVELS} levels: no height or levels)"
            )
        raised = sum(e.bottom_m > 0 for e in extents)
        text = (
            f"{self.path.name}: {len(extents)} footprints extruded to LoD1 blocks; heights: "
            + ", ".join(said)
            + (
                f"; {raised} raised by {self.keys.min_height}/{self.keys.min_level}"
                if raised
                else ""
            )
            + f"; each stands where its lowest corner meets {self.ground.what}"
        )
        if assumed:
            text += f", {assumed} beyond it at the assumed ground height {self.ground.assumed_h:.2f} m (ellipsoidal)"
        if replaced:
            text += f"; {replaced} outlines drawn by their {parts} parts"
        self.infos.append(text)


def _without_outlines_of_parts(found: list[Footprint]) -> tuple[list[Footprint], int]:
    """(the footprints drawn, how many outlines were left out): an outline in which a part lies
    (its representative point inside) is replaced by its parts, which take its tags under
    theirs (its height tags excepted: a part's extent is its own) and its id as their parent."""
    outlines = [fp for fp in found if not fp.part]
    parts = [fp for fp in found if fp.part]
    if not outlines or not parts:
        return found, 0
    tree = STRtree([o.shape for o in outlines])
    replaced: set[int] = set()
    for p in parts:
        hits = tree.query(p.shape.representative_point(), predicate="within")
        if len(hits):
            outline = outlines[int(min(hits, key=lambda i: outlines[int(i)].shape.area))]
            replaced.add(id(outline))
            p.parent = outline.id
            p.own_tags = p.tags
            inherited = {k: v for k, v in outline.tags.items() if k not in HEIGHT_TAGS}
            p.tags = {**inherited, **p.tags}
    return [fp for fp in found if id(fp) not in replaced], len(replaced)
