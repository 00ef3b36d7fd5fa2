"""CityGML 1.0/2.0/3.0 (`.gml`, `.xml`, or either inside a `.zip`), read one city object at a time.

lxml's `iterparse` walks the file and each `cityObjectMember` is read and then freed, so a
district of 100,000 buildings is never one tree in memory. Of an object the polygons
(`gml:Polygon`, `gml:Triangle`) are the geometry, read where they are defined (a solid that
refers to its boundary surfaces by xlink is thus read once); each takes its semantic kind from
the boundary surface around it (bldg:RoofSurface, con:WallSurface, ...) and its LoD from the
property around it (lod2MultiSurface, lod1Solid, ...); the object's highest LoD (at most
`max_lod`) is drawn. BuildingParts are objects of their own, with their building as parent.
Attributes: generic attributes (2.0 and 3.0 forms), simple properties (measuredHeight,
function, yearOfConstruction...) and the address, as one line.

Appearances of one theme are drawn (`theme`; by default the first the file names):
ParameterizedTextures by their rings' texture coordinates, GeoreferencedTextures (an image laid
on the ground plan, a roof's or a relief's orthophoto) by the file's horizontal coordinates
through the image's georeference: inline, a referencePoint (the centre of the image's upper-left
pixel) and an orientation (row-major A B / D E as a world file's: x = A col + B row + x0,
y = D col + E row + y0, in the CRS's units per pixel), or the world file beside the image
(`.pgw`, `.jgw`, `.tfw`, `.wld`...: A, D, B, E, x0, y0) or a GeoTIFF's own georeference tags
(before its world file, as GDAL reads them; in the file's horizontal CRS, else refused), which
win where preferWorldFile (by default true); and X3DMaterials' diffuse colours.
"""

from __future__ import annotations

import re
import warnings
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TypeVar

import numpy as np
import pyproj
import rasterio
from lxml import etree
from PIL import Image, UnidentifiedImageError
from rasterio.errors import NotGeoreferencedWarning, RasterioError

from app.core.errors import SceneError
from app.geodesy.crs import horizontal, of_raster, parse_crs
from app.scene.city.cityjson import Keep
from app.scene.city.model import SURFACE_KINDS, CityObject, Surface, footprint_centre, kind_of
from app.scene.city.paths import outside_note, texture_file

SUFFIXES = (".gml", ".xml", ".zip")
PART_NAMES = ("BuildingPart", "BridgePart", "TunnelPart")
LOD_PATTERN = re.compile(r"^lod(\d)")
GML_ID = "{http://www.opengis.net/gml}id"
GML32_ID = "{http://www.opengis.net/gml/3.2}id"
XLINK_HREF = "{http://www.w3.org/1999/xlink}href"
MEMBERS = ("cityObjectMember", "featureMember", "member")
T = TypeVar("T")
GENERIC = ("stringAttribute", "intAttribute", "doubleAttribute", "dateAttribute", "uriAttribute")


def _local(el: etree._Element) -> str:
    tag = el.tag
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _coordinates(ring: etree._Element) -> np.ndarray:
    """(N, 3) of a gml:LinearRing (posList, pos or the old coordinates), open (last dropped
    when it repeats the first)."""
    values: list[float] = []
    dim = 3
    for el in ring.iter():
        name = _local(el)
        if name == "posList":
            dim = int(el.get("srsDimension") or el.get("dimension") or 3)
            values += [float(v) for v in (el.text or "").split()]
        elif name == "pos":
            values += [float(v) for v in (el.text or "").split()]
        elif name == "coordinates":
            values += [float(v) for v in re.split(r"[,\s]+", (el.text or "").strip()) if v]
    if dim != 3 or len(values) % 3:
        raise ValueError(f"{len(values)} numbers in a ring, expected x y z triples")
    p = np.asarray(values, np.float64).reshape(-1, 3)
    if len(p) > 1 and np.array_equal(p[0], p[-1]):
        p = p[:-1]
    return p


