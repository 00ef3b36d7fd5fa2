"""A city model file as a scene layer: read around the clip's track, placed in the session's ENU
frame, coloured by surface kind, with the table that names what each triangle is.

1. The reader (CityJSON document or Sequence, CityGML, zipped or not; building footprints
   from OpenStreetMap or GeoParquet, extruded to LoD1 on the ground `ground` gives:
   app.scene.city.footprints) yields one object at a time; an object is read only if its
   horizontal centre lies within `margin_m` of the track (the track is taken into the file's
   CRS once), so a district of 100,000 buildings opens in the memory of the part around the
   clip.
2. Memory is bounded whatever the file: at most `max_triangles` triangles are kept, the objects
   nearest the track first (farther ones are dropped as nearer ones come, and that is said).
3. Heights: the file's vertical datum from its compound CRS (EGM2008, EGM96 or a 3D geographic
   CRS's ellipsoid are converted exactly, app.geodesy.geoid); a vertical datum geofuse has no
   model of (NAP, DHHN2016, NAVD88...) and a CRS without a vertical part are taken as above the
   EGM2008 geoid, and said; `vertical` overrides both, as the DEM's option does.
4. Placement: CRS (x, y) -> WGS84 lat, lon (pyproj) and height -> ellipsoidal -> ECEF -> ENU,
   per vertex, so buildings land where GNSS positions do, curvature included.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyproj
from PIL import Image, UnidentifiedImageError
from scipy.spatial import cKDTree

from app.core.errors import SceneError
from app.core.messages import Messages
from app.geodesy import geoid
from app.geodesy.crs import horizontal, parse_crs, vertical_datum, vertical_name, vertical_part
from app.geodesy.enu import LocalFrame
from app.scene.city.citygml import SUFFIXES as GML_SUFFIXES
from app.scene.city.citygml import CityGmlReader
from app.scene.city.cityjson import CityJsonReader
from app.scene.city.footprints import FootprintReader, Ground, flat_ground
from app.scene.city.model import (
    KIND_CODE,
    KIND_COLORS,
    CityObject,
    FeatureTable,
    triangle_indices,
    usable_rings,
)
from app.scene.city.osm import OsmReader, is_osm
from app.scene.city.overture import ParquetReader, is_parquet
from app.scene.city.paths import outside_note
from app.scene.mesh import MeshData, Primitive

DEFAULT_MARGIN_M = 1000.0  # objects this far from the track are read
DEFAULT_MAX_TRIANGLES = 1_500_000  # ~150 MB drawn and indexed at most
FLUSH_TRIANGLES = 50_000  # triangles placed in ENU in batches of this many
MAX_TEXTURE_PX = 8192  # a texture image is drawn at most this many pixels a side


def is_footprints(location: str | Path) -> bool:
    """Building footprints to extrude: OpenStreetMap (.osm, .osm.pbf) or GeoParquet (.parquet)."""
    return is_osm(location) or is_parquet(location)


def is_city(location: str | Path) -> bool:
    """A CityJSON (.city.json, .city.jsonl or any .json whose start says CityJSON) or CityGML
    (.gml, .xml, .zip) file, or building footprints (is_footprints)."""
    path = Path(str(location))
    name = path.name.lower()
    if is_footprints(path) or (
        name.endswith((".city.json", ".city.jsonl", ".jsonl"))
        or path.suffix.lower() in GML_SUFFIXES
    ):
        return True
    if path.suffix.lower() == ".json" and path.is_file():
        with path.open("rb") as f:
            return b'"CityJSON"' in f.read(4096)
    return False


@dataclass
class City:
    """A city layer read: the mesh (a primitive coloured by kind and one per texture image, and
    its FeatureTable), the datum its heights were taken above, what was said, and counts."""

    mesh: MeshData
    datum: str
    notes: Messages
    objects_read: int
    objects_in_file: int
    triangles: int
    bytes: int
    crs_name: str


class _Window:
    """Which object centres (file CRS) lie within margin_m of the track."""

    def __init__(self, crs: pyproj.CRS, track_ll: np.ndarray, margin_m: float) -> None:
        h = horizontal(crs)
        x, y = pyproj.Transformer.from_crs("EPSG:4326", h, always_xy=True).transform(
            track_ll[:, 1], track_ll[:, 0]
        )
        if h.is_geographic:  # degrees: scale longitude by cos(latitude) and use metres
            lat0 = float(np.radians(np.mean(track_ll[:, 0])))
            self.scale = np.array([111_320.0 * np.cos(lat0), 110_574.0])
        else:
            self.scale = np.full(2, h.axis_info[0].unit_conversion_factor)
        pts = np.stack([x, y], axis=1) * self.scale
        if not np.isfinite(pts).all():
            raise ValueError("the track lies outside the file's CRS")
        self.tree = cKDTree(pts)
        self.lo = (pts.min(axis=0) - margin_m).tolist()
        self.hi = (pts.max(axis=0) + margin_m).tolist()

    def distance(self, centre: np.ndarray) -> float:
        """Horizontal distance (m) from the track; inf beyond its box plus the margin."""
        x, y = float(centre[0] * self.scale[0]), float(centre[1] * self.scale[1])
        if not (self.lo[0] <= x <= self.hi[0] and self.lo[1] <= y <= self.hi[1]):
            return np.inf
        return float(self.tree.query((x, y))[0])


@dataclass
class _Kept:
    """One object read: its triangles in ENU (T, 3, 3 float32), kind codes (T,), texture
    indices (T,; -1 untextured), texture coordinates (T, 3, 2) and colours (T, 3 uint8: the
    material's, else the kind's)."""

    obj: CityObject
    triangles: np.ndarray
    kinds: np.ndarray
    textures: np.ndarray
    uvs: np.ndarray
    colours: np.ndarray
    distance: float


def _triangles(obj: CityObject) -> tuple[list, list, list, list, list]:
    """(triangles, kinds, textures, uvs, colours) of an object's surfaces, as lists of arrays."""
    tris, kinds, textures, uvs, colours = [], [], [], [], []
    for s in obj.surfaces:
        idx = triangle_indices(s)
        if not len(idx):
            continue
        used = usable_rings(s)
        tris.append(np.concatenate([s.rings[i] for i in used])[idx])
        kinds.append(np.full(len(idx), KIND_CODE[s.kind], np.uint8))
        rgb = KIND_COLORS[KIND_CODE[s.kind]] if s.colour is None else np.asarray(s.colour)
        colours.append(np.tile(np.round(255 * np.clip(rgb, 0, 1)).astype(np.uint8), (len(idx), 1)))
        if s.texture is not None and s.uvs is not None:
            textures.append(np.full(len(idx), s.texture, np.int32))
            uvs.append(np.concatenate([s.uvs[i] for i in used])[idx].astype(np.float32))
        else:
            textures.append(np.full(len(idx), -1, np.int32))
            uvs.append(np.zeros((len(idx), 3, 2), np.float32))
    return tris, kinds, textures, uvs, colours


