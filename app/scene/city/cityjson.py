"""CityJSON 1.0/1.1/2.0 documents (`.city.json`) and CityJSON Sequences (`.city.jsonl`), read
one city object at a time.

A CityJSON document keeps every vertex in one array and its objects in one dictionary; both are
read with ijson's streaming parser (the C backend), the vertices into a numpy array (the only
thing held whole: 24 bytes a vertex), the objects one by one, so a district of 100,000 buildings
never becomes one Python structure. A Sequence (CityJSONL) is a header line and then one
CityJSONFeature a line, each with its own vertices: read line by line.

Geometry: MultiSurface, CompositeSurface, Solid (outer and inner shells), MultiSolid,
CompositeSolid and GeometryInstance (a template placed by its matrix); of an object's
geometries the one of highest LoD (at most `max_lod`) is drawn. Semantic surfaces give each
surface its kind. A BuildingPart's parent attributes are merged under its own.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import ijson
import numpy as np

from app.core.errors import SceneError
from app.scene.city.model import CityObject, Surface, footprint_centre, kind_of
from app.scene.city.paths import texture_file

VERSIONS = ("1.0", "1.1", "2.0")
SURFACE_DEPTH = {  # nesting of `boundaries` down to a surface (a list of rings)
    "MultiSurface": 1,
    "CompositeSurface": 1,
    "Solid": 2,
    "MultiSolid": 3,
    "CompositeSolid": 3,
}
VERTEX_BLOCK = 65536

Keep = Callable[[np.ndarray], bool]  # a city object's horizontal centre (CRS) -> read it?


@dataclass
class Header:
    """What a CityJSON file says of itself: version, CRS (as written, None if absent), the
    vertices' transform (scale (3,), translate (3,)), geometry templates, the texture
    images (paths as written, relative to the file) and the materials' diffuse colours (RGB in
    [0, 1]; None for a material without one)."""

    version: str
    crs: str | None
    scale: np.ndarray
    translate: np.ndarray
    templates: list[dict]
    template_vertices: np.ndarray
    textures: list[str]
    materials: list[tuple[float, float, float] | None]


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _numbers(items: object, width: int, start: int = 0) -> np.ndarray:
    """(N, width) float64 of a JSON array of `width`-number arrays (vertices, texture
    coordinates); ValueError naming the first item (its index from `start`) that is not
    `width` numbers: a string such as "12.5" is refused, not converted."""
    if not isinstance(items, list):
        raise ValueError(f"a {type(items).__name__} (expected a list of [{width} numbers])")
    if not items:
        return np.zeros((0, width))
    try:
        out = np.asarray(items)  # numbers only give a numeric array (fast, in C)
    except ValueError:  # ragged
        out = None
    if out is not None and out.dtype.kind in "iuf" and out.shape[1:] == (width,):
        return out.astype(np.float64)
    for i, item in enumerate(items):  # what is wrong, named
        if not isinstance(item, list) or len(item) != width or not all(map(_is_number, item)):
            shown = repr(item) if len(repr(item)) <= 60 else repr(item)[:57] + "..."
            raise ValueError(f"item {start + i} is {shown} (expected {width} numbers)")
    return np.asarray(items, np.float64)  # numbers all, some beyond int64


def _lod_value(lod: object) -> float:
    try:
        return float(str(lod))
    except ValueError:
        return -1.0


def _flat(boundaries: list, depth: int) -> list[int]:
    """Every vertex index of `boundaries` whose surfaces lie `depth` lists down."""
    if depth == 1:
        return [i for surface in boundaries for ring in surface for i in ring]
    if depth == 2:
        return [i for shell in boundaries for surface in shell for ring in surface for i in ring]
    return [i for solid in boundaries for part in _flat_solid(solid) for i in part]


def _flat_solid(solid: list) -> list[list[int]]:
    return [ring for shell in solid for surface in shell for ring in surface]


def _surfaces_of(boundaries: list, depth: int) -> list[tuple[list, tuple[int, ...]]]:
    """(rings, path) of each surface: path indexes `semantics.values` the same way."""
    if depth == 1:
        return [(rings, (i,)) for i, rings in enumerate(boundaries)]
    return [
        (rings, (i, *path))
        for i, inner in enumerate(boundaries)
        for rings, path in _surfaces_of(inner, depth - 1)
    ]


def _theme_of(
    themes: object, theme: str | None, seen: set[str], default: Callable[[], str | None]
) -> object:
    """A geometry's `texture` or `material` object's entry for `theme`, None where it has none;
    theme None: the file's default theme (`default()`, asked only where a geometry has several)
    where the geometry has it, else its first by name. The names it holds are added to `seen`."""
    if not isinstance(themes, dict) or not themes:
        return None
    seen.update(str(k) for k in themes)
    if theme is not None:
        return themes.get(theme)
    if len(themes) > 1 and (named := default()) in themes:
        return themes[named]
    return themes[sorted(themes)[0]]


def _texture_values(
    texture: object, theme: str | None, seen: set[str], default: Callable[[], str | None]
) -> list | None:
    """The `values` of a geometry's texture theme (`_theme_of`; None without textures)."""
    chosen = _theme_of(texture, theme, seen, default)
    return chosen.get("values") if isinstance(chosen, dict) else None


