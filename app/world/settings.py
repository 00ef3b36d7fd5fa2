"""The user's world sources: `[[world]]` tables in the settings file (settings.toml in the
platform's config folder, app.core.paths.config_dir), chosen by `--world NAME`, or given once by
`--imagery SRC` / `--terrain SRC` / `--buildings overpass:[URL]`.

    [[world]]
    name = "maptiler"                      # what --world names
    imagery = "https://api.maptiler.com/tiles/satellite-v2/{z}/{x}/{y}.jpg?key={key}"
    terrain = "terrain-rgb:https://api.maptiler.com/tiles/terrain-rgb-v2/{z}/{x}/{y}.webp?key={key}"
    # also: a WMTS capabilities URL (#layer=NAME), an .mbtiles/.pmtiles/.gpkg archive, a
    # GeoTIFF/COG URL or file (terrain: a DEM, no encoding), a quantized-mesh layer.json URL
    # (terrain, heights above the ellipsoid), or a provider's name: imagery = "MapTiler.Satellite"
    # (its template, levels and attribution from the catalogue: app.world.providers)
    attribution = "(c) MapTiler (c) OpenStreetMap contributors"
    buildings = "overpass:"                # optional: OpenStreetMap buildings (app.world.overpass)
    datum = "egm2008"                      # the terrain's heights (default EGM2008, said)
    key_env = "MAPTILER_KEY"               # the environment variable holding {key}
    headers = { Referer = "https://example.org" }   # optional; values may hold {key} too
    imagery_max_zoom = 19                  # optional
    terrain_max_zoom = 15                  # optional
    timeout_s = 60                         # optional: the most a fetch may take, s
    reach_m = 800                          # optional: fetched this far beyond the track, m
                                           # (default: as far as the camera sees the ground,
                                           # app.scene.ground_plane.ground_reach_m)

With no `--world`, a clip without a scene takes the first table (or the name in the environment
variable GEOFUSE_WORLD; "none" there keeps the flat ground, as the tests set it); with no table
either, the default open sources where the network answers (app.world.defaults).
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

from app.core.errors import GeofuseError
from app.core.paths import config_dir
from app.world import defaults
from app.world.overpass import OverpassSource, parse_overpass
from app.world.sources import ENCODINGS, SourceError, TileSource, parse_source

NONE = "none"
ENV_WORLD = "GEOFUSE_WORLD"
DEFAULT_TIMEOUT_S = 60.0
KEYS = {
    "name",
    "imagery",
    "terrain",
    "buildings",
    "attribution",
    "datum",
    "key_env",
    "key",
    "headers",
    "imagery_max_zoom",
    "terrain_max_zoom",
    "timeout_s",
    "reach_m",
}
HOW_TO = (
    "to drape the clip on terrain and imagery instead, name tile sources in a [[world]] table of "
    "{path} (name, imagery, terrain, attribution) and pass --world NAME, or give --imagery SRC "
    "and --terrain SRC once (a URL template, a file, or a provider's name: `geofuse cache "
    "--providers` lists them)"
)


@dataclass(frozen=True)
class World:
    """A named world: imagery and/or terrain sources, what they must be credited with, the
    longest a fetch may take (s), and where its buildings are fetched from (None: nowhere);
    probe_s: the default world's (app.world.defaults): the network is asked first whether it
    answers within this long (s), the flat ground kept where it does not (0: no probe);
    reach_m: how far beyond a clip's track it is fetched (m on the ground; None: the camera's
    reach, as the clip's assumed ground has it)."""

    name: str
    imagery: TileSource | None
    terrain: TileSource | None
    attribution: str = ""
    timeout_s: float = DEFAULT_TIMEOUT_S
    buildings: OverpassSource | None = None
    probe_s: float = 0.0
    reach_m: float | None = None

    def reach(self, camera_m: float) -> float:
        """How far beyond a track this world is fetched (m on the ground): its reach_m where
        given, else camera_m, the camera's reach there."""
        return camera_m if self.reach_m is None else self.reach_m

    @property
    def credit(self) -> str:
        """What the world must be credited with wherever it is shown or written: its
        attribution, else each of its sources' (a provider's from the catalogue), once each."""
        if self.attribution:
            return self.attribution
        sources = (self.imagery, self.terrain, self.buildings)
        return "; ".join(dict.fromkeys(s.attribution for s in sources if s and s.attribution))


