"""What several of `geofuse`'s commands parse alike: argparse types that refuse a value out of
range with exit 2, naming the option (finite numbers in a range, counts, comma-separated
tuples, sizes, UTC times), the parser class with the project's one-line errors, and the option
groups commands share (a clip's scene layers, a still's camera, the projection, the pose source,
a clip's subtitle and lens). Imports nothing heavy: `geofuse --help` loads this and no more."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

from app.core.constants import (
    DEFAULT_DEPTH_BIAS_M,
    DEFAULT_DEPTH_LONG_SIDE_PX,
    DEFAULT_DEPTH_SLOPE_BIAS,
    DRONE_DEFAULT_PITCH_DEG,
    FOV_RANGE_DEG,
)

MAX_IMAGE_SIDE = 8192  # pixels: what every OpenGL 4 renderbuffer (and llvmpipe) can hold
COMMA_OPTIONS = ("--origin", "--pose", "--view-from", "--look-at", "--near")  # may start with '-'
GEODETIC = (
    (-90.0, 90.0, "latitude"),
    (-180.0, 360.0, "longitude"),
    (-12_000.0, 100_000.0, "height"),
)
ATTITUDE = ((-360.0, 360.0, "heading"), (-90.0, 90.0, "pitch"), (-180.0, 180.0, "roll"))


def floats(
    text: str, count: int, ranges: tuple[tuple[float, float, str], ...] = ()
) -> tuple[float, ...]:
    """COUNT comma-separated finite numbers, each within its (low, high, name) range if given."""
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"expected {count} comma-separated finite numbers, got {text!r}"
        )
    for v, (low, high, name) in zip(values, ranges, strict=False):
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"{name} {v:g} is outside [{low:g}, {high:g}]")
    return values


def number(low: float, high: float, open_low: bool = False):
    """An argparse type: a finite float in [low, high] ((low, high] with open_low)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or not low <= v <= high or (open_low and v == low):
            raise argparse.ArgumentTypeError(
                f"expected a finite number in {'(' if open_low else '['}{low:g}, {high:g}], got {text!r}"
            )
        return v

    return parse


