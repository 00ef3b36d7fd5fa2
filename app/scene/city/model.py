"""City models as plain data, shared by the CityJSON and CityGML readers. No GL, no files.

A reader yields `CityObject`s one at a time (a file of 100,000 buildings is never held whole):
each with its id, type, attributes, parent and the surfaces of the one level of detail chosen for
it. A surface is a planar polygon (an exterior ring, maybe holes) of (x, y, z) coordinates in the
file's CRS, float64, with its semantic kind. `triangulate` turns the polygons into triangles
(ear clipping in the polygon's own plane, holes included); `FeatureTable` keeps, for the
triangles drawn, which object and which kind of surface each one is, so that `locate` can name
what a pixel hits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mapbox_earcut
import numpy as np
import numpy.typing as npt

# Semantic kinds, in the order of their codes (uint8 per triangle)
KINDS = (
    "roof",
    "wall",
    "ground",
    "closure",
    "window",
    "door",
    "floor",
    "ceiling",
    "water",
    "road",
    "vegetation",
    "terrain",
    "other",
)
KIND_CODE = {k: i for i, k in enumerate(KINDS)}

# CityJSON and CityGML surface names -> kind
SURFACE_KINDS = {
    "RoofSurface": "roof",
    "WallSurface": "wall",
    "InteriorWallSurface": "wall",
    "GroundSurface": "ground",
    "ClosureSurface": "closure",
    "Window": "window",
    "Door": "door",
    "OuterFloorSurface": "floor",
    "FloorSurface": "floor",
    "OuterCeilingSurface": "ceiling",
    "CeilingSurface": "ceiling",
    "WaterSurface": "water",
    "WaterGroundSurface": "water",
    "WaterClosureSurface": "closure",
    "TrafficArea": "road",
    "AuxiliaryTrafficArea": "road",
}

# A surface without semantics takes its kind from its object's type (prefix match)
TYPE_KINDS = (
    ("TINRelief", "terrain"),
    ("ReliefFeature", "terrain"),
    ("LandUse", "terrain"),
    ("WaterBody", "water"),
    ("PlantCover", "vegetation"),
    ("SolitaryVegetationObject", "vegetation"),
    ("Road", "road"),
    ("Railway", "road"),
    ("TransportSquare", "road"),
    ("Waterway", "water"),
)

# Linear RGB colours by kind, as the viewer draws an untextured city
KIND_COLORS = np.array(
    [
        (0.70, 0.33, 0.27),  # roof: tile red
        (0.88, 0.86, 0.80),  # wall: off-white
        (0.45, 0.43, 0.40),  # ground
        (0.62, 0.74, 0.86),  # closure: pale blue (not a real surface)
        (0.45, 0.62, 0.78),  # window
        (0.50, 0.36, 0.24),  # door
        (0.70, 0.70, 0.66),  # floor
        (0.70, 0.70, 0.66),  # ceiling
        (0.30, 0.50, 0.75),  # water
        (0.55, 0.55, 0.55),  # road
        (0.40, 0.62, 0.32),  # vegetation
        (0.72, 0.70, 0.62),  # terrain
        (0.80, 0.78, 0.74),  # other
    ],
    np.float32,
)


def kind_of(surface_type: str | None, object_type: str) -> str:
    """A surface's kind from its semantic type (CityJSON `type`, CityGML element name), else
    from its object's type ('other' for buildings without semantics)."""
    if surface_type:
        kind = SURFACE_KINDS.get(surface_type)
        if kind is not None:
            return kind
    for prefix, kind in TYPE_KINDS:
        if object_type.startswith(prefix):
            return kind
    return "other"


@dataclass
class Surface:
    """A planar polygon: rings[0] the exterior, the others holes; each (N, 3) float64 in the
    file's CRS (x, y horizontal, z height), not closed (the first vertex is not repeated).
    texture: the index of its image among the reader's `textures` (None: untextured), uvs: its
    rings' texture coordinates ((N, 2) each, (0, 0) the image's lower-left corner); colour: its
    material's diffuse colour (RGB in [0, 1]), drawn instead of its kind's where it has no
    texture (None: none); indices: (T, 3) its triangles into its rings' vertices concatenated
    where the reader made them (an extruded block's walls: one surface of quads, not a
    polygon), None to ear-clip the polygon (triangle_indices)."""

    rings: list[np.ndarray]
    kind: str
    texture: int | None = None
    uvs: list[np.ndarray] | None = None
    colour: tuple[float, float, float] | None = None
    indices: np.ndarray | None = None