class CityGmlReader:
    """Reads one CityGML file. `crs` (the first srsName, None if none) is known once the first
    object is read; `objects(keep)` yields the objects whose horizontal centre `keep` accepts;
    `count`: objects with geometry seen."""

    def __init__(self, path: str | Path, max_lod: float = 9.0, theme: str | None = None) -> None:
        self.path = Path(path)
        self.max_lod = max_lod
        self.theme = theme  # the appearance theme drawn (None: the first the file names)
        self.themes: set[str] = set()  # the themes the appearances read name ("" unnamed)
        self.notes: list[str] = []  # what was read but cannot be drawn, said once each
        self.count = 0
        self.crs: str | None = None
        self.version: str | None = None
        self.textures: list[str] = []
        self._texture_ids: dict[str, int] = {}
        self.ring_textures: dict[str, tuple[int, np.ndarray]] = {}
        self.target_colours: dict[str, tuple[float, float, float]] = {}  # X3DMaterial, by gml:id
        # GeoreferencedTexture by the gml:id of each surface it targets: (texture index, file
        # x, y -> the image's column, row as a 2 x 3 affine matrix: the georeference inverted)
        self.target_georef: dict[str, tuple[int, np.ndarray]] = {}
        self._image_sizes: dict[int, tuple[int, int] | None] = {}
        # GeoTIFF textures' own CRS (and the line naming them), checked once an object is read
        self._georef_crs: dict[Path, tuple[pyproj.CRS, int | None]] = {}

    def _error(self, message: str, field: str | None = None, line: int | None = None) -> SceneError:
        return SceneError(self.path, message, field=field, line=line)

    @property
    def texture_uris(self) -> list[str]:
        """The texture images as the file names them, in the order surfaces name them."""
        return self.textures

    def texture_files(self) -> list[Path | None]:
        """The texture images (ParameterizedTexture imageURI, relative to the file), in the
        order surfaces name them; None for one outside the file's folder
        (app.scene.city.paths: never read)."""
        return [texture_file(self.path, uri) for uri in self.textures]

    def _texture_index(self, uri: str) -> int:
        if uri not in self._texture_ids:
            self._texture_ids[uri] = len(self.textures)
            self.textures.append(uri)
        return self._texture_ids[uri]

    def _read_textures(self, root: etree._Element) -> None:
        """Every Appearance of the theme drawn under `root`: its ParameterizedTextures' images
        and the coordinates they give each ring (by the ring's gml:id, `ring_textures`), its
        GeoreferencedTextures by the gml:id of each surface they target (`target_georef`) and
        its X3DMaterials' diffuse colours likewise (`target_colours`)."""
        for appearance in root.iter("{*}Appearance"):
            name = next(((c.text or "").strip() for c in appearance if _local(c) == "theme"), "")
            self.themes.add(name)
            if self.theme is None:
                self.theme = name
            if name != self.theme:
                continue
            self._read_materials(appearance)
            self._read_parameterized(appearance)
            self._read_georeferenced(appearance)

    def _read_materials(self, appearance: etree._Element) -> None:
        for mat in appearance.iter("{*}X3DMaterial"):
            text = next((c.text for c in mat.iter("{*}diffuseColor") if c.text), None)
            try:
                rgb = tuple(float(v) for v in (text or "").split())
            except ValueError:
                rgb = ()
            if len(rgb) != 3 or not np.all(np.isfinite(rgb)):
                continue
            for target in _targets(mat):
                self.target_colours[target] = rgb

    def _read_parameterized(self, appearance: etree._Element) -> None:
        for tex in appearance.iter("{*}ParameterizedTexture"):
            uri = next((c.text for c in tex.iter("{*}imageURI") if c.text), None)
            if not uri:
                continue
            index = self._texture_index(uri.strip())
            for coords in tex.iter("{*}textureCoordinates"):
                ring = (coords.get("ring") or "").lstrip("#")
                try:
                    uv = np.asarray([float(v) for v in (coords.text or "").split()], np.float64)
                    uv = uv.reshape(-1, 2)
                except ValueError as exc:
                    raise self._error(
                        f"texture coordinates: {exc} (expected u v pairs)", line=coords.sourceline
                    ) from exc
                if len(uv) > 1 and np.array_equal(uv[0], uv[-1]):
                    uv = uv[:-1]
                if ring:
                    self.ring_textures[ring] = (index, uv)

    def _read_georeferenced(self, appearance: etree._Element) -> None:
        for tex in appearance.iter("{*}GeoreferencedTexture"):
            uri = next((c.text for c in tex.iter("{*}imageURI") if c.text), None)
            if not uri:
                continue
            image = texture_file(self.path, uri)
            if image is None:
                if (note := outside_note(self.path, uri)) not in self.notes:
                    self.notes.append(note)
                continue
            prefer = next((c.text for c in tex if _local(c) == "preferWorldFile"), None)
            affine = None
            if (prefer or "true").strip().lower() in ("true", "1"):
                affine = self._image_georef(image, tex)
            affine = affine if affine is not None else self._inline_georef(tex)
            if affine is None:
                self.notes.append(
                    f"{self.path.name}: GeoreferencedTexture {uri.strip()} (line {tex.sourceline}) "
                    "not drawn: no referencePoint and orientation, no world file beside the "
                    "image and no georeference in it"
                )
                continue
            if abs(np.linalg.det(affine[:, :2])) < 1e-12:
                raise self._error(
                    f"GeoreferencedTexture {uri.strip()}: its georeference maps the image to a "
                    "line or a point (expected an orientation with an inverse)",
                    line=tex.sourceline,
                )
            inverse = np.linalg.inv(affine[:, :2])
            to_pixels = np.column_stack([inverse, -inverse @ affine[:, 2]])
            index = self._texture_index(uri.strip())
            for target in _targets(tex):
                self.target_georef[target] = (index, to_pixels)

    def _image_georef(self, image: Path, tex: etree._Element) -> np.ndarray | None:
        """The image's own georeference (2 x 3, as `_inline_georef`): a GeoTIFF's tags, else the
        world file beside it (GDAL's order); None with neither. A GeoTIFF whose CRS is not the
        file's is refused (its texture would land elsewhere), naming both."""
        if image.suffix.lower() in (".tif", ".tiff") and image.is_file():
            found = _geotiff_georef(image)
            if found is not None:
                affine, crs = found
                if crs is not None:  # checked against the file's once an object names it
                    self._georef_crs[image] = (crs, tex.sourceline)
                return affine
        return _world_file(image)

    def _check_georef_crs(self, image: Path) -> None:
        """Refuses a GeoTIFF texture georeferenced in another horizontal CRS than the file's
        coordinates (its texture would land elsewhere), naming both."""
        crs, line = self._georef_crs.pop(image, (None, None))
        if crs is None or self.crs is None:
            return
        ours = horizontal(parse_crs(self.crs))
        if not _same_crs(ours, horizontal(crs)):
            raise self._error(
                f"GeoreferencedTexture {image.name}: the image is georeferenced in {crs.name} but "
                f"the file's coordinates are in {ours.name} (expected the same horizontal CRS)",
                line=line,
            )

    def _inline_georef(self, tex: etree._Element) -> np.ndarray | None:
        """The 2 x 3 affine matrix (image column, row, 1 -> file x, y) of a
        GeoreferencedTexture's referencePoint and orientation, None without both."""
        point = next((c for c in tex if _local(c) == "referencePoint"), None)
        matrix = next((c for c in tex if _local(c) == "orientation"), None)
        if point is None or matrix is None:
            return None
        pos = next((c.text for c in point.iter("{*}pos", "{*}coordinates") if c.text), "")
        try:
            xy = [float(v) for v in pos.replace(",", " ").split()][:2]
            m = [float(v) for v in (matrix.text or "").split()]
        except ValueError as exc:
            raise self._error(
                f"GeoreferencedTexture: {exc} (expected numbers)", line=tex.sourceline
            ) from exc
        if len(xy) != 2 or len(m) != 4 or not np.all(np.isfinite([*xy, *m])):
            raise self._error(
                "GeoreferencedTexture: expected a 2D referencePoint and a 2 x 2 orientation",
                line=tex.sourceline,
            )
        return np.array([[m[0], m[1], xy[0]], [m[2], m[3], xy[1]]])

    def _image_size(self, index: int) -> tuple[int, int] | None:
        """(width, height) of a texture image, None where it cannot be read (said when the
        images are loaded)."""
        if index not in self._image_sizes:
            file, size = self.texture_files()[index], None
            if file is not None:  # None: outside the file's folder, never read (said)
                try:
                    with Image.open(file) as img:
                        size = img.size
                except (OSError, UnidentifiedImageError):
                    pass
            self._image_sizes[index] = size
        return self._image_sizes[index]

    def _georeferenced_uvs(
        self, polygon: etree._Element, obj: etree._Element, rings: list[np.ndarray]
    ) -> tuple[int, list[np.ndarray]] | None:
        """(texture, each ring's texture coordinates) of the GeoreferencedTexture targeting the
        polygon or a surface around it: each vertex's pixel through the inverse georeference,
        as (s, t) with t up (CityGML's texture space: (0, 0) the image's lower-left corner)."""
        found = _targeted(polygon, obj, self.target_georef)
        if found is None:
            return None
        index, to_pixels = found
        self._check_georef_crs(self.texture_files()[index])
        size = self._image_size(index)
        if size is None:
            return None
        out = []
        for ring in rings:
            col, row = to_pixels[:, :2] @ ring[:, :2].T + to_pixels[:, 2:]
            out.append(np.column_stack([(col + 0.5) / size[0], 1.0 - (row + 0.5) / size[1]]))
        return index, out

    def _global_appearances(self) -> None:
        """Appearances kept apart from the objects (CityModel/appearanceMember, often after
        them): read in a first pass when the file has any, so that one pass over the objects
        finds them."""
        with self._open() as f:
            found = False
            while chunk := f.read(1 << 22):
                if b"appearanceMember" in chunk:
                    found = True
                    break
        if not found:
            return
        with self._open() as f:
            for _, el in etree.iterparse(
                f, events=("end",), tag="{*}appearanceMember", huge_tree=True
            ):
                self._read_textures(el)
                el.clear()

    @contextmanager
    def _open(self) -> Iterator[IO[bytes]]:
        if self.path.suffix.lower() != ".zip":
            with self.path.open("rb") as f:
                yield f
            return
        try:
            archive = zipfile.ZipFile(self.path)
        except zipfile.BadZipFile as exc:
            raise self._error(f"not a zip archive: {exc}") from exc
        with archive:
            members = [
                i for i in archive.infolist() if i.filename.lower().endswith((".gml", ".xml"))
            ]
            if not members:
                raise self._error("the archive holds no .gml or .xml file (expected CityGML)")
            biggest = max(members, key=lambda i: i.file_size)
            with archive.open(biggest) as f:
                yield f

    def _note_root(self, el: etree._Element) -> None:
        if self.version is None:
            ns = el.tag.split("}", 1)[0].lstrip("{") if "}" in el.tag else ""
            m = re.search(r"citygml/(\d\.\d)", ns)
            self.version = m.group(1) if m else None

    def objects(self, keep: Keep | None = None) -> Iterator[CityObject]:
        """The city objects with geometry (top-level members and their parts)."""
        seen_root = False
        tags = ("{*}CityModel", "{*}Envelope", *(f"{{*}}{m}" for m in MEMBERS))
        try:
            self._global_appearances()
            with self._open() as f:
                for event, el in etree.iterparse(
                    f, events=("start", "end"), tag=tags, huge_tree=True
                ):
                    name = _local(el)
                    if event == "start":
                        if name == "CityModel" and not seen_root:
                            seen_root = True
                            self._note_root(el)
                        continue
                    if name == "Envelope":
                        self.crs = self.crs or el.get("srsName")
                        continue
                    if name not in MEMBERS or not seen_root:
                        continue
                    parent = el.getparent()
                    if parent is None or _local(parent) != "CityModel":
                        continue
                    if self.crs is None:
                        found = el.find(".//*[@srsName]")
                        self.crs = None if found is None else found.get("srsName")
                    for child in el:
                        if isinstance(child.tag, str):
                            self._read_textures(child)  # the object's own appearances
                            yield from self._read(child, keep, None)
                    el.clear()
                    while el.getprevious() is not None:
                        del parent[0]
        except etree.XMLSyntaxError as exc:
            raise self._error(f"broken XML: {exc.msg}", line=exc.lineno) from exc
        except zipfile.BadZipFile as exc:
            raise self._error(f"broken zip archive: {exc}") from exc
        if not seen_root:
            raise self._error("no CityModel element (expected a CityGML file)")

    def _read(
        self,
        obj: etree._Element,
        keep: Keep | None,
        parent: str | None,
        inherited: dict | None = None,
    ) -> Iterator[CityObject]:
        """The object (if it has polygons of its own) and its parts, each with the attributes
        of the objects around it merged under its own."""
        oid = obj.get(GML_ID) or obj.get(GML32_ID)
        oid = oid or f"{_local(obj)}@{obj.sourceline}"
        parts = [el for el in obj.iter(*(f"{{*}}{n}" for n in PART_NAMES)) if el is not obj]
        inside_parts = {id(x) for p in parts for x in p.iter("{*}Polygon", "{*}Triangle")}
        polygons = []
        # a relief (dem:ReliefFeature) says its LoD in a `lod` element, not a property's name
        stated = next((c.text for c in obj if _local(c) == "lod" and c.text), None)
        default_lod = int(stated) if stated and stated.strip().isdigit() else 1
        for el in obj.iter("{*}Polygon", "{*}Triangle"):
            if id(el) in inside_parts:
                continue
            lod, kind = self._context(el, obj)
            lod = default_lod if lod is None else lod
            if lod <= self.max_lod:
                polygons.append((lod, kind, el))
        attributes = {**(inherited or {}), **_attributes(obj)}
        if polygons:
            self.count += 1
            yield from self._object(obj, oid, polygons, keep, parent, attributes)
        for part in parts:
            yield from self._read(part, keep, oid, attributes)

    @staticmethod
    def _context(polygon: etree._Element, obj: etree._Element) -> tuple[int | None, str | None]:
        """(LoD, semantic surface name) of a polygon, from the elements around it."""
        lod = kind = None
        el = polygon.getparent()
        while el is not None and el is not obj:
            name = _local(el)
            if lod is None:
                m = LOD_PATTERN.match(name)
                if m:
                    lod = int(m.group(1))
            if kind is None and name in SURFACE_KINDS:
                kind = name
            el = el.getparent()
        return lod, kind

    def _colour(
        self, polygon: etree._Element, obj: etree._Element
    ) -> tuple[float, float, float] | None:
        """The X3DMaterial colour targeting the polygon, or the nearest surface holding it."""
        return _targeted(polygon, obj, self.target_colours)

    def _object(
        self,
        obj: etree._Element,
        oid: str,
        polygons: list,
        keep: Keep | None,
        parent: str | None,
        attributes: dict,
    ) -> Iterator[CityObject]:
        top = max(lod for lod, _, _ in polygons)
        otype = _local(obj)
        surfaces = []
        for lod, name, polygon in polygons:
            if lod != top:
                continue
            rings, textures = [], []
            for ring in polygon.iter("{*}LinearRing"):
                try:
                    coords = _coordinates(ring)
                except ValueError as exc:
                    raise self._error(
                        str(exc), field=f"{oid} polygon", line=polygon.sourceline
                    ) from exc
                if not np.isfinite(coords).all():
                    raise self._error(
                        "coordinates that are not finite numbers",
                        field=f"{oid} polygon",
                        line=polygon.sourceline,
                    )
                rings.append(coords)
                textures.append(self.ring_textures.get(ring.get(GML_ID) or ring.get(GML32_ID)))
            if rings:
                surface = Surface(rings, kind_of(name, otype), colour=self._colour(polygon, obj))
                if all(
                    t is not None and len(t[1]) == len(r)
                    for t, r in zip(textures, rings, strict=True)
                ):
                    if len({t[0] for t in textures}) == 1:
                        surface.texture, surface.uvs = textures[0][0], [t[1] for t in textures]
                if surface.texture is None and (
                    georef := self._georeferenced_uvs(polygon, obj, rings)
                ):
                    surface.texture, surface.uvs = georef
                surfaces.append(surface)
        if not surfaces:
            return
        centre = footprint_centre(np.concatenate([r for s in surfaces for r in s.rings]))
        if keep is not None and not keep(centre):
            return
        yield CityObject(oid, otype, attributes, surfaces, centre, str(top), parent)


