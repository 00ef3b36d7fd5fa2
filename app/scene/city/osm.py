"""OpenStreetMap buildings from a local file: OSM XML (`.osm`, as JOSM, Overpass and osmium
write it) or PBF (`.osm.pbf`, read with pyosmium), as footprints for LoD1 extrusion
(app.scene.city.footprints).

A building is a closed way tagged `building=*` or `building:part=*` (not `=no`), or a
`type=multipolygon` relation so tagged, whose member ways are joined end to end into rings (by
node id; outer and inner told apart by nesting, as renderers do, whatever their roles say). A
way that is an outer member of a building multipolygon is drawn by its relation only.

XML: lxml's iterparse walks the file once; node positions are kept in flat arrays (24 bytes a
node) and ways' node ids per way, so a city's extract is read in the memory of a fraction of its
size; Overpass's `out geom` (positions on the ways' `nd`) is read as well; objects JOSM marks
`action="delete"` and deleted ones (`visible="false"`) are left out. PBF: relations first, then
the buildings' ways with their node positions (osmium's location index, in C++), then the
member ways still missing, so Python sees only buildings; a way's position tested against the
track as it comes.

What cannot be drawn is counted and said once a kind (app.scene.city.footprints.FAULT_TEXT):
ways that are not closed, nodes or members missing (an extract cut at its edge), rings that do
not close, self-crossing rings (repaired), unreadable heights.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import osmium
from lxml import etree
from shapely.geometry import MultiPolygon, Polygon

from app.core.errors import SceneError
from app.scene.city.footprints import (
    Faults,
    Footprint,
    FootprintReader,
    Ground,
    Keep,
    near,
    valid_shape,
)

SUFFIXES = (".osm", ".osm.pbf")
BUILDING_KEYS = ("building", "building:part")


def is_osm(location: str | Path) -> bool:
    """An OSM XML (.osm) or PBF (.osm.pbf) file, by its name."""
    return str(location).lower().endswith(SUFFIXES)


def is_building(tags: dict[str, str]) -> bool:
    """Tagged building=* or building:part=* (other than "no")."""
    return any(tags.get(k, "no") != "no" for k in BUILDING_KEYS)


def _is_part(tags: dict[str, str]) -> bool:
    return tags.get("building", "no") == "no"


@dataclass
class OsmData:
    """What a file holds of its buildings. ways: id -> (node ids (N,) int64, positions (N, 2)
    lon, lat deg, NaN where the node is missing); buildings: the tagged ways (id, tags);
    relations: the building multipolygons (id, tags, member ways (id, role)); count: buildings
    in the file; version: the file's OSM API version (XML) or ''."""

    ways: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    buildings: list[tuple[int, dict[str, str]]] = field(default_factory=list)
    relations: list[tuple[int, dict[str, str], list[tuple[int, str]]]] = field(default_factory=list)
    count: int = 0
    version: str = ""


class _Nodes:
    """Node positions by id, kept in flat arrays as the file is read."""

    def __init__(self) -> None:
        self.ids, self.lon, self.lat = array("q"), array("d"), array("d")

    def add(self, nid: int, lon: float, lat: float) -> None:
        self.ids.append(nid)
        self.lon.append(lon)
        self.lat.append(lat)

    def lookup(self) -> Callable[[np.ndarray], np.ndarray]:
        """A function: node ids (N,) -> (N, 2) lon, lat (NaN where not in the file)."""
        ids = np.frombuffer(self.ids, np.int64) if len(self.ids) else np.zeros(0, np.int64)
        order = np.argsort(ids, kind="stable")
        ids = ids[order]
        pos = np.column_stack(
            [np.frombuffer(self.lon, np.float64), np.frombuffer(self.lat, np.float64)]
        ).reshape(-1, 2)[order]

        def find(refs: np.ndarray) -> np.ndarray:
            out = np.full((len(refs), 2), np.nan)
            if len(ids):
                i = np.minimum(np.searchsorted(ids, refs), len(ids) - 1)
                hit = ids[i] == refs
                out[hit] = pos[i[hit]]
            return out

        return find


def _attr(el: etree._Element, name: str, kind: type, path: Path) -> object:
    """An element's attribute as `kind`, or SceneError naming the file and line."""
    value = el.get(name)
    try:
        return kind(value)
    except (TypeError, ValueError):
        raise SceneError(
            path,
            f"<{el.tag}> attribute {name}={value!r} is not {'an integer' if kind is int else 'a number'}",
            line=el.sourceline,
        ) from None