def count(low: int, high: int):
    """An argparse type: a whole number in [low, high]."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            v = low - 1
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(
                f"expected a whole number in [{low}, {high}], got {text!r}"
            )
        return v

    return parse


def utc(text: str) -> datetime:
    """An argparse type: an ISO 8601 time, UTC where it names no zone."""
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected an ISO 8601 time, got {text!r}") from exc
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from exc
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
        raise argparse.ArgumentTypeError(
            f"each side must be 1 to {MAX_IMAGE_SIDE} pixels, got {text!r}"
        )
    return w, h


def joined_negative_values(argv: Sequence[str]) -> list[str]:
    """`--view-from -150,-150,120` as `--view-from=-150,-150,120`: argparse takes a value that
    starts with '-' for an option unless it is joined to its option."""
    out: list[str] = []
    args = list(argv)
    i = 0
    while i < len(args):
        if (
            args[i] in COMMA_OPTIONS
            and i + 1 < len(args)
            and args[i + 1][:1] == "-"
            and args[i + 1][1:2].isdigit() | (args[i + 1][1:2] == ".")
        ):
            out.append(f"{args[i]}={args[i + 1]}")
            i += 2
            continue
        out.append(args[i])
        i += 1
    return out


def add_projection_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--alpha",
        type=number(0.0, 1.0),
        default=1.0,
        help="video opacity over the model, 0..1 (default 1)",
    )
    p.add_argument(
        "--bias",
        type=number(0.0, 100.0),
        default=DEFAULT_DEPTH_BIAS_M,
        help="constant depth bias, metres",
    )
    p.add_argument(
        "--slope-bias",
        type=number(0.0, 100.0),
        default=DEFAULT_DEPTH_SLOPE_BIAS,
        help="slope-scaled depth bias, depth-map texels",
    )
    p.add_argument(
        "--depth-size",
        type=count(16, MAX_IMAGE_SIDE),
        default=DEFAULT_DEPTH_LONG_SIDE_PX,
        help="depth-map texels on the video's long side",
    )
    p.add_argument(
        "--no-neighbourhood",
        action="store_true",
        help="test only the fragment's own depth texel (not the nine-case rule)",
    )
    p.add_argument("--no-frustum", action="store_true", help="do not draw the projector's frustum")


def add_layer_options(p: argparse.ArgumentParser, placed_models: bool = False) -> None:
    """--scene (repeatable), --dem, --buildings, --ortho, --dem-vertical, --city-theme, --world,
    --imagery, --terrain, --dem-error: a clip's scene."""
    what = (
        "a model (glTF/GLB, OBJ, PLY) placed by --origin, "
        if placed_models
        else "a model in ECEF, "
    )
    p.add_argument(
        "--scene",
        action="append",
        default=None,
        metavar="PATH|URL",
        help=f"a scene layer, repeatable: a 3D Tiles tileset.json (folder or http(s) URL), a DEM .tif, a CityJSON (.city.json, .city.jsonl) or CityGML (.gml, .xml, .zip) city model, OpenStreetMap (.osm, .osm.pbf) or GeoParquet buildings (as --buildings), or {what}drawn together",
    )
    p.add_argument(
        "--dem",
        type=Path,
        default=None,
        help="terrain from a GeoTIFF DEM in any CRS (the same as --scene DEM.tif)",
    )
    p.add_argument(
        "--buildings",
        action="append",
        default=None,
        metavar="FILE|overpass:",
        help="buildings, repeatable: OpenStreetMap (.osm, .osm.pbf) or GeoParquet (Overture) footprints extruded to LoD1 from their height or levels, standing on the other layers' ground (else the clip's assumed flat ground); or any scene layer; or overpass: (overpass:URL for another instance than overpass-api.de): OpenStreetMap's buildings over the clip's area fetched once from the Overpass API (its fair use: one query a scene, at most 25 km2, kept in the tile cache for offline use)",
    )
    p.add_argument(
        "--ortho", type=Path, default=None, help="an orthophoto GeoTIFF draped on the DEM"
    )
    p.add_argument(
        "--dem-vertical",
        choices=("ellipsoid", "egm2008", "egm96"),
        default=None,
        help="the heights of a DEM or a city model are above this (default: the file's vertical CRS, else EGM2008)",
    )
    p.add_argument(
        "--city-theme",
        default=None,
        metavar="NAME",
        help="a city model's appearance theme drawn (its textures and materials; default: the first the file names)",
    )
    p.add_argument(
        "--world",
        default=None,
        metavar="NAME",
        help="drape a clip with no scene on the terrain and imagery of this [[world]] of the settings file (default: its first; with none there, open keyless sources where they answer within 2 s; 'none': the flat ground)",
    )
    p.add_argument(
        "--imagery",
        default=None,
        metavar="SRC",
        help="imagery for this run: an XYZ URL template with {z}/{x}/{y} (tms: before it for TMS rows), a WMTS capabilities URL (#layer=NAME), an .mbtiles, .pmtiles or .gpkg file, a GeoTIFF/COG (URL or file), or a provider's name (Esri.WorldImagery: geofuse cache --providers lists them)",
    )
    p.add_argument(
        "--terrain",
        default=None,
        metavar="SRC",
        help="terrain for this run: terrain-rgb: or terrarium: before a PNG URL template, a WMTS capabilities URL or an .mbtiles/.pmtiles/.gpkg file; or a DEM GeoTIFF/COG (URL or file); heights above EGM2008 unless --dem-vertical says otherwise; or a Cesium quantized-mesh layer.json URL (heights above the ellipsoid); or a provider's name (AWS.Terrarium)",
    )
    p.add_argument(
        "--dem-error",
        type=number(0.01, 100.0),
        default=0.5,
        help="the terrain mesh's largest vertical error, metres (default 0.5)",
    )


class Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors (`geofuse: error: ...`, exit status 2)."""

    def error(self, message: str):
        self.exit(
            2,
            f"geofuse: error: {self.prog.split(' ', 1)[-1]}: {message}\n"
            if " " in self.prog
            else f"geofuse: error: {message}\n",
        )


def add_still_options(p: argparse.ArgumentParser) -> None:
    """A still's scene and camera: --scene/--dem (placed by --origin, --up, --scene-heading,
    --scene-scale), --image, --pose, --fov or --lens (render, locate)."""
    add_layer_options(p, placed_models=True)
    p.add_argument(
        "--origin",
        type=lambda s: floats(s, 3, GEODETIC),
        metavar="LAT,LON,H",
        help="the scene's origin: degrees, degrees, ellipsoidal metres",
    )
    p.add_argument(
        "--up",
        choices=["Y", "Z"],
        default=None,
        help="the scene's up axis (default: Y for glTF, Z otherwise)",
    )
    p.add_argument(
        "--scene-heading",
        type=number(-360.0, 360.0),
        default=0.0,
        help="rotate the scene clockwise about Up, degrees",
    )
    p.add_argument(
        "--scene-scale",
        type=number(0.0, 1e6, open_low=True),
        default=1.0,
        help="scene units -> metres",
    )
    p.add_argument(
        "--image",
        type=Path,
        action="append",
        default=None,
        help="the image (video frame) to project: PNG or JPEG; repeatable (several projected at once, each with its own --pose)",
    )
    p.add_argument(
        "--pose",
        type=lambda s: floats(s, 6, GEODETIC + ATTITUDE),
        action="append",
        default=None,
        metavar="LAT,LON,H,HEADING,PITCH,ROLL",
        help="the image's camera: position (deg, deg, ellipsoidal m) and optical-axis heading (deg from true north, clockwise), pitch (deg above horizon), roll (deg); repeatable, paired with --image by order",
    )
    p.add_argument(
        "--fov",
        type=number(*FOV_RANGE_DEG),
        action="append",
        default=None,
        help="the image's horizontal field of view, degrees; one for all images, or one each",
    )
    p.add_argument(
        "--lens",
        type=Path,
        action="append",
        default=None,
        help="a gyroflow lens profile (JSON) of the image's camera, instead of --fov (one for all, or one each); with --session, of a clip",
    )


def add_source_option(p: argparse.ArgumentParser, help: str, filter_alias: bool = True) -> None:
    """--source (also spelled --filter): the pose source of a session or clip."""
    names = ("--source", "--filter") if filter_alias else ("--source",)
    p.add_argument(*names, dest="source", default=None, help=help)


def add_srt_option(p: argparse.ArgumentParser, help: str) -> None:
    """--srt: a DJI clip's subtitle when it is not beside the video; --klv, the same place: the
    video's raw KLV (Local Sets, timed by their stamps) kept apart from it."""
    p.add_argument("--srt", type=Path, default=None, help=help)
    p.add_argument(
        "--klv",
        type=Path,
        default=None,
        dest="srt",
        help="the video's MISB ST 0601 KLV as a raw file (.klv/.bin), when not beside it",
    )


def add_lens_option(
    p: argparse.ArgumentParser,
    help: str = "a gyroflow lens profile (JSON) for a clip (default: chosen from the file)",
) -> None:
    """--lens: a clip's gyroflow lens profile instead of the one chosen from the file."""
    p.add_argument("--lens", type=Path, default=None, help=help)


def add_fov_option(p: argparse.ArgumentParser) -> None:
    """--fov: a clip's horizontal field of view (degrees), overriding its lens's."""
    p.add_argument(
        "--fov",
        type=number(*FOV_RANGE_DEG),
        default=None,
        help="override the lens's horizontal field of view, degrees",
    )


def add_pitch_option(p: argparse.ArgumentParser, help: str) -> None:
    """--pitch: a drone clip's camera pitch (degrees above the horizon) where it wrote none."""
    p.add_argument("--pitch", type=number(-90.0, 90.0), default=DRONE_DEFAULT_PITCH_DEG, help=help)


def add_radius(p: argparse.ArgumentParser, name: str, default: float | None, help: str) -> None:
    """An option of a search's radius (metres, positive): --radius of an area to start from,
    --search-radius of a live feed's home point."""
    p.add_argument(
        name, type=number(0.0, 100_000.0, open_low=True), default=default, metavar="M", help=help
    )


def add_gnss_accuracy_option(p: argparse.ArgumentParser) -> None:
    """--gnss-accuracy M: the fixes' accuracy where they state none (a clip's, a stream's)."""
    p.add_argument(
        "--gnss-accuracy",
        type=number(0.1, 1000.0),
        default=None,
        metavar="M",
        help="the GNSS's accuracy, metres (1 sigma per axis), where its fixes state none (a DJI subtitle, GPX, KLV, MAVLink without GPS_RAW_INT's h_acc): "
        "the fixes are tested against the registered keyframes and the IMU with it (default 5; a smaller one catches a drag-off sooner, under open sky only: fixes that state no accuracy cannot say they grew less sure, so a multipath burst is then taken for a lie)",
    )


def add_start_options(p: argparse.ArgumentParser) -> None:
    """--near LAT,LON with --radius M, or --start-area FILE, and --height M: where a clip with no
    GNSS fix at all begins (its `registered` source searches the scene there for the first
    pose: app.register.coldstart)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--near",
        type=lambda s: floats(s, 2, GEODETIC[:2]),
        default=None,
        metavar="LAT,LON",
        help="a clip with no GNSS fix at all: search the scene within --radius of this place (degrees) for its first pose (the registered source)",
    )
    where.add_argument(
        "--start-area",
        type=Path,
        default=None,
        metavar="FILE",
        help="as --near, within a GeoJSON polygon (or a Feature of one)",
    )
    add_radius(p, "--radius", None, "with --near: metres around it (default 300)")
    p.add_argument(
        "--height",
        type=number(0.0, 100_000.0, open_low=True),
        default=None,
        metavar="M",
        help="with --near or --start-area: the camera's height above the ground, metres (default: a DJI subtitle's height above take-off, else a phone's mount height)",
    )