def footprint_centre(points: np.ndarray) -> np.ndarray:
    """(2,) the middle of the points' (N, 3) horizontal extent: where a reader places a city
    object to decide whether it lies near the track."""
    return (points[:, :2].min(axis=0) + points[:, :2].max(axis=0)) / 2


@dataclass
class CityObject:
    """One city object with geometry. attributes: as the file gives them (parent's merged under
    its own); lod: the level of detail drawn ('2.2', '1', ...); surfaces in the file's CRS;
    centre: its footprint_centre (file CRS), as the reader tested it."""

    id: str
    type: str
    attributes: dict
    surfaces: list[Surface]
    centre: np.ndarray
    lod: str = ""
    parent: str | None = None


def _newell(ring: np.ndarray) -> np.ndarray:
    """The polygon's normal (not unit) by Newell's method: robust for nearly planar rings."""
    nxt = np.roll(ring, -1, axis=0)
    return np.array(
        [
            np.sum((ring[:, 1] - nxt[:, 1]) * (ring[:, 2] + nxt[:, 2])),
            np.sum((ring[:, 2] - nxt[:, 2]) * (ring[:, 0] + nxt[:, 0])),
            np.sum((ring[:, 0] - nxt[:, 0]) * (ring[:, 1] + nxt[:, 1])),
        ]
    )


def usable_rings(surface: Surface) -> list[int]:
    """The rings that take part in triangulation (three vertices or more), by index; none when
    the exterior has fewer."""
    if not surface.rings or len(surface.rings[0]) < 3:
        return []
    return [i for i, r in enumerate(surface.rings) if len(r) >= 3]


def triangulate(surface: Surface) -> np.ndarray:
    """(T, 3, 3) float64 triangles of a surface, in its coordinates, wound as its exterior ring
    (see `triangle_indices`)."""
    points = np.concatenate([surface.rings[i] for i in usable_rings(surface)] or [np.zeros((0, 3))])
    return points[triangle_indices(surface)]


def triangle_indices(surface: Surface) -> np.ndarray:
    """(T, 3) indices of a surface's triangles into its usable rings' vertices concatenated.

    Three-vertex rings are taken as they are; others are ear-clipped (mapbox_earcut) in their
    own plane: the vertices are projected on the two axes most perpendicular to the Newell
    normal, so a wall is triangulated in its own plane, not squashed on the ground. A degenerate
    ring (fewer than 3 vertices, or no area) gives no triangles. A surface's own `indices`,
    where its reader made them, are taken as they are."""
    if surface.indices is not None:
        return surface.indices
    rings = [surface.rings[i] for i in usable_rings(surface)]
    if not rings:
        return np.zeros((0, 3), np.int64)
    if len(rings) == 1 and len(rings[0]) == 3:
        return np.array([[0, 1, 2]])
    points = np.concatenate(rings)
    origin = points[0]
    local = points - origin  # CRS coordinates are large (UTM northing ~5e6 m): subtract first
    normal = _newell(local[: len(rings[0])])
    if not np.linalg.norm(normal) > 1e-12:
        return np.zeros((0, 3), np.int64)
    drop = int(np.argmax(np.abs(normal)))
    axes = [a for a in range(3) if a != drop]
    ends = np.cumsum([len(r) for r in rings]).astype(np.uint32)
    tri = mapbox_earcut.triangulate_float64(local[:, axes], ends).reshape(-1, 3).astype(np.int64)
    # earcut winds triangles its own way: keep the ring's orientation (outward for a solid)
    out = local[tri]
    n = np.cross(out[:, 1] - out[:, 0], out[:, 2] - out[:, 0])
    flip = n @ normal < 0
    tri[flip] = tri[flip][:, ::-1]
    return tri