def default_world() -> World:
    """The world of a clip when nothing is configured: app.world.defaults' open sources,
    probed before they are used (probe_s). Raises GeofuseError for a replacement spelt wrongly
    in GEOFUSE_DEFAULT_IMAGERY/GEOFUSE_DEFAULT_TERRAIN, naming the variable."""
    out = []
    for kind, text, env in zip(
        ("imagery", "terrain"),
        defaults.spellings(),
        (defaults.ENV_IMAGERY, defaults.ENV_TERRAIN),
        strict=True,
    ):
        try:
            out.append(parse_source(text, kind) if text else None)
        except SourceError as exc:
            raise GeofuseError(f"{env}: {exc}") from exc
    return World(defaults.NAME, out[0], out[1], probe_s=defaults.PROBE_TIMEOUT_S)


def settings_path() -> Path:
    """The settings file: config_dir()/settings.toml."""
    return config_dir() / "settings.toml"


def how_to_configure() -> str:
    """A sentence saying how to configure a world source (for the flat ground's message)."""
    return HOW_TO.format(path=settings_path())


def world_tables(path: Path | None = None) -> list[dict]:
    """The [[world]] tables of the settings file, their names and keys checked (none when the
    file does not exist). Raises GeofuseError naming the file and the table at fault."""
    path = path or settings_path()
    if not path.is_file():
        return []
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeofuseError(f"{path}: cannot read as TOML: {exc}") from exc
    tables = doc.get("world", [])
    if not isinstance(tables, list):
        raise GeofuseError(f"{path}: 'world' must be [[world]] tables")
    for i, table in enumerate(tables):
        where = f"{path}: [[world]] {table.get('name', f'#{i + 1}')!r}"
        unknown = set(table) - KEYS
        if unknown:
            raise GeofuseError(
                f"{where}: unknown key(s) {', '.join(sorted(unknown))} (expected {', '.join(sorted(KEYS))})"
            )
        if not isinstance(table.get("name"), str) or not table["name"].strip():
            raise GeofuseError(f"{where}: give it a name")
        if table["name"].lower() == NONE:
            raise GeofuseError(f"{where}: 'none' is kept for the flat ground")
    return tables


def world_of(table: dict, path: Path | None = None) -> World:
    """The World a [[world]] table names (its key read from the environment now). Raises
    GeofuseError naming the file and the table."""
    try:
        return _world(table)
    except SourceError as exc:
        raise GeofuseError(
            f"{path or settings_path()}: [[world]] {table.get('name')!r}: {exc}"
        ) from exc


MANIFEST_KEYS = KEYS - {"key"}  # a manifest is shared: a key only through key_env there


def manifest_world(table: dict, folder: Path) -> World:
    """The World a session manifest's [world] table names: `name` alone, a [[world]] of the
    settings file; else its own sources (the [[world]] keys but a literal key), local files
    relative to the manifest's `folder`. Raises GeofuseError saying what is wrong (the caller
    names the manifest's key)."""
    given = {k: v for k, v in table.items() if k != "name"}
    if not given:
        name = table.get("name")
        if not isinstance(name, str) or not name.strip():
            raise GeofuseError("name a [[world]] of the settings file, or give imagery/terrain")
        world = choose_world(name)
        if world is None:
            raise GeofuseError("'none' keeps the flat ground: drop the [world] table instead")
        return world
    if "key" in table:
        raise GeofuseError("no key in a manifest: key_env names the environment variable")
    own = dict(table, name=str(table.get("name", "manifest")))
    for kind in ("imagery", "terrain"):
        if isinstance(own.get(kind), str):
            own[kind] = _relative_to(own[kind], folder)
    try:
        return _world(own)
    except SourceError as exc:
        raise GeofuseError(str(exc)) from exc


def _relative_to(text: str, folder: Path) -> str:
    """A source's spelling with a local file resolved against `folder` (prefixes kept)."""
    prefix = ""
    rest = text.strip()
    for p in (*(e + ":" for e in ENCODINGS), "tms:", "wmts:"):
        if rest.lower().startswith(p):
            prefix, rest = prefix + rest[: len(p)], rest[len(p) :]
    if rest.lower().startswith(("http://", "https://")) or Path(rest).is_absolute():
        return text
    return prefix + str((folder / rest).resolve())


