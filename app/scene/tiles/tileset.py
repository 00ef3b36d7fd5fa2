"""A 3D Tiles tileset (1.0 and 1.1) as a tree of tiles placed in the session's ENU frame.

Read per the specification: `transform` (column-major 4x4) chains from the root down and applies
to box and sphere volumes and to content, never to regions (longitude, latitude in radians and
heights on WGS84, EPSG:4979); `refine` ('ADD' or 'REPLACE', any case) is inherited; content is
`content.uri` (`url` in pre-1.0 files) or 1.1's `contents`; content that is itself a tileset JSON
is an external tileset whose root sits in the referencing tile's frame; a tile with
`implicitTiling` roots a quadtree or octree described by subtree files.

Opening reads the root tileset only. External tilesets and subtrees are read later, by
`expand()` on a worker thread (the loader), so a city opens at once. Each tile keeps a bounding
sphere and box in ENU (float64 m) for culling and screen-space error.
"""

from __future__ import annotations

import itertools
import json
import threading
from dataclasses import dataclass, field

import numpy as np

from app.core.constants import ECEF_MIN_RADIUS_M
from app.geodesy.enu import LocalFrame, ecef_to_enu_rotation, geodetic_to_ecef
from app.scene.tiles import fetch
from app.scene.tiles.gltf import Skipped
from app.scene.tiles.implicit import (
    Subtree,
    expand_template,
    level_offset,
    morton,
    read_subtree,
)

REFINES = ("ADD", "REPLACE")


MAX_ERRORS_KEPT = 8  # failures named per tileset (all are counted)


class TilesetError(ValueError):
    """A tileset JSON that cannot be read; `location` names the file, `field` the key."""

    def __init__(self, location: str, message: str, field: str | None = None) -> None:
        self.location, self.field, self.detail = location, field, message
        where = location + (f" field {field!r}" if field else "")
        super().__init__(f"{where}: {message}")


@dataclass
class Implicit:
    """Where an implicit tile sits: its tree, level, coordinates and the subtree holding it."""

    scheme_dims: int  # 2 quadtree, 3 octree
    subtree_levels: int
    available_levels: int
    subtree_template: str  # absolute, with {level} {x} {y} {z}
    content_templates: tuple[str, ...]
    root_volume: dict
    root_error: float
    level: int
    coords: tuple[int, ...]
    subtree: Subtree | None = None  # the subtree this tile lies in (None: its own, still unread)
    subtree_root: tuple[int, tuple[int, ...]] = (0, (0, 0))


@dataclass(eq=False)
class Tile:
    """One tile. `children` is None until known (external tilesets, implicit subtrees)."""

    id: int
    depth: int
    transform: np.ndarray  # (4, 4) this tile's frame -> ECEF
    center: np.ndarray  # ENU m, bounding sphere
    radius: float
    box: np.ndarray  # (2, 3) ENU AABB
    geometric_error: float
    refine: str
    contents: tuple[str, ...]  # absolute locations
    document: str  # the tileset JSON that holds the tile
    children: list[Tile] | None = field(default_factory=list)
    external: str | None = None  # the external tileset JSON its content names (read by expand())
    implicit: Implicit | None = None
    request_box: np.ndarray | None = None  # (2, 3) ENU AABB of its viewerRequestVolume, if any

    def requested_from(self, position: np.ndarray) -> bool:
        """Whether a viewer at `position` (ENU m) may see the tile: inside its
        viewerRequestVolume (bounded by its box here), or it has none."""
        b = self.request_box
        return b is None or bool(np.all((position >= b[0]) & (position <= b[1])))


def _matrix(values: object, where: str, document: str) -> np.ndarray:
    try:
        m = np.asarray(values, np.float64).reshape(4, 4).T  # column-major
    except (ValueError, TypeError) as exc:
        raise TilesetError(document, "transform must hold 16 numbers", where) from exc
    if not np.all(np.isfinite(m)):
        raise TilesetError(document, "transform holds a non-finite number", where)
    return m