@dataclass
class Feature:
    """What a point of the scene is on: a city object's id, type, surface kind, attributes and
    parent (a building of which it is a part), and the point's distance (m) from its surface."""

    layer: str
    id: str
    type: str
    surface: str
    attributes: dict
    parent: str | None
    distance_m: float

    def as_dict(self) -> dict[str, object]:
        """The fields for JSON."""
        return {
            "layer": self.layer,
            "id": self.id,
            "type": self.type,
            "surface": self.surface,
            "parent": self.parent,
            "attributes": self.attributes,
        }

    def line(self) -> str:
        """One line for people: the object, its surface and its main attributes."""
        shown = [f"{k} {v}" for k, v in self.attributes.items() if _shown(k, v)][:4]
        part = f" (part of {self.parent})" if self.parent else ""
        extra = f"; {', '.join(shown)}" if shown else ""
        return f"{self.type} {self.id}{part}, {self.surface}{extra}"


SHOWN_ATTRIBUTES = ("height", "function", "usage", "address", "name", "year", "roof", "storeys")


def _shown(key: str, value: object) -> bool:
    """An attribute worth one line: a short value under a name people look for."""
    k = key.lower()
    return isinstance(value, str | int | float) and any(w in k for w in SHOWN_ATTRIBUTES)


@dataclass
class FeatureTable:
    """Which city object and which kind of surface each triangle of a city layer is.

    triangles: (M, 3, 3) float32 ENU m (a view of the drawn positions), grouped by object;
    starts: (N + 1,) the first triangle of each object; kinds: (M,) uint8 codes of KINDS;
    boxes: (N, 2, 3) each object's ENU bounds."""

    layer: str
    ids: list[str]
    types: list[str]
    attributes: list[dict]
    parents: list[str | None]
    triangles: npt.NDArray[np.float32]
    starts: npt.NDArray[np.int64]
    kinds: npt.NDArray[np.uint8]
    boxes: npt.NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        # every object has a triangle (the reader keeps none without): one reduction each way
        corners = self.triangles.reshape(-1, 3)
        first = self.starts[:-1] * 3
        self.boxes = np.stack(
            [np.minimum.reduceat(corners, first), np.maximum.reduceat(corners, first)], axis=1
        ).astype(np.float64)

    def at(self, point_enu: npt.ArrayLike, tolerance_m: float = 0.25) -> Feature | None:
        """The object whose surface lies nearest the ENU point (m), if within tolerance_m."""
        p = np.asarray(point_enu, np.float64)
        near = np.flatnonzero(
            np.all(self.boxes[:, 0] - tolerance_m <= p, axis=1)
            & np.all(p <= self.boxes[:, 1] + tolerance_m, axis=1)
        )
        best: tuple[float, int, int] | None = None
        for i in near:
            tris = self.triangles[self.starts[i] : self.starts[i + 1]].astype(np.float64)
            d = point_triangle_distance(p, tris)
            j = int(np.argmin(d))
            if best is None or d[j] < best[0]:
                best = (float(d[j]), int(i), int(self.starts[i]) + j)
        if best is None or best[0] > tolerance_m:
            return None
        dist, i, t = best
        return Feature(
            self.layer,
            self.ids[i],
            self.types[i],
            KINDS[int(self.kinds[t])],
            self.attributes[i],
            self.parents[i],
            dist,
        )


def point_triangle_distance(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(M,) distances (m) from the point p (3,) to each triangle (M, 3, 3): to the plane where p
    projects inside the triangle, else to the nearest edge."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 1e-18
    d = np.full(len(tris), np.inf)
    safe = np.where(ok, nn, 1.0)
    t = np.einsum("ij,ij->i", p - a, n) / safe
    q = p - t[:, None] * n  # p projected on the plane
    inside = ok.copy()
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, q - u), n) >= 0
    d[inside] = np.abs(t[inside]) * np.sqrt(nn[inside])
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        ee = np.maximum(np.einsum("ij,ij->i", e, e), 1e-18)
        s = np.clip(np.einsum("ij,ij->i", p - u, e) / ee, 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(p - (u + s[:, None] * e), axis=1))
    return d