def read_xml(path: Path) -> OsmData:
    """The buildings of an OSM XML file (module docstring). Raises SceneError naming the file
    and line of a damaged document, or a file that is not OSM XML."""
    data = OsmData()
    nodes = _Nodes()
    refs_of: dict[int, np.ndarray] = {}
    inline: dict[int, np.ndarray] = {}
    root = None
    try:
        for event, el in etree.iterparse(
            str(path), events=("start", "end"), huge_tree=True, resolve_entities=False,
            no_network=True, remove_comments=True,
        ):  # fmt: skip
            if event == "start":
                if root is None:
                    root = el
                    if el.tag != "osm":
                        raise SceneError(
                            path,
                            f"not OpenStreetMap XML (its root element is <{el.tag}>, expected <osm>)",
                            line=el.sourceline,
                        )
                    data.version = el.get("version", "")
                continue
            if el.getparent() is not root:
                continue  # a child (nd, tag, member): read with its element
            if el.get("action") == "delete" or el.get("visible") == "false":
                pass
            elif el.tag == "node":
                if el.get("lat") is not None:
                    nodes.add(
                        _attr(el, "id", int, path),
                        _attr(el, "lon", float, path),
                        _attr(el, "lat", float, path),
                    )
            elif el.tag == "way":
                wid = _attr(el, "id", int, path)
                nds = el.findall("nd")
                refs_of[wid] = np.array([_attr(nd, "ref", int, path) for nd in nds], np.int64)
                if nds and all(nd.get("lat") is not None for nd in nds):  # Overpass `out geom`
                    inline[wid] = np.array(
                        [
                            [_attr(nd, "lon", float, path), _attr(nd, "lat", float, path)]
                            for nd in nds
                        ]
                    )
                tags = {t.get("k"): t.get("v") for t in el.iterfind("tag")}
                if is_building(tags):
                    data.buildings.append((wid, tags))
                    data.count += 1
            elif el.tag == "relation":
                tags = {t.get("k"): t.get("v") for t in el.iterfind("tag")}
                if tags.get("type") == "multipolygon" and is_building(tags):
                    members = [
                        (_attr(m, "ref", int, path), m.get("role") or "")
                        for m in el.iterfind("member")
                        if m.get("type") == "way"
                    ]
                    data.relations.append((_attr(el, "id", int, path), tags, members))
                    data.count += 1
            el.clear()
            while el.getprevious() is not None:
                del root[0]
    except etree.XMLSyntaxError as exc:
        raise SceneError(
            path, f"not well-formed XML: {exc.msg.split(', line')[0]}", line=exc.lineno
        ) from None
    find = nodes.lookup()
    for wid, refs in refs_of.items():
        data.ways[wid] = (refs, inline[wid] if wid in inline else find(refs))
    return data


def _way(way) -> tuple[np.ndarray, np.ndarray]:
    """(node ids, positions lon, lat with NaN where missing) of an osmium way."""
    refs = np.array([n.ref for n in way.nodes], np.int64)
    pos = np.array(
        [(n.lon, n.lat) if n.location.valid() else (np.nan, np.nan) for n in way.nodes],
        np.float64,
    ).reshape(-1, 2)
    return refs, pos


def read_pbf(path: Path, keep: Keep) -> OsmData:
    """The buildings of an OSM PBF file (module docstring): the building ways near the track
    (keep), every member way of a building multipolygon. Raises SceneError where osmium
    cannot read it."""
    data = OsmData()
    try:
        members: set[int] = set()
        relations = osmium.FileProcessor(str(path), osmium.osm.RELATION).with_filter(
            osmium.filter.KeyFilter(*BUILDING_KEYS)
        )
        for r in relations:
            tags = {t.k: t.v for t in r.tags}
            if tags.get("type") == "multipolygon" and is_building(tags):
                ms = [(m.ref, m.role) for m in r.members if m.type == "w"]
                data.relations.append((r.id, tags, ms))
                members.update(ref for ref, _ in ms)
                data.count += 1
        ways = (
            osmium.FileProcessor(str(path), osmium.osm.NODE | osmium.osm.WAY)
            .with_locations()
            .with_filter(osmium.filter.EntityFilter(osmium.osm.WAY))
            .with_filter(osmium.filter.KeyFilter(*BUILDING_KEYS))
        )
        for w in ways:
            tags = {t.k: t.v for t in w.tags}
            if not is_building(tags):
                continue
            data.count += 1
            refs, pos = _way(w)
            if w.id in members or near(pos, keep) or not np.isfinite(pos).any():
                data.ways[w.id] = (refs, pos)
                data.buildings.append((w.id, tags))
        missing = members - data.ways.keys()
        if missing:
            rest = (
                osmium.FileProcessor(str(path), osmium.osm.NODE | osmium.osm.WAY)
                .with_locations()
                .with_filter(osmium.filter.EntityFilter(osmium.osm.WAY))
                .with_filter(osmium.filter.IdFilter(missing))
            )
            for w in rest:
                data.ways[w.id] = _way(w)
    except RuntimeError as exc:
        raise SceneError(path, f"cannot read it as OpenStreetMap PBF ({exc})") from None
    return data