def volume_points(
    volume: dict, transform: np.ndarray, document: str, where: str
) -> tuple[np.ndarray, float | None]:
    """ECEF sample points of a bounding volume (corners; a grid for regions), and a sphere's own
    radius (scaled) when the volume is a sphere."""
    try:
        if "box" in volume:
            b = np.asarray(volume["box"], np.float64).reshape(12)
            c, axes = b[:3], b[3:].reshape(3, 3)
            signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
            local = c + signs @ axes
            return local @ transform[:3, :3].T + transform[:3, 3], None
        if "region" in volume:
            w, s, e, n, lo, hi = (float(v) for v in volume["region"])
            lon = np.degrees(np.linspace(w, e if e >= w else e + 2 * np.pi, 5))
            lat = np.degrees(np.linspace(s, n, 5))
            la, lg, h = np.meshgrid(lat, lon, [lo, hi], indexing="ij")
            return geodetic_to_ecef(la.ravel(), lg.ravel(), h.ravel()), None
        if "sphere" in volume:
            s4 = np.asarray(volume["sphere"], np.float64).reshape(4)
            c = transform[:3, :3] @ s4[:3] + transform[:3, 3]
            r = s4[3] * float(np.max(np.linalg.norm(transform[:3, :3], axis=0)))
            return c + np.vstack([np.eye(3), -np.eye(3)]) * r, r
    except (ValueError, TypeError) as exc:
        raise TilesetError(document, f"bounding volume malformed: {exc}", where) from exc
    raise TilesetError(document, "bounding volume needs box, region or sphere", where)


def _georeferenced(root: object, document: str) -> bool:
    """Whether a root tile's bounding volume (after its own transform) lies in ECEF, beyond
    ECEF_MIN_RADIUS_M from the Earth's centre (a region always does)."""
    if not isinstance(root, dict) or not isinstance(root.get("boundingVolume"), dict):
        return True  # the tile reader says what is wrong with it
    if "region" in root["boundingVolume"]:
        return True
    transform = (
        _matrix(root["transform"], "root.transform", document) if "transform" in root else np.eye(4)
    )
    points, _ = volume_points(root["boundingVolume"], transform, document, "root.boundingVolume")
    return float(np.linalg.norm(points.mean(axis=0))) > ECEF_MIN_RADIUS_M


def model_matrix(
    origin: tuple[float, float, float], heading_deg: float = 0.0, scale: float = 1.0
) -> np.ndarray:
    """(4, 4) a model's Z-up coordinates -> ECEF: scaled, turned clockwise by heading_deg about
    Up, with x, y, z along east, north, up at origin (lat, lon deg, ellipsoidal h m)."""
    a = np.radians(heading_deg)
    c, s = np.cos(a), np.sin(a)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # as app.scene.loader's
    m = np.eye(4)
    m[:3, :3] = ecef_to_enu_rotation(origin[0], origin[1]).T @ turn * float(scale)
    m[:3, 3] = geodetic_to_ecef(*origin)
    return m