def _datum(path: Path, crs: pyproj.CRS, vertical: str | None, notes: Messages) -> tuple[str, float]:
    """(datum, metres per vertical unit) of the file's heights, with what was assumed said."""
    part = vertical_part(crs)
    unit = part.axis_info[0].unit_conversion_factor if part is not None else 1.0
    if vertical is not None:
        if vertical not in geoid.VERTICAL_DATUMS:
            raise SceneError(
                path,
                f"vertical datum {vertical!r} unknown (expected one of {', '.join(geoid.VERTICAL_DATUMS)})",
                field="vertical",
            )
        return vertical, unit
    datum = vertical_datum(crs)
    if datum is not None:
        return datum, unit
    name = vertical_name(crs)
    if name is None:
        notes.add(
            f"{path.name}: heights taken as above sea level (EGM2008): the CRS names no vertical datum; set the layer's vertical datum to change it"
        )
    else:
        notes.add(
            f"{path.name}: {name}s taken as above the EGM2008 geoid (geofuse has no model of that datum: expect an error of up to a metre); set the layer's vertical datum to change it"
        )
    return "egm2008", unit


class _Placer:
    """File CRS coordinates -> session ENU (float64)."""

    def __init__(self, crs: pyproj.CRS, datum: str, unit: float, frame: LocalFrame) -> None:
        self.to_ll = pyproj.Transformer.from_crs(horizontal(crs), "EPSG:4326", always_xy=True)
        self.datum, self.unit, self.frame = datum, unit, frame

    def __call__(self, p: np.ndarray) -> np.ndarray:
        lon, lat = self.to_ll.transform(p[:, 0], p[:, 1])
        lat, lon = np.asarray(lat), np.asarray(lon)
        h = geoid.to_ellipsoidal(p[:, 2] * self.unit, lat, lon, self.datum)
        return self.frame.geodetic_to_enu(lat, lon, h)


