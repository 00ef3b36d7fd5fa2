"""A session's scene as layers: model files, 3D Tiles tilesets (folders or URLs), DEM terrain
with its orthophoto, city models; all placed in one ENU frame into one MeshData.

The kind of a layer comes from its name: a CityJSON file (`.city.json`, `.city.jsonl`, or a
`.json` that says CityJSON), CityGML (`.gml`, `.xml`, `.zip`) or building footprints
(OpenStreetMap `.osm`, `.osm.pbf`, GeoParquet `.parquet`) is a city, any other `.json` or
an http(s) URL a tileset, `.tif`/`.tiff` a DEM, `.glb`/`.gltf`/`.obj`/`.ply` a model. Tilesets,
DEMs and cities are georeferenced by themselves; models by their placement (app.scene.loader).

Footprints are extruded after every other layer is loaded, each building standing on the
other layers' ground under it; with no other layer, on an assumed flat ground (the clip's), which
is drawn under them. Where a DEM is draped with imagery, their roofs show it too
(app.scene.city.drape).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.core.errors import SceneError
from app.core.messages import Messages
from app.geodesy.enu import LocalFrame
from app.scene.city.drape import draped_roofs
from app.scene.city.footprints import flat_ground, terrain_ground
from app.scene.city.read import is_city, is_footprints, read_city
from app.scene.ground_plane import ASSUMED_GROUND_MARGIN_M, ground_plane
from app.scene.loader import SUPPORTED_SUFFIXES, Placement, load_scene
from app.scene.mesh import MeshData
from app.scene.terrain import DEFAULT_MAX_ERROR_M, DEM_SUFFIXES, read_terrain
from app.scene.tiles import fetch
from app.scene.tiles.tileset import Tileset, TilesetError

KINDS = ("mesh", "tileset", "dem", "city", "world")
SCENE_FAR_M = 500.0  # a scene farther than this from the camera is misplaced, or the camera is


def layer_kind(location: str | Path) -> str:
    """'city', 'tileset', 'dem' or 'mesh' from a layer's name (and a .json's first bytes);
    raises SceneError for anything else."""
    text = str(location)
    suffix = Path(text.split("?")[0]).suffix.lower()
    if not fetch.is_url(text) and is_city(text):
        return "city"
    if fetch.is_url(text) or suffix == ".json":
        return "tileset"
    if suffix in DEM_SUFFIXES:
        return "dem"
    if suffix in SUPPORTED_SUFFIXES:
        return "mesh"
    raise SceneError(
        text,
        f"unknown scene layer {suffix or 'without a suffix'!r} (expected a 3D Tiles tileset.json or URL, a DEM .tif, a CityJSON or CityGML city model, OpenStreetMap (.osm, .osm.pbf) or GeoParquet buildings, or {', '.join(SUPPORTED_SUFFIXES)})",
    )


@dataclass(frozen=True)
class Layer:
    """One layer. location: a file path or URL; placement: a model's (app.scene.loader); ortho,
    max_error_m: a DEM's orthophoto and largest vertical error of its mesh, m; vertical: a DEM's
    or a city's vertical datum (None: the file's, else EGM2008); lod: a city's highest level of
    detail read (None: each object's highest); theme: a city's appearance theme drawn (None:
    the first the file names); world: a world's tile sources (app.world.settings.World, kind
    "world": resolved over a clip's track into a DEM layer by app.world.build); attribution:
    what its imagery or heights must be credited with (shown in the viewer's Session panel);
    fetched: what a layer fetched for the clip came from (app.world.overpass), whose buildings
    the scene opens without, saying why, where none can be drawn ('': a file the user named)."""

    location: str
    kind: str
    placement: Placement = Placement()
    ortho: Path | None = None
    vertical: str | None = None
    max_error_m: float = DEFAULT_MAX_ERROR_M
    lod: float | None = None
    theme: str | None = None
    world: object | None = None
    attribution: str = ""
    fetched: str = ""

    @classmethod
    def of(cls, location: str | Path, **options) -> Layer:
        return cls(str(location), layer_kind(location), **options)

    @property
    def name(self) -> str:
        """The file's name; a tileset.json with its folder (most tilesets are called that); a
        URL whole."""
        return fetch.display_name(self.location)

    @property
    def georeferenced(self) -> bool:
        """Placed by its own coordinates (a tileset, a DEM, a city), not by a manifest's origin."""
        return self.kind != "mesh"

    def files(self) -> list[Path]:
        """Local files this layer reads (never to be written)."""
        if self.kind == "world":
            return []
        out = [] if fetch.is_url(self.location) else [Path(self.location)]
        return out + ([self.ortho] if self.ortho is not None else [])


def scene_credit(layers: Iterable[Layer]) -> str:
    """What a scene of `layers` must be credited with, as its providers' licences require:
    their attributions, each part (between ';') once, in order; '' where none has one. The
    viewer shows it over the 3D view; exports that carry the imagery write it (app.export)."""
    parts = (p.strip() for layer in layers for p in layer.attribution.split(";"))
    return "; ".join(dict.fromkeys(p for p in parts if p))


def named_layers(
    names: list[str],
    ortho: Path | None = None,
    vertical: str | None = None,
    max_error_m: float = DEFAULT_MAX_ERROR_M,
    placement: Placement | None = None,
    theme: str | None = None,
) -> tuple[Layer, ...]:
    """The layers a user named (files or URLs), checked before anything loads: local files
    exist, kinds are known; a DEM takes the orthophoto, vertical datum and largest error (m)
    given, a city the vertical datum and appearance theme, a model the placement. Raises
    SceneError naming the file
    at fault."""
    out = []
    for name in names:
        if not fetch.is_url(name) and not Path(name).exists():
            raise SceneError(name, "scene file does not exist")
        layer = Layer.of(name)
        if layer.kind == "dem":
            layer = Layer.of(name, ortho=ortho, vertical=vertical, max_error_m=max_error_m)
        elif layer.kind == "city":
            layer = Layer.of(name, vertical=vertical, theme=theme)
        elif layer.kind in ("mesh", "tileset") and placement is not None:
            layer = Layer.of(name, placement=placement)
        out.append(layer)
    if ortho is not None:
        if not any(layer.kind == "dem" for layer in out):
            raise SceneError(
                str(ortho),
                "an orthophoto drapes a DEM: give --dem DEM.tif (or --scene DEM.tif) too",
            )
        if not ortho.is_file():
            raise SceneError(str(ortho), "orthophoto file does not exist")
    return tuple(out)


@dataclass
class LoadedLayers:
    """Every layer in one MeshData, each layer's own (for per-layer checks), and what was said."""

    mesh: MeshData
    parts: list[tuple[Layer, MeshData]] = field(default_factory=list)
    notes: Messages = field(default_factory=Messages)

    def warn_far(self, points_enu: npt.ArrayLike, what: str) -> None:
        """A warning in `notes` for each layer farther than SCENE_FAR_M (horizontally) from every
        one of the points (N, 3) ENU m (`what` names them: the camera's track, the camera)."""
        for layer, part in self.parts:
            far = part.horizontal_distance(points_enu)
            if far > SCENE_FAR_M:
                hint = (
                    "its georeferencing (or --origin for one that has none)"
                    if layer.georeferenced
                    else "the model's origin and up axis"
                )
                self.notes.add(
                    f"{layer.name}: the scene lies {far / 1000:.1f} km from {what}: check {hint} and the camera's position"
                )


def _tileset(layer: Layer, frame: LocalFrame) -> Tileset:
    try:
        p = layer.placement
        return Tileset(layer.location, frame, p.origin, p.heading_deg, p.scale)
    except fetch.FetchError as exc:
        raise SceneError(exc.location, str(exc).split(": ", 1)[-1]) from exc
    except TilesetError as exc:
        raise SceneError(exc.location, exc.detail, field=exc.field) from exc


def _is_footprints(layer: Layer) -> bool:
    return layer.kind == "city" and is_footprints(layer.location)


def load_layers(
    layers: list[Layer] | tuple[Layer, ...],
    frame: LocalFrame,
    track_ll: npt.ArrayLike | None = None,
    ground_h: float | None = None,
    margin_m: float = ASSUMED_GROUND_MARGIN_M,
) -> LoadedLayers:
    """Every layer in `frame`, in one MeshData. track_ll: (N, 2) lat, lon (deg) of the clip's
    track: DEMs and city models are read around it. ground_h: the clip's assumed ground
    (ellipsoidal m; None: the frame origin's height), where building footprints stand when no
    other layer has ground under them, drawn margin_m (m) beyond the track and them when no
    other layer is given (load_footprints). Raises SceneError naming the file at fault."""
    out = LoadedLayers(MeshData())
    notes = out.notes
    for layer in layers:
        if _is_footprints(layer):
            continue  # after the others: they stand on them
        if layer.kind == "mesh":
            part = load_scene(layer.location, frame, layer.placement)
        elif layer.kind == "tileset":
            ts = _tileset(layer, frame)
            part = MeshData(tilesets=[ts])
            notes.info(f"{layer.name}: 3D Tiles {ts.version}, streamed by level of detail")
        elif layer.kind == "world":
            raise SceneError(
                layer.location,
                "a world is built around a clip's track: open a clip with it (a still's scene is --scene/--dem)",
            )
        elif layer.kind == "city":
            lod = {} if layer.lod is None else {"max_lod": layer.lod}
            city = read_city(
                layer.location, frame, track_ll, layer.vertical, theme=layer.theme, **lod
            )
            part = city.mesh
            notes.extend(city.notes)
        else:
            terrain = read_terrain(
                layer.location, frame, track_ll, layer.ortho, layer.vertical, layer.max_error_m
            )
            part = terrain.mesh
            notes.extend(terrain.notes)
            notes.info(
                f"{layer.name}: terrain of {terrain.mesh.triangle_count} triangles from {terrain.grid_shape[0]}x{terrain.grid_shape[1]} samples "
                f"(~{terrain.cell_m:.1f} m apart), within {terrain.error_m:.2f} m of them, heights from {terrain.datum}"
                + (f", draped with {layer.ortho.name}" if layer.ortho is not None else "")
            )
        out.parts.append((layer, part))
    models = [part for layer, part in out.parts if layer.kind == "mesh"]
    for i, (layer, part) in enumerate(out.parts):
        if layer.kind == "dem" and models:
            part, lowered = under_models(part, models)
            out.parts[i] = (layer, part)
            if lowered:
                notes.info(
                    f"{layer.name}: {lowered} terrain vertices under the models lowered below their ground, which is drawn there"
                )
    footprints = [layer for layer in layers if _is_footprints(layer)]
    if footprints:
        load_footprints(out, footprints, frame, track_ll, ground_h, margin_m)
    for _, part in out.parts:
        out.mesh = out.mesh.merged(part)
    return out


def load_footprints(
    out: LoadedLayers,
    layers: list[Layer],
    frame: LocalFrame,
    track_ll: npt.ArrayLike | None,
    ground_h: float | None,
    margin_m: float,
) -> None:
    """Building footprint layers extruded into `out` (app.scene.city.footprints), on the
    ground of the layers already in it; with none, on the flat ground at ground_h (ellipsoidal
    m; None: the frame origin's height), which is then drawn beneath them and the track, margin_m
    (m) beyond both."""
    assumed = frame.h_m if ground_h is None else float(ground_h)
    track = None if track_ll is None else np.atleast_2d(np.asarray(track_ll, np.float64))
    at = (frame.lat_deg, frame.lon_deg) if track is None or not len(track) else track[0]
    z = float(frame.geodetic_to_enu(at[0], at[1], assumed)[2])  # the flat ground's ENU height
    terrain = MeshData()
    for _, part in out.parts:
        terrain = terrain.merged(part)
    if terrain.primitives or terrain.tilesets:
        names = ", ".join(layer.name for layer, _ in out.parts)
        ground = terrain_ground(terrain, frame, f"the ground of {names}", assumed)
    else:
        ground = flat_ground(
            frame,
            z,
            assumed,
            f"an assumed flat ground at {assumed:.2f} m (ellipsoidal), drawn under them",
        )
    first = len(out.parts)
    # the terrain draped with an orthophoto (a DEM's, a world's): the roofs show it too
    dems = [(dem, part) for dem, part in out.parts if dem.kind == "dem"]
    imagery = [p for _, part in dems for p in part.primitives]
    under = ", ".join(dem.name for dem, _ in dems)
    for layer in layers:
        try:
            city = read_city(layer.location, frame, track, ground=ground)
        except SceneError as exc:
            if not layer.fetched:
                raise
            out.notes.add(f"{layer.fetched}: the scene opens without them: {exc.detail}")
            continue
        out.notes.extend(city.notes)
        mesh, draped = draped_roofs(city.mesh, imagery)
        if draped:
            out.notes.info(
                f"{layer.name}: roofs ({draped} triangles) draped with the imagery of {under} under them"
            )
        out.parts.append((layer, mesh))
    if terrain.primitives or terrain.tilesets:
        return
    corners = [part.bounds()[:, :2] for _, part in out.parts[first:]]
    if track is not None and len(track):
        corners.append(
            frame.geodetic_to_enu(track[:, 0], track[:, 1], np.full(len(track), assumed))[:, :2]
        )
    if not corners:
        return
    xy = np.concatenate(corners)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    plane = ground_plane((lo + hi) / 2, z, float(max(hi - lo) / 2 + margin_m))
    if len(out.parts) == first:  # every layer was a fetched one left out: the ground alone
        out.parts.append((layers[0], plane))
        return
    layer, part = out.parts[first]
    out.parts[first] = (layer, part.merged(plane))


MODEL_GROUND_CLEARANCE_M = (
    0.3  # terrain under a model is kept this far below the model's lowest point
)


def under_models(terrain: MeshData, models: list[MeshData]) -> tuple[MeshData, int]:
    """The terrain with its vertices inside each model's horizontal extent kept
    MODEL_GROUND_CLEARANCE_M below that model's lowest point (ENU m), so that a model's own
    ground wins the depth test where both are drawn (no striping where a DEM and a site model's
    ground nearly coincide); terrain already lower is left. Returns (terrain, vertices moved)."""
    moved = 0
    prims = []
    for prim in terrain.primitives:
        p = prim.positions.astype(np.float64)
        for model in models:
            if not model.primitives:
                continue
            (x0, y0, z0), (x1, y1, _) = model.bounds()
            inside = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
            floor = z0 - MODEL_GROUND_CLEARANCE_M
            lower = inside & (p[:, 2] > floor)
            p[lower, 2] = floor
            moved += int(lower.sum())
        prims.append(replace(prim, positions=p.astype(np.float32)))
    return MeshData(prims, list(terrain.tilesets)), moved