def _diffuse(material: object) -> tuple[float, float, float] | None:
    """A material's diffuseColor (RGB in [0, 1]), None without a usable one."""
    try:
        rgb = tuple(float(c) for c in material["diffuseColor"])
    except (KeyError, TypeError, ValueError):
        return None
    return rgb if len(rgb) == 3 and all(np.isfinite(rgb)) else None


def _material_index(
    material: object,
    path: tuple[int, ...],
    theme: str | None,
    seen: set[str],
    default: Callable[[], str | None],
) -> int | None:
    """The surface's material (path: its index in the boundaries' nesting) in the geometry's
    material theme (`_theme_of`): `value` for all its surfaces, else `values` nested as the
    surfaces."""
    theme = _theme_of(material, theme, seen, default)
    if not isinstance(theme, dict):
        return None
    if theme.get("value") is not None:
        values = theme["value"]
    else:
        values = theme.get("values")
        try:
            for i in path:
                values = None if values is None else values[i]
        except (IndexError, TypeError):
            return None
    return (
        int(values) if isinstance(values, (int, float)) and not isinstance(values, bool) else None
    )


def _semantic_type(semantics: dict | None, path: tuple[int, ...]) -> str | None:
    if not semantics:
        return None
    values = semantics.get("values")
    try:
        for i in path:
            if values is None:
                return None
            values = values[i]
        if values is None:
            return None
        return semantics["surfaces"][int(values)].get("type")
    except (IndexError, KeyError, TypeError):
        return None