def read_city(
    path: str | Path,
    frame: LocalFrame,
    track_ll: npt.ArrayLike | None = None,
    vertical: str | None = None,
    margin_m: float = DEFAULT_MARGIN_M,
    max_triangles: int = DEFAULT_MAX_TRIANGLES,
    max_lod: float = 9.0,
    theme: str | None = None,
    ground: Ground | None = None,
) -> City:
    """The city model at `path` in `frame` (see the module docstring). track_ll: (N, 2) lat,
    lon (deg) of the clip's track, None to read every object (up to max_triangles); ground:
    what footprints stand on (None: the plane of the frame's origin; their heights are their
    own, `vertical` does not apply). Raises SceneError naming the file, and the object or line
    at fault."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(path, "city model file does not exist")
    notes = Messages()
    gml = path.suffix.lower() in GML_SUFFIXES
    if is_footprints(path):
        ground = ground or flat_ground(frame, 0.0, frame.h_m, "the plane of the frame's origin")
        reader = (OsmReader if is_osm(path) else ParquetReader)(path, ground)
        vertical = theme = None
    else:
        reader = (CityGmlReader if gml else CityJsonReader)(path, max_lod, theme)
    track = None if track_ll is None else np.atleast_2d(np.asarray(track_ll, np.float64))
    state: dict[str, object] = {}

    def setup() -> tuple[_Window | None, _Placer]:
        if "placer" not in state:
            is_json = isinstance(reader, CityJsonReader)
            text = reader.header.crs if is_json else reader.crs
            field = "metadata.referenceSystem" if is_json else "srsName"
            if not text:
                raise SceneError(path, "the file names no CRS (expected one)", field=field)
            try:
                crs = parse_crs(str(text))
                window = None if track is None or not len(track) else _Window(crs, track, margin_m)
            except ValueError as exc:
                raise SceneError(path, str(exc), field=field) from exc
            datum, unit = _datum(path, crs, vertical, notes)
            state.update(
                crs=crs, datum=datum, window=window, placer=_Placer(crs, datum, unit, frame)
            )
        return state["window"], state["placer"]  # type: ignore[return-value]

    def keep(centre: np.ndarray) -> bool:
        window, _ = setup()
        return window is None or window.distance(centre) <= margin_m

    kept: list[_Kept] = []
    pending: list[tuple[CityObject, list, list, list, list]] = []
    pending_triangles = 0
    total = 0
    dropped = 0

    def trim() -> None:
        """Drop the objects farthest from the track until at most max_triangles are kept."""
        nonlocal total, dropped
        kept.sort(key=lambda k: k.distance)
        while total > max_triangles and kept:
            total -= len(kept.pop().triangles)
            dropped += 1

    def flush() -> None:
        nonlocal pending_triangles, total
        if not pending:
            return
        window, placer = setup()
        flat = np.concatenate([t for _, tris, *_ in pending for t in tris]).reshape(-1, 3)
        enu = placer(flat).astype(np.float32).reshape(-1, 3, 3)
        start = 0
        for obj, tris, kinds, textures, uvs, colours in pending:
            n = sum(len(t) for t in tris)
            distance = 0.0 if window is None else window.distance(obj.centre)
            kept.append(
                _Kept(
                    obj,
                    enu[start : start + n],
                    np.concatenate(kinds),
                    np.concatenate(textures),
                    np.concatenate(uvs),
                    np.concatenate(colours),
                    distance,
                )
            )
            start += n
            total += n
        pending.clear()
        pending_triangles = 0
        if total > max_triangles * 1.25:  # trimmed now and then, not after every object
            trim()

    for obj in reader.objects(keep):
        tris, kinds, textures, uvs, colours = _triangles(obj)
        if not tris:
            continue
        pending.append((obj, tris, kinds, textures, uvs, colours))
        pending_triangles += sum(len(t) for t in tris)
        if pending_triangles >= FLUSH_TRIANGLES:
            flush()
    flush()
    if total > max_triangles:
        trim()
    if reader.count == 0:
        raise SceneError(
            path, "the city holds no object with surfaces to draw (expected buildings, terrain...)"
        )
    if not kept:
        raise SceneError(
            path,
            f"none of its {reader.count} objects lies within {margin_m:.0f} m of the clip's track: check the file's CRS and the track",
        )
    if theme is not None and theme not in reader.themes:
        raise SceneError(
            path,
            f"no appearance theme {theme!r} among the objects read (theirs: "
            f"{', '.join(repr(n) for n in sorted(reader.themes)) or 'none'})",
            field="theme",
        )
    for note in reader.notes:
        notes.add(note)
    if isinstance(reader, FootprintReader):
        for note in reader.infos:
            notes.info(note)
    return _city(
        path, reader, kept, dropped, state, notes, track is not None, margin_m, max_triangles
    )


def _primitive(
    triangles: np.ndarray,
    colours: np.ndarray | None,
    uvs: np.ndarray | None,
    image: np.ndarray | None,
    name: str,
) -> Primitive:
    """Triangles (T, 3, 3) as a primitive: coloured (T, 3 uint8), or white under a texture."""
    positions = np.ascontiguousarray(triangles.reshape(-1, 3))
    n = len(positions)
    colors = np.ones((n, 4), np.float32)
    if colours is not None:
        colors[:, :3] = np.repeat(colours.astype(np.float32) / 255.0, 3, axis=0)
    return Primitive(
        positions=positions,
        colors=colors,
        indices=np.arange(n, dtype=np.uint32).reshape(-1, 3),
        uvs=None if uvs is None else np.ascontiguousarray(uvs.reshape(-1, 2)),
        texture=image,
        name=name,
    )


def _themes_said(reader: CityJsonReader | CityGmlReader | FootprintReader) -> str:
    """The appearance themes the objects read name, and the one drawn, for the layer's note
    (empty where there are fewer than two)."""
    names = sorted(reader.themes)
    if len(names) < 2:
        return ""
    if reader.theme is not None:
        drawn = repr(reader.theme)
    elif isinstance(reader, CityJsonReader) and reader.default_texture_theme_read:
        drawn = f"{reader.default_texture_theme_read!r}, the file's default"
    else:
        drawn = "each object's first by name"
    return f"; appearance themes {', '.join(repr(n) for n in names)}, drawn: {drawn}"


def _images(
    reader: CityJsonReader | CityGmlReader | FootprintReader, used: set[int], notes: Messages
) -> dict[int, np.ndarray]:
    """The texture images used, as RGBA bottom row first (app.scene.mesh), at most
    MAX_TEXTURE_PX a side; one that is missing, unreadable or outside the model's folder (not
    read: app.scene.city.paths) is said and its surfaces are drawn by kind."""
    out = {}
    files = reader.texture_files()
    for t in sorted(used):
        file = files[t]
        if file is None:
            notes.add(outside_note(reader.path, reader.texture_uris[t]))
            continue
        try:
            with Image.open(file) as img:
                img = img.convert("RGBA")
                if max(img.size) > MAX_TEXTURE_PX:
                    img.thumbnail((MAX_TEXTURE_PX, MAX_TEXTURE_PX))
                out[t] = np.ascontiguousarray(np.asarray(img, np.uint8)[::-1])
        except (OSError, UnidentifiedImageError) as exc:
            notes.add(f"{file}: texture not drawn ({exc}); its surfaces are drawn by kind")
    return out


def _city(
    path: Path,
    reader: CityJsonReader | CityGmlReader | FootprintReader,
    kept: list[_Kept],
    dropped: int,
    state: dict,
    notes: Messages,
    windowed: bool,
    margin_m: float,
    max_triangles: int,
) -> City:
    """The kept objects as primitives (one coloured by material or kind, one per texture image) and their
    feature table, with the layer's note."""
    parents = {k.obj.parent for k in kept if k.obj.parent is not None}
    inherited = reader.attributes_of(parents) if isinstance(reader, CityJsonReader) else {}
    triangles = np.concatenate([k.triangles for k in kept])
    kinds = np.concatenate([k.kinds for k in kept])
    textures = np.concatenate([k.textures for k in kept])
    uvs = np.concatenate([k.uvs for k in kept])
    colours = np.concatenate([k.colours for k in kept])
    used = set(np.unique(textures[textures >= 0]).tolist())
    images = _images(reader, used, notes)
    textures = np.where(np.isin(textures, list(images)), textures, -1)
    prims = [
        _primitive(
            triangles[textures == t], None, uvs[textures == t], image, f"{path.name} texture {t}"
        )
        for t, image in images.items()
    ]
    plain = textures < 0
    if plain.any():
        prims.append(_primitive(triangles[plain], colours[plain], None, None, path.name))
    starts = np.concatenate([[0], np.cumsum([len(k.triangles) for k in kept])]).astype(np.int64)
    table = FeatureTable(
        path.name,
        [k.obj.id for k in kept],
        [k.obj.type for k in kept],
        [{**inherited.get(k.obj.parent or "", {}), **k.obj.attributes} for k in kept],
        [k.obj.parent for k in kept],
        triangles,
        starts,
        kinds,
    )
    size = (
        sum(p.positions.nbytes + p.colors.nbytes + p.indices.nbytes for p in prims)
        + sum(p.texture.nbytes + p.uvs.nbytes for p in prims if p.textured)
        + triangles.nbytes
        + kinds.nbytes
        + table.boxes.nbytes
        + starts.nbytes
    )
    crs = state["crs"]
    lods = sorted({k.obj.lod for k in kept if k.obj.lod})
    where = f" within {margin_m:.0f} m of the track" if windowed else ""
    if isinstance(reader, CityJsonReader):
        kind, version = "CityJSON", reader.header.version or "?"
    else:
        kind = "CityGML" if isinstance(reader, CityGmlReader) else reader.format
        version = reader.version or ("" if isinstance(reader, FootprintReader) else "?")
    notes.info(
        f"{path.name}: {f'{kind} {version}'.strip()} in {crs.name}, {len(kept):,} of {reader.count:,} objects{where} "
        f"(LoD {', '.join(lods)}), {len(triangles):,} triangles, {size / 1e6:.1f} MB, heights above {state['datum']}"
        + _themes_said(reader)
    )
    if dropped:
        notes.add(
            f"{path.name}: {dropped:,} objects farther from the track left out to keep within {max_triangles:,} triangles"
        )
    return City(
        MeshData(prims, features=[table]),
        str(state["datum"]),
        notes,
        len(kept),
        reader.count,
        len(triangles),
        size,
        crs.name,
    )