class Tileset:
    """The tile tree of one tileset in `frame`. Thread safety: `expand()` runs on worker threads
    (of one or several streams: the viewer and an off-screen probe may share a tileset), expands a
    tile once, and assigns its `children` at its end; readers treat None as "not yet"."""

    def __init__(
        self,
        location: str,
        frame: LocalFrame,
        origin: tuple[float, float, float] | None = None,
        heading_deg: float = 0.0,
        scale: float = 1.0,
    ) -> None:
        """origin (lat, lon deg, ellipsoidal h m), heading_deg (clockwise about Up) and scale
        place a tileset that is not georeferenced (its root near the Earth's centre: a model in
        its own Z-up coordinates, as the official 3D Tiles samples are) with a model matrix, as
        viewers do: its x, y, z become east, north, up at the origin. A georeferenced tileset
        ignores them. Raises TilesetError for one without georeference and without an origin."""
        self.location = location
        self.frame = frame
        self._ids = itertools.count()
        self._lock = threading.Lock()
        self._expanding = [threading.Lock() for _ in range(16)]  # striped by tile id
        self.tile_count = 0
        self.skipped = Skipped()  # what the readers left out, by kind, whoever read the tiles
        self.failures = 0  # tiles (or subtrees, external tilesets) missing or damaged
        self.errors: list[str] = []  # the first MAX_ERRORS_KEPT of them, named
        self._failed: set[str] = set()
        doc = self._read_json(location)
        self.version = str(doc.get("asset", {}).get("version", "?"))
        if "root" not in doc:
            raise TilesetError(location, "no root tile", "root")
        self.placed = not _georeferenced(doc["root"], location)
        model = np.eye(4)
        if self.placed:
            if origin is None:
                self._tile(doc["root"], model, None, location, 0, "root")  # its own errors first
                raise TilesetError(
                    location,
                    "this tileset is not georeferenced (its root lies near the Earth's centre, in its own "
                    "coordinates): place it with --origin LAT,LON,H (and --scene-heading, --scene-scale), "
                    "or scene.origin in a manifest",
                    "root",
                )
            model = model_matrix(origin, heading_deg, scale)
        self.root = self._tile(doc["root"], model, None, location, 0, "root")

    def add_failure(self, message: str) -> None:
        """One tile (or subtree, or external tileset) that could not be read; thread-safe. The
        same failure met again (by another stream or reader) is counted once."""
        with self._lock:
            if message in self._failed:
                return
            self._failed.add(message)
            self.failures += 1
            if len(self.errors) < MAX_ERRORS_KEPT:
                self.errors.append(message)

    def report(self) -> str | None:
        """What could not be drawn, in a line: the kinds skipped with their counts, the tiles
        missing or damaged with the first few named; None when nothing was left out."""
        parts = []
        skipped = self.skipped.snapshot()
        if skipped:
            parts.append("skipped " + ", ".join(f"{n} {k}" for k, n in sorted(skipped.items())))
        with self._lock:
            failures, errors = self.failures, list(self.errors[:3])
        if failures:
            parts.append(
                f"{failures} tile{'s' if failures > 1 else ''} missing or damaged ("
                + "; ".join(errors)
                + (", ..." if failures > len(errors) else "")
                + ")"
            )
        return f"{fetch.display_name(self.location)}: {'; '.join(parts)}" if parts else None

    def _read_json(self, location: str) -> dict:
        try:
            data = fetch.read(location)
            doc = json.loads(data.decode("utf-8-sig"))
        except fetch.FetchError:
            raise
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise TilesetError(location, f"not valid JSON: {exc}") from exc
        if not isinstance(doc, dict) or "asset" not in doc:
            raise TilesetError(location, "not a 3D Tiles tileset (no 'asset')", "asset")
        return doc

    def _new_id(self) -> int:
        with self._lock:
            self.tile_count += 1
            return next(self._ids)

    def _place(
        self, volume: dict, transform: np.ndarray, document: str, where: str
    ) -> tuple[np.ndarray, float, np.ndarray]:
        pts_ecef, own_radius = volume_points(volume, transform, document, where)
        enu = self.frame.ecef_to_enu(pts_ecef)
        box = np.stack([enu.min(axis=0), enu.max(axis=0)])
        center = box.mean(axis=0)
        radius = (
            own_radius
            if own_radius is not None
            else float(np.linalg.norm(enu - center, axis=1).max())
        )
        return center, radius, box

    def _tile(
        self,
        node: dict,
        parent_transform: np.ndarray,
        parent: Tile | None,
        document: str,
        depth: int,
        where: str,
    ) -> Tile:
        if not isinstance(node, dict):
            raise TilesetError(document, "a tile must be a JSON object", where)
        transform = (
            parent_transform @ _matrix(node["transform"], f"{where}.transform", document)
            if "transform" in node
            else parent_transform
        )
        if "boundingVolume" not in node:
            raise TilesetError(document, "tile without boundingVolume", f"{where}.boundingVolume")
        center, radius, box = self._place(
            node["boundingVolume"], transform, document, f"{where}.boundingVolume"
        )
        refine = str(node.get("refine", parent.refine if parent else "REPLACE")).upper()
        if refine not in REFINES:
            raise TilesetError(
                document,
                f"refine must be ADD or REPLACE, got {node.get('refine')!r}",
                f"{where}.refine",
            )
        try:
            error = float(node.get("geometricError", parent.geometric_error / 2 if parent else 0.0))
        except (TypeError, ValueError) as exc:
            raise TilesetError(
                document, "geometricError must be a number", f"{where}.geometricError"
            ) from exc
        if not np.isfinite(error) or error < 0:
            raise TilesetError(
                document,
                f"geometricError must be finite and >= 0, got {error}",
                f"{where}.geometricError",
            )
        if (
            "geometricError" in node
        ):  # in the tile's units: scaled as its transform scales (CesiumJS)
            error *= float(np.max(np.linalg.norm(transform[:3, :3], axis=0)))
        raw = node.get("contents") or ([node["content"]] if "content" in node else [])
        uris = []
        for c in raw:
            uri = c.get("uri", c.get("url")) if isinstance(c, dict) else None
            if not isinstance(uri, str):
                raise TilesetError(document, "content without uri", f"{where}.content")
            uris.append(uri)
        tile = Tile(
            self._new_id(), depth, transform, center, radius, box, error, refine, (), document
        )
        if "viewerRequestVolume" in node:
            _, _, tile.request_box = self._place(
                node["viewerRequestVolume"], transform, document, f"{where}.viewerRequestVolume"
            )
        if "implicitTiling" in node:
            tile.implicit = self._implicit_root(node, uris, document, where)
            tile.children = None
            return tile
        locations = [fetch.resolve(document, u) for u in uris]
        json_ = [u for u in locations if u.split("?")[0].lower().endswith(".json")]
        if json_:
            if len(locations) > 1:
                raise TilesetError(
                    document,
                    "an external tileset must be the tile's only content",
                    f"{where}.content",
                )
            tile.external, tile.children = json_[0], None
            return tile
        tile.contents = tuple(locations)
        kids = node.get("children", [])
        tile.children = [
            self._tile(k, transform, tile, document, depth + 1, f"{where}.children[{i}]")
            for i, k in enumerate(kids)
        ]
        return tile

    # -- implicit tiling -------------------------------------------------------------------
    def _implicit_root(self, node: dict, uris: list[str], document: str, where: str) -> Implicit:
        spec = node["implicitTiling"]
        scheme = str(spec.get("subdivisionScheme", "")).upper()
        if scheme not in ("QUADTREE", "OCTREE"):
            raise TilesetError(
                document,
                f"subdivisionScheme must be QUADTREE or OCTREE, got {scheme!r}",
                f"{where}.implicitTiling",
            )
        volume = node["boundingVolume"]
        if "sphere" in volume:
            raise TilesetError(
                document, "implicit tiling needs a box or region volume", f"{where}.boundingVolume"
            )
        try:
            levels = int(spec["subtreeLevels"])
            available = int(spec.get("availableLevels", spec.get("maximumLevel", 0) + 1))
            subtrees = spec["subtrees"]["uri"]
        except (KeyError, TypeError, ValueError) as exc:
            raise TilesetError(
                document,
                f"implicitTiling needs subtreeLevels, availableLevels and subtrees.uri ({exc})",
                f"{where}.implicitTiling",
            ) from exc
        dims = 2 if scheme == "QUADTREE" else 3
        return Implicit(
            dims, levels, available, fetch.resolve(document, subtrees), tuple(fetch.resolve(document, u) for u in uris),
            volume, float(node.get("geometricError", 0.0)), 0, (0,) * dims,
        )  # fmt: skip

    def _implicit_volume(self, imp: Implicit, level: int, coords: tuple[int, ...]) -> dict:
        n = float(1 << level)
        v = imp.root_volume
        if "box" in v:
            b = np.asarray(v["box"], np.float64)
            c, axes = b[:3].copy(), b[3:].reshape(3, 3).copy()
            for d in range(imp.scheme_dims):
                c += axes[d] * ((2 * coords[d] + 1) / n - 1.0)
                axes[d] /= n
            return {"box": list(c) + list(axes.ravel())}
        w, s, e, nn, lo, hi = (float(x) for x in v["region"])
        x, y = coords[0], coords[1]
        dx, dy = (e - w) / n, (nn - s) / n
        if imp.scheme_dims == 3:
            dz = (hi - lo) / n
            lo, hi = lo + coords[2] * dz, lo + (coords[2] + 1) * dz
        return {"region": [w + x * dx, s + y * dy, w + (x + 1) * dx, s + (y + 1) * dy, lo, hi]}

    def _implicit_tile(
        self,
        parent: Tile,
        level: int,
        coords: tuple[int, ...],
        subtree: Subtree | None,
        subtree_root: tuple[int, tuple[int, ...]],
    ) -> Tile:
        imp = parent.implicit
        volume = self._implicit_volume(imp, level, coords)
        center, radius, box = self._place(
            volume,
            parent.transform,
            parent.document,
            f"implicit tile {level}/{'/'.join(map(str, coords))}",
        )
        child_imp = Implicit(
            imp.scheme_dims,
            imp.subtree_levels,
            imp.available_levels,
            imp.subtree_template,
            imp.content_templates,
            imp.root_volume,
            imp.root_error,
            level,
            coords,
            subtree,
            subtree_root,
        )
        tile = Tile(
            self._new_id(),
            parent.depth + 1,
            parent.transform,
            center,
            radius,
            box,
            imp.root_error / (1 << level),
            parent.refine,
            (),
            parent.document,
            None,
            implicit=child_imp,
        )
        if subtree is not None:
            self._implicit_contents(tile)
        return tile

    def _local_index(self, imp: Implicit) -> tuple[int, tuple[int, ...]]:
        root_level, root_coords = imp.subtree_root
        local_level = imp.level - root_level
        local = tuple(c - (r << local_level) for c, r in zip(imp.coords, root_coords, strict=True))
        return local_level, local

    def _implicit_contents(self, tile: Tile) -> None:
        imp = tile.implicit
        local_level, local = self._local_index(imp)
        index = level_offset(local_level, imp.scheme_dims) + morton(local)
        tile.contents = tuple(
            expand_template(t, imp.level, imp.coords)
            for t, avail in zip(imp.content_templates, imp.subtree.contents, strict=True)
            if avail(index)
        )

    def _expand_implicit(self, tile: Tile) -> list[Tile]:
        imp = tile.implicit
        if imp.subtree is None:  # this tile roots a subtree that has not been read yet
            uri = expand_template(imp.subtree_template, imp.level, imp.coords)
            imp.subtree = read_subtree(fetch.read(uri), lambda u: fetch.read(fetch.resolve(uri, u)))
            imp.subtree_root = (imp.level, imp.coords)
            if not imp.subtree.tiles(0):
                return []
            self._implicit_contents(tile)
        if imp.level + 1 >= imp.available_levels:
            return []
        local_level, local = self._local_index(imp)
        kids = []
        for bits in itertools.product((0, 1), repeat=imp.scheme_dims):
            coords = tuple(2 * c + b for c, b in zip(imp.coords, bits, strict=True))
            child_local = tuple(2 * c + b for c, b in zip(local, bits, strict=True))
            if local_level + 1 < imp.subtree_levels:
                index = level_offset(local_level + 1, imp.scheme_dims) + morton(child_local)
                if imp.subtree.tiles(index):
                    kids.append(
                        self._implicit_tile(
                            tile, imp.level + 1, coords, imp.subtree, imp.subtree_root
                        )
                    )
            elif imp.subtree.children(morton(child_local)):
                kids.append(
                    self._implicit_tile(tile, imp.level + 1, coords, None, (imp.level + 1, coords))
                )
        return kids

    def expand(self, tile: Tile) -> None:
        """Read what a tile's children need (an external tileset, a subtree) and set them. Runs
        on a worker; raises FetchError, TilesetError or SubtreeError naming the file."""
        with self._expanding[tile.id % len(self._expanding)]:  # several streams may share a tileset
            if tile.children is not None:
                return
            if tile.implicit is not None:
                kids = self._expand_implicit(tile)
            else:
                location = tile.external
                doc = self._read_json(location)
                if "root" not in doc:
                    raise TilesetError(location, "no root tile", "root")
                kids = [
                    self._tile(doc["root"], tile.transform, tile, location, tile.depth + 1, "root")
                ]
            tile.children = kids

    def bounds(self) -> np.ndarray:
        """(2, 3) ENU box of the root's bounding volume, m."""
        return self.root.box