def join_rings(chains: list[np.ndarray]) -> tuple[list[np.ndarray], int]:
    """Member ways (node id sequences) joined end to end into closed rings. Returns (the rings
    as node id sequences, first id repeated last; how many chains were left open)."""
    rings = [c for c in chains if len(c) >= 4 and c[0] == c[-1]]
    pool = [c for c in chains if not (len(c) >= 4 and c[0] == c[-1]) and len(c) >= 2]
    open_left = 0
    while pool:
        ring = pool.pop()
        while ring[0] != ring[-1]:
            for i, c in enumerate(pool):
                if c[0] == ring[-1]:
                    ring = np.concatenate([ring, c[1:]])
                elif c[-1] == ring[-1]:
                    ring = np.concatenate([ring, c[::-1][1:]])
                elif c[-1] == ring[0]:
                    ring = np.concatenate([c, ring[1:]])
                elif c[0] == ring[0]:
                    ring = np.concatenate([c[::-1], ring[1:]])
                else:
                    continue
                pool.pop(i)
                break
            else:
                open_left += 1
                break
        else:
            if len(ring) >= 4:
                rings.append(ring)
    return rings, open_left


def _nest(rings: list[np.ndarray]) -> Polygon | MultiPolygon | None:
    """Rings (N, 2) lon, lat as polygons with holes: a ring inside an odd number of others is a
    hole of the smallest that holds it (roles are not trusted, as renderers do)."""
    polys = [Polygon(r) for r in rings]
    order = sorted(range(len(polys)), key=lambda i: -polys[i].area)
    depth = dict.fromkeys(order, 0)
    holder: dict[int, int] = {}
    for k, i in enumerate(order):
        point = polys[i].representative_point()
        for j in reversed(order[:k]):  # smallest first among the larger
            if polys[j].contains(point):
                depth[i] = depth[j] + 1
                holder[i] = j
                break
    outers = [i for i in order if depth[i] % 2 == 0]
    if not outers:
        return None
    shells = [
        Polygon(rings[i], [rings[h] for h in order if holder.get(h) == i and depth[h] % 2])
        for i in outers
    ]
    return shells[0] if len(shells) == 1 else MultiPolygon(shells)


def osm_footprints(data: OsmData, keep: Keep, faults: Faults) -> Iterator[Footprint]:
    """The buildings of `data` near the track as valid footprints; what cannot be drawn near
    it counted in `faults`."""
    outer_members = {
        ref for _, _, members in data.relations for ref, role in members if role != "inner"
    }
    for wid, tags in data.buildings:
        fid = f"way/{wid}"
        if wid in outer_members and not _is_part(tags):
            continue  # drawn by its multipolygon
        refs, pos = data.ways[wid]
        if np.isfinite(pos).any() and not near(pos, keep):
            continue
        if len(refs) < 4 or refs[0] != refs[-1]:
            faults.add("not closed", fid)
        elif not np.isfinite(pos).all():
            faults.add("missing nodes", fid)
        elif (shape := valid_shape(Polygon(pos), fid, faults)) is not None:
            yield Footprint(fid, {**tags, "osm_id": fid}, shape, _is_part(tags))
    for rid, tags, members in data.relations:
        fid = f"relation/{rid}"
        had = [data.ways[m] for m, _ in members if m in data.ways]
        pos = np.concatenate([p for _, p in had]) if had else np.zeros((0, 2))
        if not near(pos, keep) and len(pos):
            continue
        if len(had) < len(members) or not members:
            faults.add("missing members", fid)
            continue
        if not np.isfinite(pos).all():
            faults.add("missing nodes", fid)
            continue
        where = {}
        for refs, p in had:
            where.update(zip(refs.tolist(), map(tuple, p), strict=True))
        rings, open_left = join_rings([refs for refs, _ in had])
        if open_left:
            faults.add("open rings", fid)
        shape = _nest([np.array([where[n] for n in ring.tolist()]) for ring in rings])
        if shape is None:
            faults.add("no outer", fid)
        elif (shape := valid_shape(shape, fid, faults)) is not None:
            yield Footprint(fid, {**tags, "osm_id": fid}, shape, _is_part(tags))


class OsmReader(FootprintReader):
    """OpenStreetMap buildings (XML or PBF) with the reader interface app.scene.city.read
    uses (app.scene.city.footprints.FootprintReader)."""

    def __init__(self, path: str | Path, ground: Ground) -> None:
        super().__init__(path, ground)
        self.pbf = self.path.name.lower().endswith(".pbf")
        self.format = "OpenStreetMap PBF" if self.pbf else "OpenStreetMap XML"

    def _footprints(self, keep: Keep) -> Iterator[Footprint]:
        data = read_pbf(self.path, keep) if self.pbf else read_xml(self.path)
        self.count, self.version = data.count, data.version or ""
        yield from osm_footprints(data, keep, self.faults)