def read_worlds(path: Path | None = None) -> list[World]:
    """Every world of the settings file (module docstring)."""
    return [world_of(t, path) for t in world_tables(path)]


def _key(table: dict) -> str | None:
    env = table.get("key_env")
    if env is None:
        return table.get("key")
    value = os.environ.get(str(env))
    if not value:
        raise SourceError(f"the environment variable {env} (key_env) is not set")
    return value


def _world(table: dict) -> World:
    if not any(table.get(k) for k in ("imagery", "terrain", "buildings")):
        raise SourceError(
            "name an imagery source, a terrain source, buildings (overpass:), or some of them"
        )
    key = _key(table) if ("key_env" in table or "key" in table) else None
    common = {
        "attribution": str(table.get("attribution", "")),
        "headers": {str(k): str(v) for k, v in dict(table.get("headers", {})).items()},
        "key": key,
    }
    imagery = terrain = None
    if table.get("imagery"):
        imagery = parse_source(
            str(table["imagery"]), "imagery", max_zoom=table.get("imagery_max_zoom"), **common
        )
    if table.get("terrain"):
        terrain = parse_source(
            str(table["terrain"]),
            "terrain",
            datum=table.get("datum"),
            max_zoom=table.get("terrain_max_zoom"),
            **common,
        )
    reach = table.get("reach_m")
    if reach is not None and (
        isinstance(reach, bool)
        or not isinstance(reach, int | float)
        or not math.isfinite(reach)
        or reach <= 0
    ):
        raise SourceError(f"reach_m must be a distance in metres above 0 (got {reach!r})")
    return World(
        str(table["name"]),
        imagery,
        terrain,
        common["attribution"],
        float(table.get("timeout_s", DEFAULT_TIMEOUT_S)),
        parse_overpass(str(table["buildings"])) if table.get("buildings") else None,
        reach_m=None if reach is None else float(reach),
    )


def choose_world(
    name: str | None = None,
    imagery: str | None = None,
    terrain: str | None = None,
    scene_named: bool = False,
    datum: str | None = None,
    buildings: str | None = None,
) -> World | None:
    """The world a command drapes its clip on, None for the flat ground (or the scene named).

    name: --world (NAME or 'none'); imagery, terrain: --imagery, --terrain (one-off sources,
    replacing the named world's); scene_named: a --scene/--dem was given (then no world unless
    asked for); datum: --dem-vertical, the heights of --terrain (default EGM2008); buildings:
    --buildings overpass:[URL] (one-off, as imagery and terrain). With none of them, GEOFUSE_WORLD's name, else the settings' first world. Raises
    GeofuseError for an unknown name, listing the names configured."""
    given = imagery or terrain or buildings
    if name is not None and name.lower() == NONE:
        if given:
            raise GeofuseError(
                "--world none keeps the flat ground: drop --imagery/--terrain/--buildings overpass:"
            )
        return None
    if name is None and not given:
        if scene_named:
            return None
        name = os.environ.get(ENV_WORLD) or None
        if name is not None and name.lower() == NONE:
            return None
    tables = world_tables() if name is not None or not given else []
    world = None
    if name is not None:
        table = next((t for t in tables if t["name"] == name), None)
        if table is None:
            names = ", ".join(t["name"] for t in tables)
            raise GeofuseError(
                f"--world {name}: no such world in {settings_path()} "
                + (f"(configured: {names}, or none)" if names else "(none is configured there)")
            )
        world = world_of(table)
    elif tables and not given:
        world = world_of(tables[0])
    elif not given:
        world = default_world()  # nothing configured: open sources, where the network answers
    if not given:
        return world
    try:
        return World(
            world.name if world else "given",
            parse_source(imagery, "imagery") if imagery else world.imagery if world else None,
            parse_source(terrain, "terrain", datum=datum)
            if terrain
            else world.terrain
            if world
            else None,
            world.attribution if world else "",
            world.timeout_s if world else DEFAULT_TIMEOUT_S,
            parse_overpass(buildings) if buildings else world.buildings if world else None,
        )
    except SourceError as exc:
        raise GeofuseError(str(exc)) from exc
