"""`geofuse`'s commands and their options: argument parsing only (argparse types that refuse a
value out of range with exit 2, naming the option). Each command names its job
("module:function" in app.cli; function `run` by default), which app.cli.main imports and calls.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

from app.core.constants import (
    DEFAULT_DEPTH_BIAS_M,
    DEFAULT_DEPTH_LONG_SIDE_PX,
    DEFAULT_DEPTH_SLOPE_BIAS,
    DEFAULT_FAR_M,
    DRONE_DEFAULT_PITCH_DEG,
    FOV_RANGE_DEG,
    SYNC_MIN_CONFIDENCE,
)
from app.export import EXPORT_SUFFIXES

MAX_IMAGE_SIDE = 8192  # pixels: what every OpenGL 4 renderbuffer (and llvmpipe) can hold
COMMA_OPTIONS = ("--origin", "--pose", "--view-from", "--look-at")  # values that may start with '-'
GEODETIC = (
    (-90.0, 90.0, "latitude"),
    (-180.0, 360.0, "longitude"),
    (-12_000.0, 100_000.0, "height"),
)
BENCHMARKS = {
    "render": "bench_render.py",
    "attitude": "bench_attitude.py",
    "accuracy": "bench_accuracy.py",
    "playback": "bench_playback.py",
    "lens": "bench_lens.py",
    "sync": "bench_sync.py",
    "registration": "bench_registration.py",
    "footprints": "bench_footprints.py",
    "index": "bench_index.py",
}
ATTITUDE = ((-360.0, 360.0, "heading"), (-90.0, 90.0, "pitch"), (-180.0, 180.0, "roll"))


def _floats(
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
    for v, (low, high, name) in zip(values, ranges):
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"{name} {v:g} is outside [{low:g}, {high:g}]")
    return values


def _number(low: float, high: float, open_low: bool = False):
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


def _count(low: int, high: int):
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


def _utc(text: str) -> datetime:
    """An argparse type: an ISO 8601 time, UTC where it names no zone."""
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected an ISO 8601 time, got {text!r}") from exc
    return t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)


def _size(text: str) -> tuple[int, int]:
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


def _add_projection_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--alpha",
        type=_number(0.0, 1.0),
        default=1.0,
        help="video opacity over the model, 0..1 (default 1)",
    )
    p.add_argument(
        "--bias",
        type=_number(0.0, 100.0),
        default=DEFAULT_DEPTH_BIAS_M,
        help="constant depth bias, metres",
    )
    p.add_argument(
        "--slope-bias",
        type=_number(0.0, 100.0),
        default=DEFAULT_DEPTH_SLOPE_BIAS,
        help="slope-scaled depth bias, depth-map texels",
    )
    p.add_argument(
        "--depth-size",
        type=_count(16, MAX_IMAGE_SIDE),
        default=DEFAULT_DEPTH_LONG_SIDE_PX,
        help="depth-map texels on the video's long side",
    )
    p.add_argument(
        "--no-neighbourhood",
        action="store_true",
        help="test only the fragment's own depth texel (not the nine-case rule)",
    )
    p.add_argument("--no-frustum", action="store_true", help="do not draw the projector's frustum")


def _add_layer_options(p: argparse.ArgumentParser, placed_models: bool = False) -> None:
    """--scene (repeatable), --dem, --ortho, --dem-vertical, --dem-error: a clip's scene."""
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
        help=f"a scene layer, repeatable: a 3D Tiles tileset.json (folder or http(s) URL), a DEM .tif, or {what}drawn together",
    )
    p.add_argument(
        "--dem",
        type=Path,
        default=None,
        help="terrain from a GeoTIFF DEM in any CRS (the same as --scene DEM.tif)",
    )
    p.add_argument(
        "--ortho", type=Path, default=None, help="an orthophoto GeoTIFF draped on the DEM"
    )
    p.add_argument(
        "--dem-vertical",
        choices=("ellipsoid", "egm2008", "egm96"),
        default=None,
        help="the DEM's heights are above this (default: the file's vertical CRS, else EGM2008)",
    )
    p.add_argument(
        "--dem-error",
        type=_number(0.01, 100.0),
        default=0.5,
        help="the terrain mesh's largest vertical error, metres (default 0.5)",
    )


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors (`geofuse: error: ...`, exit status 2)."""

    def error(self, message: str):
        self.exit(
            2,
            f"geofuse: error: {self.prog.split(' ', 1)[-1]}: {message}\n"
            if " " in self.prog
            else f"geofuse: error: {message}\n",
        )


def _add_still_options(p: argparse.ArgumentParser) -> None:
    """A still's scene and camera: --scene/--dem (placed by --origin, --up, --scene-heading,
    --scene-scale), --image, --pose, --fov or --lens (render, locate)."""
    _add_layer_options(p, placed_models=True)
    p.add_argument(
        "--origin",
        type=lambda s: _floats(s, 3, GEODETIC),
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
        type=_number(-360.0, 360.0),
        default=0.0,
        help="rotate the scene clockwise about Up, degrees",
    )
    p.add_argument(
        "--scene-scale",
        type=_number(0.0, 1e6, open_low=True),
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
        type=lambda s: _floats(s, 6, GEODETIC + ATTITUDE),
        action="append",
        default=None,
        metavar="LAT,LON,H,HEADING,PITCH,ROLL",
        help="the image's camera: position (deg, deg, ellipsoidal m) and optical-axis heading (deg from true north, clockwise), pitch (deg above horizon), roll (deg); repeatable, paired with --image by order",
    )
    p.add_argument(
        "--fov",
        type=_number(*FOV_RANGE_DEG),
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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="geofuse", description="Drape mobile video onto a georeferenced 3D model."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render one image projected onto a scene to a PNG")
    r.add_argument(
        "--session",
        type=Path,
        action="append",
        default=None,
        help="a session manifest or clip: the frame at --time with its solved pose; repeatable (the others' frames at the same moment on one timeline, drawn on the first one's scene)",
    )
    r.add_argument(
        "--time",
        type=_number(-1e6, 1e6),
        default=None,
        help="with --session: seconds from the video's first frame",
    )
    r.add_argument(
        "--source",
        "--filter",
        dest="source",
        default=None,
        help="with --session: attitude source (default: the first the session offers)",
    )
    _add_still_options(r)
    r.add_argument(
        "--view-from",
        type=lambda s: _floats(s, 3),
        metavar="E,N,U",
        default=None,
        help="window camera position, ENU metres (default: behind and above the image's camera)",
    )
    r.add_argument(
        "--look-at",
        type=lambda s: _floats(s, 3),
        metavar="E,N,U",
        default=None,
        help="window camera target, ENU metres",
    )
    r.add_argument(
        "--view-fov",
        type=_number(*FOV_RANGE_DEG),
        default=60.0,
        help="window camera horizontal field of view, degrees",
    )
    r.add_argument(
        "--size", type=_size, default=(1280, 720), help="output WIDTHxHEIGHT (default 1280x720)"
    )
    r.add_argument(
        "--far",
        type=_number(1.0, 1e7),
        default=DEFAULT_FAR_M,
        help="far plane of both cameras, metres",
    )
    _add_projection_options(r)
    r.add_argument("--out", required=True, type=Path, help="output PNG")
    r.set_defaults(job="render")

    lo = sub.add_parser(
        "locate",
        help="where a pixel of a video frame (or of a still) lies on the scene: latitude, longitude, heights, range",
    )
    lo.add_argument(
        "input",
        nargs="?",
        type=Path,
        default=None,
        help="a session manifest or a clip (GoPro MP4, DJI MP4); or give a still's --scene, --image, --pose",
    )
    lo.add_argument(
        "--time",
        type=_number(-1e6, 1e6),
        default=None,
        help="with a session or clip: seconds from the video's first frame",
    )
    lo.add_argument(
        "--pixel",
        type=lambda s: _floats(s, 2),
        action="append",
        metavar="X,Y",
        default=None,
        help="image pixel coordinates (x right, y down, 0,0 the top-left corner), repeatable",
    )
    lo.add_argument(
        "--pixels",
        type=Path,
        default=None,
        help="a CSV of X,Y pixel coordinates (a header optional)",
    )
    lo.add_argument(
        "--source",
        "--filter",
        dest="source",
        default=None,
        help="attitude source (default: the first the session offers)",
    )
    lo.add_argument(
        "--srt", type=Path, default=None, help="a DJI clip's subtitle, when not beside it"
    )
    _add_still_options(lo)
    lo.add_argument("--json", action="store_true", help="print a JSON array for scripts")
    lo.set_defaults(job="locate")

    ix = sub.add_parser(
        "index",
        help="index folders of clips into one GeoParquet archive of footprints, on Dask distributed",
    )
    ix.add_argument("folders", nargs="+", type=Path, help="folders (walked) or files of clips")
    ix.add_argument("--out", required=True, type=Path, help="the archive: ARCHIVE.parquet")
    ix.add_argument(
        "--every-s",
        type=_number(0.01, 3600.0),
        default=1.0,
        help="seconds between footprints (default 1)",
    )
    ix.add_argument(
        "--scene",
        action="append",
        default=None,
        metavar="PATH|URL",
        help="a scene layer for every clip without its own (a tileset, a DEM, a model in ECEF), repeatable; default: the manifest's, else the assumed ground",
    )
    ix.add_argument(
        "--source",
        default=None,
        help="pose source for every clip (default: the first each offers)",
    )
    where = ix.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=_count(1, 1024),
        default=None,
        help="worker processes of a local Dask cluster (default: one per core)",
    )
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="an existing Dask scheduler (`dask scheduler`, with `dask worker` on each machine)",
    )
    ix.set_defaults(job="index")

    fi = sub.add_parser(
        "find", help="the clips of an archive that saw a place, and when (most head-on first)"
    )
    fi.add_argument("archive", type=Path, help="ARCHIVE.parquet written by `geofuse index`")
    place = fi.add_mutually_exclusive_group(required=True)
    place.add_argument(
        "--point",
        type=lambda s: _floats(s, 2, GEODETIC[:2]),
        metavar="LAT,LON",
        help="a place: latitude, longitude (degrees)",
    )
    place.add_argument(
        "--polygon", type=Path, help="an area: a GeoJSON file of a Polygon (or a Feature of one)"
    )
    fi.add_argument(
        "--radius",
        type=_number(0.0, 100_000.0),
        default=0.0,
        help="with --point: metres around it (default 0)",
    )
    fi.add_argument("--from", dest="start", type=_utc, default=None, help="ISO 8601 time (UTC)")
    fi.add_argument("--to", dest="end", type=_utc, default=None, help="ISO 8601 time (UTC)")
    fi.add_argument("--json", action="store_true", help="print the hits as a JSON array")
    fi.add_argument(
        "--open", action="store_true", help="open the viewer on the best clip at that time"
    )
    fi.set_defaults(job="find")

    v = sub.add_parser(
        "view", help="the interactive viewer (the bundled sample when no manifest is given)"
    )
    v.add_argument(
        "manifest",
        nargs="*",
        type=Path,
        default=None,
        help="a session manifest, a GoPro MP4 or a DJI clip (default: the bundled sample); several play together on one timeline, on the first one's scene",
    )
    v.add_argument(
        "--srt", type=Path, default=None, help="the DJI subtitle of the clip, when not beside it"
    )
    v.add_argument(
        "--lens",
        type=Path,
        default=None,
        help="a gyroflow lens profile (JSON) for a clip (default: chosen from the file)",
    )
    _add_layer_options(v)
    v.add_argument("--size", type=_size, default=(1280, 720), help="window WIDTHxHEIGHT")
    v.add_argument(
        "--script", type=Path, default=None, help="a file of timed UI actions (app/ui/script.py)"
    )
    v.add_argument(
        "--screenshot",
        type=Path,
        default=None,
        help="save the window to this PNG (alone: after --play seconds, then exit)",
    )
    v.add_argument(
        "--play",
        type=_number(0.0, 3600.0),
        default=2.0,
        help="with --screenshot alone: seconds to play first",
    )
    v.set_defaults(job="view")

    so = sub.add_parser(
        "solve", help="a camera pose for every video frame of a session or clip, as CSV"
    )
    so.add_argument(
        "manifest",
        type=Path,
        help="a session manifest (.toml), a GoPro MP4, or a DJI clip (its .SRT beside it)",
    )
    so.add_argument(
        "--source",
        "--filter",
        dest="source",
        default=None,
        help="attitude source: gd-ahrs | gd-imu | cf-ahrs | cf-imu | offline | phone | camera | telemetry | course | truth (default: the first the session offers)",
    )
    so.add_argument(
        "--srt", type=Path, default=None, help="the DJI subtitle of the clip, when not beside it"
    )
    so.add_argument(
        "--lens",
        type=Path,
        default=None,
        help="a gyroflow lens profile (JSON) for a clip (default: chosen from the file)",
    )
    _add_layer_options(so)
    so.add_argument(
        "--fov",
        type=_number(*FOV_RANGE_DEG),
        default=None,
        help="override the lens's horizontal field of view, degrees",
    )
    so.add_argument(
        "--pitch",
        type=_number(-90.0, 90.0),
        default=DRONE_DEFAULT_PITCH_DEG,
        help=f"a drone clip without gimbal attitude: the camera's pitch, degrees (default {DRONE_DEFAULT_PITCH_DEG:g})",
    )
    so.add_argument("--out", type=Path, required=True)
    so.set_defaults(job="solve")

    ex = sub.add_parser(
        "export",
        help="footprints (GeoJSON/KML/KMZ), an FMV metadata CSV, MISB KLV in MPEG-TS, or the fused view as a video",
    )
    ex.add_argument(
        "what",
        choices=sorted(EXPORT_SUFFIXES),
        help="footprints: .geojson/.kml/.kmz; fmv-csv: .csv; klv: .ts; video: .mp4",
    )
    ex.add_argument(
        "input",
        type=Path,
        nargs="+",
        help="a session manifest, a GoPro MP4 or a DJI clip; footprints: several, each footprint with its clip",
    )
    ex.add_argument("--out", type=Path, required=True)
    ex.add_argument(
        "--source",
        "--filter",
        dest="source",
        default=None,
        help="attitude source (default: the first the session offers)",
    )
    ex.add_argument(
        "--every",
        type=_count(1, 1_000_000),
        default=1,
        help="footprints, CSV, KLV: every Nth frame (1: every frame)",
    )
    ex.add_argument(
        "--from",
        dest="start",
        type=_number(0.0, 1e7),
        default=None,
        help="video: first second (media time)",
    )
    ex.add_argument(
        "--to",
        dest="end",
        type=_number(0.0, 1e7),
        default=None,
        help="video: last second (media time)",
    )
    ex.add_argument("--size", type=_size, default=(1280, 720), help="video: WIDTHxHEIGHT")
    ex.add_argument(
        "--view",
        choices=("ride", "follow", "orbit", "top"),
        default="follow",
        help="video: the window camera",
    )
    ex.add_argument(
        "--preview",
        type=Path,
        default=None,
        help="footprints, CSV, KLV: also a PNG of the footprints seen from above (--size)",
    )
    ex.add_argument(
        "--srt", type=Path, default=None, help="the DJI subtitle of the clip, when not beside it"
    )
    ex.add_argument(
        "--lens",
        type=Path,
        default=None,
        help="a gyroflow lens profile (JSON) for a clip (default: chosen from the file)",
    )
    _add_layer_options(ex)
    ex.add_argument(
        "--fov",
        type=_number(*FOV_RANGE_DEG),
        default=None,
        help="override the lens's horizontal field of view, degrees",
    )
    ex.add_argument(
        "--pitch",
        type=_number(-90.0, 90.0),
        default=DRONE_DEFAULT_PITCH_DEG,
        help="a drone clip without gimbal attitude: the camera's pitch, degrees",
    )
    ex.set_defaults(job="export")

    rg = sub.add_parser(
        "register",
        help="control points by hand: solve the clip's boresight and a position correction from pixel <-> model point pairs",
    )
    rg.add_argument(
        "input", type=Path, help="a session manifest, a GoPro MP4, or a DJI MP4 with its subtitle"
    )
    rg.add_argument(
        "--points",
        type=Path,
        required=True,
        help="CSV of frame, x, y, latitude, longitude, height (ellipsoidal m): a video pixel and the model point it shows; 4 pairs or more",
    )
    rg.add_argument(
        "--source",
        default=None,
        help="the pose source to correct (default: offline, else the first the session offers)",
    )
    rg.add_argument(
        "--write",
        action="store_true",
        help="keep the points in NAME.control.csv beside the input (never in an input); the registered source then starts from their correction",
    )
    rg.add_argument(
        "--lens", type=Path, default=None, help="a gyroflow lens profile (JSON) for a clip"
    )
    rg.set_defaults(job="register")

    sy = sub.add_parser(
        "sync",
        help="the time offset between the video and the gyroscope (or a recorded attitude: a DJI gimbal, a camera, a phone; or a drone's course: the lag of its GNSS track), from the camera's rotation seen in the video",
    )
    sy.add_argument(
        "input", type=Path, help="a session manifest, a GoPro MP4, or a DJI MP4 with its subtitle"
    )
    sy.add_argument(
        "--write",
        action="store_true",
        help="keep it in NAME.geofuse.toml beside the input (never in an input)",
    )
    sy.add_argument(
        "--force",
        action="store_true",
        help=f"with --write: keep an offset found with a confidence below {SYNC_MIN_CONFIDENCE} too",
    )
    sy.add_argument(
        "--lens", type=Path, default=None, help="a gyroflow lens profile (JSON) for a clip"
    )
    sy.set_defaults(job="sync")

    te = sub.add_parser(
        "telemetry", help="what a telemetry file holds: streams, rates, gaps, fixes, messages"
    )
    te.add_argument(
        "file",
        type=Path,
        help="a GoPro MP4, a DJI .SRT, a GPX, a Sensor Logger folder/zip or a geofuse CSV",
    )
    te.add_argument(
        "--csv",
        type=Path,
        default=None,
        help="write the position track: time_s,latitude,longitude,height[,attitude...]",
    )
    te.set_defaults(job="telemetry")

    s = sub.add_parser("simulate", help="generate sample data")
    ssub = s.add_subparsers(dest="what", required=True)
    sc = ssub.add_parser(
        "scene", help="the procedural sample site (stadium hall and surroundings) as GLB"
    )
    sc.add_argument("--out", required=True, type=Path)
    sc.add_argument("--seed", type=int, default=7)
    sc.set_defaults(job="simulate:scene")
    ss = ssub.add_parser(
        "session",
        help="the sample session: a phone filming the sample site while walking, with truth",
    )
    ss.add_argument("--out", required=True, type=Path)
    ss.add_argument(
        "--scene", type=Path, default=None, help="the site GLB (default: the bundled sample)"
    )
    ss.add_argument("--seed", type=int, default=2026)
    ss.add_argument("--duration", type=_number(1.0, 3600.0), default=80.0, help="seconds of video")
    ss.add_argument(
        "--model-world",
        action="store_true",
        help="render the video from the plain model itself (the old sample), not from a world that differs from it",
    )
    ss.set_defaults(job="simulate:session")
    sp = ssub.add_parser(
        "photo",
        help="the sample photo: the site seen from the sample pose, plus a banner, people, a car",
    )
    sp.add_argument("--scene", required=True, type=Path)
    sp.add_argument("--out", required=True, type=Path)
    sp.set_defaults(job="simulate:photo")

    d = sub.add_parser("demo", help="render the bundled sample to a PNG")
    d.add_argument("--out", type=Path, default=Path("out/demo.png"))
    d.set_defaults(job="demo")

    b = sub.add_parser("bench", help="benchmarks (results go to docs/PERFORMANCE.md)")
    b.add_argument("what", choices=sorted(BENCHMARKS))
    b.add_argument("rest", nargs=argparse.REMAINDER, help="the benchmark's own options")
    b.set_defaults(job="bench")
    return parser