class CityJsonReader:
    """Reads one CityJSON document or Sequence. `header` first; `objects(keep)` then yields the
    objects whose horizontal centre `keep` accepts; `count` is how many objects with geometry
    the file holds (known after `objects` ran)."""

    def __init__(self, path: str | Path, max_lod: float = 9.0, theme: str | None = None) -> None:
        self.path = Path(path)
        self.sequence = self.path.suffix.lower() == ".jsonl"
        self.max_lod = max_lod
        # the appearance theme drawn (None: the file's default-theme-texture / -material where a
        # geometry has it, else each geometry's first by name)
        self.theme = theme
        self.themes: set[str] = set()  # the texture and material themes the objects read name
        self.notes: list[str] = []  # what was read but cannot be drawn (CityGmlReader's)
        self._defaults: dict[str, str | None] = {}  # the file's default themes, once read
        self.count = 0
        self.header = self._read_header()
        self._vertices: np.ndarray | None = None
        self._uvs: np.ndarray | None = None

    # -- the header ----------------------------------------------------------------------------

    def _error(self, message: str, field: str | None = None, line: int | None = None) -> SceneError:
        return SceneError(self.path, message, field=field, line=line)

    def _items(self, prefix: str) -> object:
        """The first value at `prefix` of the document (None if absent), streamed."""
        try:
            with self.path.open("rb") as f:
                return next(ijson.items(f, prefix, use_float=True), None)
        except (ijson.JSONError, ijson.IncompleteJSONError) as exc:
            raise self._error(f"broken JSON: {exc} (expected a CityJSON document)") from exc

    def _read_header(self) -> Header:
        if self.sequence:
            with self.path.open("rb") as f:
                first = f.readline()
            try:
                doc = json.loads(first)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise self._error(f"broken JSON: {exc}", line=1) from exc
            if not isinstance(doc, dict):
                raise self._error("expected the CityJSON header object", line=1)
            get = doc.get
        else:
            cache: dict[str, object] = {}

            def get(key: str, default: object = None) -> object:
                if key not in cache:
                    cache[key] = self._items(key)
                return default if cache[key] is None else cache[key]

        kind = get("type")
        if kind != "CityJSON":
            raise self._error(f"got type {kind!r}, expected 'CityJSON'", field="type")
        version = str(get("version", ""))
        if not any(version == v or version.startswith(v + ".") for v in VERSIONS):
            raise self._error(
                f"version {version!r} not read (expected {', '.join(VERSIONS)})", field="version"
            )
        transform = get("transform") or {}
        try:
            scale, translate = _numbers(
                [transform.get("scale", [1.0] * 3), transform.get("translate", [0.0] * 3)], 3
            )
        except (AttributeError, ValueError):
            raise self._error(
                "expected 3 numbers in scale and translate", field="transform"
            ) from None
        if not np.isfinite([scale, translate]).all() or not scale.all():
            raise self._error("expected finite numbers and no zero scale", field="transform")
        metadata = get("metadata") or {}
        crs = metadata.get("referenceSystem") if isinstance(metadata, dict) else None
        templates = get("geometry-templates") or {}
        if not isinstance(templates, dict):
            raise self._error("expected an object", field="geometry-templates")
        tv = self._checked(
            templates.get("vertices-templates", []), 3, "geometry-templates.vertices-templates"
        )
        if self.sequence:
            textures = (get("appearance") or {}).get("textures")
            materials = (get("appearance") or {}).get("materials")
        else:
            textures = get("appearance.textures")
            materials = get("appearance.materials")
        images = [str(t.get("image", "")) for t in textures or [] if isinstance(t, dict)]
        colours = [_diffuse(m) for m in materials or []]
        return Header(
            version, crs, scale, translate, templates.get("templates", []), tv, images, colours
        )

    def _default_theme(self, kind: str) -> str | None:
        """The file's `appearance.default-theme-texture` or `-material` (kind), read once and
        only when a geometry has several themes (a document is streamed for it)."""
        key = f"default-theme-{kind}"
        if key not in self._defaults:
            if self.sequence:
                with self.path.open("rb") as f:
                    header = json.loads(f.readline())
                value = (header.get("appearance") or {}).get(key)
            else:
                value = self._items(f"appearance.{key}")
            self._defaults[key] = value if isinstance(value, str) else None
        return self._defaults[key]

    @property
    def default_texture_theme_read(self) -> str | None:
        """The file's default texture theme, where it names one and a geometry with several
        themes made the reader look (None otherwise)."""
        return self._defaults.get("default-theme-texture")

    # -- vertices ------------------------------------------------------------------------------

    def _checked(
        self, items: object, width: int, field: str, line: int | None = None
    ) -> np.ndarray:
        """(N, width) float64 of a JSON array of `width`-number arrays held whole (a
        CityJSONFeature's, the templates'), refused naming `field` unless numbers, all finite."""
        try:
            out = _numbers(items, width)
        except ValueError as exc:
            raise self._error(str(exc), field=field, line=line) from None
        if not np.isfinite(out).all():
            raise self._error("numbers that are not finite", field=field, line=line)
        return out

    def _real(self, ints: np.ndarray) -> np.ndarray:
        return ints * self.header.scale + self.header.translate

    def _array(self, prefix: str, width: int, field: str) -> np.ndarray:
        """(N, width) float64 of the document's array at `prefix`, read in blocks."""
        blocks, block = [], []

        def close(block: list) -> None:
            try:
                blocks.append(_numbers(block, width, VERTEX_BLOCK * len(blocks)))
            except ValueError as exc:
                raise self._error(str(exc), field=field) from None

        try:
            with self.path.open("rb") as f:
                for v in ijson.items(f, prefix, use_float=True):
                    block.append(v)
                    if len(block) == VERTEX_BLOCK:
                        close(block)
                        block = []
        except (ijson.JSONError, ijson.IncompleteJSONError) as exc:
            raise self._error(f"broken JSON: {exc}", field=field) from exc
        except ValueError as exc:
            raise self._error(f"{exc} (expected numbers)", field=field) from exc
        if block:
            close(block)
        out = np.concatenate(blocks) if blocks else np.zeros((0, width))
        blocks.clear()
        if not np.isfinite(out).all():
            raise self._error("numbers that are not finite", field=field)
        return out

    def vertices(self) -> np.ndarray:
        """(N, 3) float64 CRS coordinates of a document's vertices (transform applied), read in
        blocks."""
        if self._vertices is None:
            v = self._array("vertices.item", 3, "vertices")
            v *= self.header.scale
            v += self.header.translate
            self._vertices = v
        return self._vertices

    def texture_vertices(self) -> np.ndarray:
        """(N, 2) texture coordinates of a document (none when it has no textures)."""
        if self._uvs is None:
            self._uvs = (
                self._array("appearance.vertices-texture.item", 2, "appearance.vertices-texture")
                if self.header.textures
                else np.zeros((0, 2))
            )
        return self._uvs

    # -- objects -------------------------------------------------------------------------------

    def _raw_objects(self) -> Iterator[tuple[str, dict, np.ndarray, np.ndarray, int | None]]:
        """(id, object, its vertices (N, 3) CRS, its texture coordinates (M, 2), line) of every
        object in the file."""
        if not self.sequence:
            vertices, uvs = self.vertices(), self.texture_vertices()
            try:
                with self.path.open("rb") as f:
                    for oid, obj in ijson.kvitems(f, "CityObjects", use_float=True):
                        yield oid, obj, vertices, uvs, None
            except (ijson.JSONError, ijson.IncompleteJSONError) as exc:
                raise self._error(f"broken JSON: {exc}", field="CityObjects") from exc
            return
        with self.path.open("rb") as f:
            f.readline()
            for number, line in enumerate(f, start=2):
                if not line.strip():
                    continue
                try:
                    feature = json.loads(line)
                    objects = feature["CityObjects"].items()
                    appearance = feature.get("appearance") or {}
                    uv_items = appearance.get("vertices-texture", [])
                except (json.JSONDecodeError, UnicodeDecodeError, AttributeError, KeyError) as exc:
                    raise self._error(f"broken CityJSONFeature: {exc}", line=number) from exc
                local = self._checked(feature.get("vertices", []), 3, "vertices", number)
                uvs = self._checked(uv_items, 2, "appearance.vertices-texture", number)
                real = self._real(local)
                for oid, obj in objects:
                    yield oid, obj, real, uvs, number

    def _geometry(self, oid: str, obj: dict) -> tuple[int, dict] | None:
        """(index, geometry) of the object's highest LoD at most max_lod."""
        best = None
        for g, geom in enumerate(obj.get("geometry") or []):
            lod = geom.get("lod")
            if geom.get("type") == "GeometryInstance":
                t = geom.get("template")
                if not isinstance(t, int) or not 0 <= t < len(self.header.templates):
                    raise self._error(
                        f"template {t!r} not among the file's {len(self.header.templates)}",
                        field=f"CityObjects.{oid}.geometry[{g}]",
                    )
                lod = self.header.templates[t].get("lod")
            value = _lod_value(lod)
            if value <= self.max_lod and (best is None or value > best[0]):
                best = (value, g, geom)
        return None if best is None else (best[1], best[2])

    def _instance(
        self, oid: str, g: int, geom: dict, vertices: np.ndarray
    ) -> tuple[dict, np.ndarray]:
        """A GeometryInstance as (template geometry, its vertices placed in CRS coordinates)."""
        where = f"CityObjects.{oid}.geometry[{g}]"
        template = self.header.templates[geom["template"]]
        try:
            anchor = vertices[int(geom["boundaries"][0])]
            m = np.asarray(geom.get("transformationMatrix", np.eye(4).ravel()), np.float64)
            m = m.reshape(4, 4)
        except (IndexError, KeyError, TypeError, ValueError) as exc:
            raise self._error(f"broken GeometryInstance: {exc}", field=where) from exc
        tv = self.header.template_vertices
        placed = tv @ m[:3, :3].T + m[:3, 3] + anchor
        return template, placed

    def objects(self, keep: Keep | None = None) -> Iterator[CityObject]:
        """The file's city objects with geometry whose centre `keep` accepts (all if None)."""
        for oid, obj, vertices, uvs, line in self._raw_objects():
            if not isinstance(obj, dict):
                raise self._error("expected a city object", field=f"CityObjects.{oid}", line=line)
            chosen = self._geometry(oid, obj)
            if chosen is None:
                continue
            self.count += 1
            g, geom = chosen
            where = f"CityObjects.{oid}.geometry[{g}]"
            if geom.get("type") == "GeometryInstance":
                geom, vertices = self._instance(oid, g, geom, vertices)
            depth = SURFACE_DEPTH.get(geom.get("type", ""))
            if depth is None:
                continue  # points and lines draw nothing
            boundaries = geom.get("boundaries") or []
            try:
                index = np.asarray(_flat(boundaries, depth), np.int64)
            except (TypeError, ValueError) as exc:
                raise self._error(
                    f"broken boundaries: {exc} (expected {geom.get('type')} nesting)",
                    field=where,
                    line=line,
                ) from exc
            if not len(index):
                continue
            if index.min() < 0 or index.max() >= len(vertices):
                raise self._error(
                    f"vertex index {int(index.max() if index.max() >= len(vertices) else index.min())} "
                    f"out of range (the file has {len(vertices)} vertices)",
                    field=where,
                    line=line,
                )
            centre = footprint_centre(vertices[index])
            if keep is not None and not keep(centre):
                continue
            otype = str(obj.get("type", ""))
            surfaces = []
            textured = _texture_values(
                geom.get("texture"),
                self.theme,
                self.themes,
                partial(self._default_theme, "texture"),
            )
            for rings, path in _surfaces_of(boundaries, depth):
                kind = kind_of(_semantic_type(geom.get("semantics"), path), otype)
                surface = Surface([vertices[np.asarray(r, np.int64)] for r in rings], kind)
                m = _material_index(
                    geom.get("material"),
                    path,
                    self.theme,
                    self.themes,
                    partial(self._default_theme, "material"),
                )
                if m is not None and 0 <= m < len(self.header.materials):
                    surface.colour = self.header.materials[m]
                if textured is not None:
                    self._texture(surface, textured, path, uvs, where, line)
                surfaces.append(surface)
            parents = obj.get("parents") or []
            yield CityObject(
                str(oid),
                otype,
                dict(obj.get("attributes") or {}),
                surfaces,
                centre,
                str(geom.get("lod", "")),
                str(parents[0]) if parents else None,
            )

    def _texture(
        self,
        surface: Surface,
        values: list,
        path: tuple[int, ...],
        uvs: np.ndarray,
        where: str,
        line: int | None,
    ) -> None:
        """Give the surface its texture and coordinates from a theme's `values` (nested as the
        boundaries, one [texture, uv index per vertex] list a ring), when every ring has them."""
        try:
            rings = values
            for i in path:
                rings = rings[i]
            if rings is None or not all(r and r[0] is not None for r in rings):
                return
            texture = int(rings[0][0])
            coords = [uvs[np.asarray(r[1:], np.int64)] for r in rings]
        except (IndexError, TypeError, ValueError) as exc:
            raise self._error(
                f"texture values do not match the boundaries ({exc})",
                field=f"{where}.texture",
                line=line,
            ) from exc
        if not 0 <= texture < len(self.header.textures):
            raise self._error(
                f"texture {texture} not among the file's {len(self.header.textures)}",
                field=f"{where}.texture",
                line=line,
            )
        if any(len(c) != len(r) for c, r in zip(coords, surface.rings, strict=True)):
            raise self._error(
                "texture coordinates and ring vertices differ in number",
                field=f"{where}.texture",
                line=line,
            )
        surface.texture, surface.uvs = texture, coords

    @property
    def texture_uris(self) -> list[str]:
        """The texture images as the file names them, in the order surfaces name them."""
        return self.header.textures

    def texture_files(self) -> list[Path | None]:
        """The texture images (relative to the file), in the order surfaces name them; None
        for one outside the file's folder (app.scene.city.paths: never read)."""
        return [texture_file(self.path, t) for t in self.header.textures]

    def attributes_of(self, ids: set[str]) -> dict[str, dict]:
        """The attributes of the objects named (parents of the objects read), in one pass."""
        out: dict[str, dict] = {}
        if not ids:
            return out
        for oid, obj, _, _, _ in self._raw_objects():
            if oid in ids and isinstance(obj, dict):
                out[oid] = dict(obj.get("attributes") or {})
                if len(out) == len(ids):
                    break
        return out