def _targets(surface_data: etree._Element) -> Iterator[str]:
    """The gml:ids a surface data element (a material, a texture) targets."""
    for target in surface_data.iter("{*}target"):
        uri = target.get("uri") or target.get(XLINK_HREF) or target.text
        if uri and uri.strip():
            yield uri.strip().lstrip("#")


def _targeted(polygon: etree._Element, obj: etree._Element, table: dict[str, T]) -> T | None:
    """The entry of `table` (by gml:id) for the polygon, or for the nearest surface around it
    within the object."""
    if not table:
        return None
    for el in (polygon, *polygon.iterancestors()):
        if el is obj:
            return None
        key = el.get(GML_ID) or el.get(GML32_ID)
        if key in table:
            return table[key]
    return None


WORLD_FILE_SUFFIXES = {
    ".png": ".pgw",
    ".jpg": ".jgw",
    ".jpeg": ".jgw",
    ".tif": ".tfw",
    ".tiff": ".tfw",
}


def _geotiff_georef(image: Path) -> tuple[np.ndarray, pyproj.CRS | None] | None:
    """(the 2 x 3 affine matrix (column, row, 1 -> x, y; pixel centres), its CRS or None) of a
    GeoTIFF's own georeference tags, None where it has none (or is no TIFF rasterio reads)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(image) as src:
                t, crs = src.transform, src.crs
    except RasterioError:
        return None
    if t.is_identity:
        return None
    x0, y0 = t @ (0.5, 0.5)  # the centre of the upper-left pixel
    affine = np.array([[t.a, t.b, x0], [t.d, t.e, y0]])
    return affine, None if crs is None else of_raster(crs)


def _same_crs(a: pyproj.CRS, b: pyproj.CRS) -> bool:
    """Whether two CRSs are one (by EPSG code where both have one: a GeoTIFF's WKT names its
    parts otherwise than a srsName's)."""
    codes = a.to_epsg(), b.to_epsg()
    if None not in codes:
        return codes[0] == codes[1]
    return a.equals(b, ignore_axis_order=True)


def _world_file(image: Path) -> np.ndarray | None:
    """The 2 x 3 affine matrix (column, row, 1 -> x, y; pixel centres) of the world file
    beside an image (its suffix's conventional one, `.<suffix>w`, or `.wld`), None without
    one or where it is not six numbers."""
    suffix = image.suffix.lower()
    names = [WORLD_FILE_SUFFIXES.get(suffix), suffix + "w", ".wld"]
    for name in filter(None, names):
        for candidate in (image.with_suffix(name), image.with_suffix(name.upper())):
            if not candidate.is_file():
                continue
            try:
                a, d, b, e, x0, y0 = (float(v) for v in candidate.read_text().split())
            except ValueError:
                return None
            return np.array([[a, b, x0], [d, e, y0]])
    return None


def _attributes(obj: etree._Element) -> dict:
    """Generic attributes, simple properties and the address of an object (not of its parts)."""
    out: dict[str, object] = {}
    for el in obj:
        name = _local(el)
        if name in GENERIC or name == "genericAttribute":
            generic = el if name in GENERIC else next((c for c in el if isinstance(c.tag, str)), el)
            key = generic.get("name") or next(
                (c.text for c in generic if _local(c) == "name"), None
            )
            value = next((c.text for c in generic if _local(c) == "value"), None)
            if key and value is not None:
                out[key] = _number(value)
        elif name == "address":
            texts = [t.strip() for t in el.itertext() if t.strip()]
            if texts:
                out["address"] = " ".join(texts)
        elif len(el) == 0 and el.text and el.text.strip() and name not in ("boundedBy",):
            out[name] = _number(el.text.strip())
    return out


def _number(text: str) -> object:
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text
