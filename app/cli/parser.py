"""`geofuse`'s commands and their options: argument parsing only, one small function per
command (the types and the option groups several share are app.cli.options). Each command
names its job ("module:function" in app.cli; function `run` by default), which app.cli.main
imports and calls.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli.options import (
    GEODETIC,
    MAX_IMAGE_SIDE,
    Parser,
    add_fov_option,
    add_gnss_accuracy_option,
    add_layer_options,
    add_lens_option,
    add_pitch_option,
    add_projection_options,
    add_radius,
    add_source_option,
    add_srt_option,
    add_start_options,
    add_still_options,
    count,
    floats,
    joined_negative_values,
    number,
    size,
    utc,
)
from app.core.constants import (
    DEFAULT_FAR_M,
    DEFAULT_START_RADIUS_M,
    DRONE_DEFAULT_PITCH_DEG,
    FOV_RANGE_DEG,
    KEYFRAMES_S,
    ORTHO_KEYFRAMES_S,
    SYNC_MIN_CONFIDENCE,
)
from app.export import EXPORT_SUFFIXES
from app.share.target import CotTarget, parse_target

__all__ = ["BENCHMARKS", "MAX_IMAGE_SIDE", "build_parser", "joined_negative_values"]

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
    "live": "bench_live.py",
    "ortho": "bench_ortho.py",
    "cot": "bench_cot.py",
    "map": "bench_web_map.py",
}
SOURCE_HELP = "attitude source (default: the first the session offers)"
SRT_HELP = "the DJI subtitle of the clip, when not beside it"
Commands = argparse._SubParsersAction  # what add_parser is called on


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="geofuse", description="Drape mobile video onto a georeferenced 3D model.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (
        _render, _locate, _index, _find, _view, _live, _serve, _solve, _export, _register, _sync,
        _telemetry, _simulate, _demo, _bench, _cache,
    ):  # fmt: skip
        command(sub)
    return parser


def _render(sub: Commands) -> None:
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
        type=number(-1e6, 1e6),
        default=None,
        help="with --session: seconds from the video's first frame",
    )
    add_source_option(r, "with --session: attitude source (default: the first the session offers)")
    add_still_options(r)
    r.add_argument(
        "--view-from",
        type=lambda s: floats(s, 3),
        metavar="E,N,U",
        default=None,
        help="window camera position, ENU metres (default: behind and above the image's camera)",
    )
    r.add_argument(
        "--look-at",
        type=lambda s: floats(s, 3),
        metavar="E,N,U",
        default=None,
        help="window camera target, ENU metres",
    )
    r.add_argument(
        "--view-fov",
        type=number(*FOV_RANGE_DEG),
        default=60.0,
        help="window camera horizontal field of view, degrees",
    )
    r.add_argument(
        "--size", type=size, default=(1280, 720), help="output WIDTHxHEIGHT (default 1280x720)"
    )
    r.add_argument(
        "--far",
        type=number(1.0, 1e7),
        default=DEFAULT_FAR_M,
        help="far plane of both cameras, metres",
    )
    add_projection_options(r)
    add_start_options(r)
    add_gnss_accuracy_option(r)
    r.add_argument("--out", required=True, type=Path, help="output PNG")
    r.set_defaults(job="render")


def _locate(sub: Commands) -> None:
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
        type=number(-1e6, 1e6),
        default=None,
        help="with a session or clip: seconds from the video's first frame",
    )
    lo.add_argument(
        "--pixel",
        type=lambda s: floats(s, 2),
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
    add_source_option(lo, SOURCE_HELP)
    add_srt_option(lo, "a DJI clip's subtitle, when not beside it")
    add_still_options(lo)
    lo.add_argument("--json", action="store_true", help="print a JSON array for scripts")
    lo.set_defaults(job="locate")


def _index(sub: Commands) -> None:
    ix = sub.add_parser(
        "index",
        help="index folders of clips into one GeoParquet archive of footprints, on Dask distributed",
    )
    ix.add_argument("folders", nargs="+", type=Path, help="folders (walked) or files of clips")
    ix.add_argument("--out", required=True, type=Path, help="the archive: ARCHIVE.parquet")
    ix.add_argument(
        "--every-s",
        type=number(0.01, 3600.0),
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
        "--buildings",
        action="append",
        default=None,
        metavar="FILE",
        help="buildings for every clip without its own scene: OpenStreetMap (.osm, .osm.pbf) or GeoParquet footprints extruded to LoD1, repeatable",
    )
    add_source_option(
        ix, "pose source for every clip (default: the first each offers)", filter_alias=False
    )
    where = ix.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=count(1, 1024),
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


def _find(sub: Commands) -> None:
    fi = sub.add_parser(
        "find", help="the clips of an archive that saw a place, and when (most head-on first)"
    )
    fi.add_argument("archive", type=Path, help="ARCHIVE.parquet written by `geofuse index`")
    place = fi.add_mutually_exclusive_group(required=True)
    place.add_argument(
        "--point",
        type=lambda s: floats(s, 2, GEODETIC[:2]),
        metavar="LAT,LON",
        help="a place: latitude, longitude (degrees)",
    )
    place.add_argument(
        "--polygon", type=Path, help="an area: a GeoJSON file of a Polygon (or a Feature of one)"
    )
    fi.add_argument(
        "--radius",
        type=number(0.0, 100_000.0),
        default=0.0,
        help="with --point: metres around it (default 0)",
    )
    fi.add_argument("--from", dest="start", type=utc, default=None, help="ISO 8601 time (UTC)")
    fi.add_argument("--to", dest="end", type=utc, default=None, help="ISO 8601 time (UTC)")
    fi.add_argument("--json", action="store_true", help="print the hits as a JSON array")
    fi.add_argument(
        "--open", action="store_true", help="open the viewer on the best clip at that time"
    )
    fi.set_defaults(job="find")


def _view(sub: Commands) -> None:
    v = sub.add_parser(
        "view", help="the interactive viewer (the bundled sample when no manifest is given)"
    )
    v.add_argument(
        "manifest",
        nargs="*",
        default=None,
        help="a session manifest, a GoPro MP4, a DJI clip or a drone's .ts (default: the bundled sample); several play together on one timeline, "
        "on the first one's scene; or a stream to receive live: udp://HOST:PORT, rtp://, rtsp://, srt:// (recorded under out/live/)",
    )
    add_srt_option(v, SRT_HELP)
    add_lens_option(v)
    add_layer_options(v)
    v.add_argument("--size", type=size, default=(1280, 720), help="window WIDTHxHEIGHT")
    v.add_argument(
        "--script", type=Path, default=None, help="a file of timed UI actions (app/ui/script.py)"
    )
    v.add_argument(
        "--screenshot",
        type=Path,
        default=None,
        help="save the window to this PNG (alone: after --play seconds and the world drawn in full, then exit)",
    )
    v.add_argument(
        "--play",
        type=number(0.0, 3600.0),
        default=2.0,
        help="with --screenshot alone: seconds to play first",
    )
    _stream_options(v)
    _cot_options(v)
    add_start_options(v)
    v.set_defaults(job="view")


def _stream_options(p: argparse.ArgumentParser) -> None:
    """What a stream needs beside its URL (geofuse live, and geofuse view URL)."""
    add_gnss_accuracy_option(p)
    p.add_argument(
        "--buffer-ms",
        type=number(0.0, 5000.0),
        default=100.0,
        help="a stream's jitter buffer, milliseconds (default 100)",
    )
    p.add_argument(
        "--origin",
        type=lambda s: floats(s, 3, GEODETIC),
        default=None,
        help="a stream's assumed ground: latitude, longitude (deg), ellipsoidal height (m) of its origin; "
        "a feed without any fix (MAVLink without a HOME_POSITION, KLV that never places the sensor) is searched for within --search-radius of it (its take-off point)",
    )
    add_radius(
        p,
        "--search-radius",
        DEFAULT_START_RADIUS_M,
        "a feed without any fix: how far around its home point (HOME_POSITION, else --origin) the camera is searched for first, metres (default 300; each search that misses doubles it, up to 1000)",
    )
    p.add_argument(
        "--mavlink",
        default=None,
        metavar="CONNECTION",
        help="pose a stream from MAVLink telemetry (ArduPilot, PX4) instead of KLV: udp:HOST:PORT listens, "
        "udpout:, tcp:HOST:PORT or a serial device as pymavlink opens them; its lag behind the video is estimated as it flies",
    )
    p.add_argument(
        "--fov",
        type=number(1.0, 179.0),
        default=None,
        help="a stream camera's horizontal field of view, degrees, where the feed does not say it (default: the KLV's, else 73.7)",
    )
    p.add_argument(
        "--no-register",
        dest="register",
        action="store_false",
        help="a stream over a textured scene: do not register keyframes against it (by default they are, in the background, the correction applied forward)",
    )


def _cot_url(text: str) -> CotTarget:
    """A --cot target (app.share.target), refused at once in one line saying what is expected."""
    try:
        return parse_target(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _cot_options(p: argparse.ArgumentParser) -> None:
    """Cursor on Target out (geofuse view and geofuse live; app.share.tak)."""
    p.add_argument(
        "--cot",
        type=_cot_url,
        action="append",
        default=[],
        metavar="URL",
        help="send the aircraft, its point of interest, the footprint and the marks as Cursor on Target to TAK: "
        "udp://239.2.3.1:6969 (ATAK's mesh on the LAN), udp://HOST:PORT, tcp://HOST:PORT, or tls://HOST:PORT "
        "(a TAK Server, with --cot-cert); may be given several times",
    )
    p.add_argument(
        "--cot-cert",
        type=Path,
        default=None,
        metavar="PATH",
        help="a tls:// target's client certificate: PEM (with --cot-key) or PKCS#12 (.p12, its key inside; "
        "the password from $GEOFUSE_COT_PASSWORD); or a [[tak]] table of the settings file",
    )
    p.add_argument("--cot-key", type=Path, default=None, metavar="PATH", help="its PEM key")
    p.add_argument(
        "--cot-ca",
        type=Path,
        default=None,
        metavar="PATH",
        help="the TAK Server's certificate authority: PEM or a PKCS#12 truststore (default: the system's)",
    )
    p.add_argument(
        "--cot-callsign",
        default="geofuse",
        metavar="NAME",
        help="the aircraft's name on the TAK map (default geofuse)",
    )


def _live(sub: Commands) -> None:
    li = sub.add_parser(
        "live",
        help="receive a live feed (MPEG-TS with MISB KLV) and drape it off screen: the viewer's pipeline without a window",
    )
    li.add_argument(
        "url",
        help="the stream: udp://HOST:PORT (unicast or multicast MPEG-TS), rtp://, rtsp://, srt:// where this FFmpeg has it",
    )
    li.add_argument(
        "--record", type=Path, default=None, help="keep what arrives as MPEG-TS (a .ts file)"
    )
    li.add_argument(
        "--for",
        dest="seconds",
        type=number(0.1, 86400.0),
        default=None,
        help="stop after this many seconds (default: when the stream has been silent for 10 s)",
    )
    li.add_argument("--size", type=size, default=(1280, 720), help="the drawing's WIDTHxHEIGHT")
    li.add_argument(
        "--restream",
        default=None,
        metavar="udp://HOST:PORT",
        help="send the video on (copied) as MPEG-TS with MISB ST 0601 KLV carrying the pose each frame was drawn with: "
        "the registered one where live registration corrected it (item 98 says so), the platform's otherwise",
    )
    _stream_options(li)
    add_layer_options(li)
    _cot_options(li)
    li.set_defaults(job="live")


def _serve(sub: Commands) -> None:
    se = sub.add_parser(
        "serve",
        help="a browser map of a clip played in real time, or of a live feed: the aircraft, its track, the footprint, the frame and the marks (no window)",
    )
    se.add_argument(
        "input",
        help="a session manifest or a clip (played in real time from its solved track, again and again unless --once), "
        "or a stream to receive: udp://HOST:PORT, rtp://, rtsp://, srt://",
    )
    se.add_argument(
        "--bind",
        default="127.0.0.1:0",
        metavar="HOST:PORT",
        help="where the map listens (default 127.0.0.1:0: this machine only, a free port); 0.0.0.0:PORT for every network, said as a warning",
    )
    se.add_argument(
        "--token",
        default=None,
        help="the access token every request must carry (default: a random one; 8 to 128 of A-Z a-z 0-9 . _ ~ -)",
    )
    se.add_argument("--once", action="store_true", help="a clip: play it once, then stop")
    se.add_argument(
        "--for",
        dest="seconds",
        type=number(0.1, 86400.0 * 30),
        default=None,
        help="stop after this many seconds (default: until Ctrl-C, or the end of --once)",
    )
    add_source_option(se, SOURCE_HELP)
    add_srt_option(se, SRT_HELP)
    add_lens_option(se)
    _stream_options(se)
    add_layer_options(se)
    se.set_defaults(job="serve")


def _solve(sub: Commands) -> None:
    so = sub.add_parser(
        "solve", help="a camera pose for every video frame of a session or clip, as CSV"
    )
    so.add_argument(
        "manifest",
        type=Path,
        help="a session manifest (.toml), a GoPro MP4, or a DJI clip (its .SRT beside it)",
    )
    add_source_option(
        so,
        "attitude source: gd-ahrs | gd-imu | cf-ahrs | cf-imu | offline | phone | camera | telemetry | course | truth (default: the first the session offers)",
    )
    add_srt_option(so, SRT_HELP)
    add_lens_option(so)
    add_layer_options(so)
    add_fov_option(so)
    add_pitch_option(
        so,
        f"a drone clip without gimbal attitude: the camera's pitch, degrees (default {DRONE_DEFAULT_PITCH_DEG:g})",
    )
    add_start_options(so)
    add_gnss_accuracy_option(so)
    so.add_argument("--out", type=Path, required=True)
    so.set_defaults(job="solve")


def _export(sub: Commands) -> None:
    ex = sub.add_parser(
        "export",
        help="footprints (GeoJSON/KML/KMZ), an FMV metadata CSV, MISB KLV in MPEG-TS, the fused view as a video, a true orthophoto (COG) or the scene painted by the clip (GLB)",
    )
    ex.add_argument(
        "what",
        choices=sorted(EXPORT_SUFFIXES),
        help="footprints: .geojson/.kml/.kmz; fmv-csv: .csv; klv: .ts; video: .mp4; ortho: .tif (and .seen.tif beside it); model: .glb, or tileset.json (3D Tiles, its tiles beside it)",
    )
    ex.add_argument(
        "input",
        type=Path,
        nargs="+",
        help="a session manifest, a GoPro MP4 or a DJI clip; footprints: several, each footprint with its clip",
    )
    ex.add_argument("--out", type=Path, required=True)
    add_source_option(ex, SOURCE_HELP)
    add_start_options(ex)
    add_gnss_accuracy_option(ex)
    ex.add_argument(
        "--every",
        type=count(1, 1_000_000),
        default=1,
        help="footprints, CSV, KLV: every Nth frame (1: every frame)",
    )
    ex.add_argument(
        "--from",
        dest="start",
        type=number(0.0, 1e7),
        default=None,
        help="video: first second (media time)",
    )
    ex.add_argument(
        "--to",
        dest="end",
        type=number(0.0, 1e7),
        default=None,
        help="video: last second (media time)",
    )
    ex.add_argument("--size", type=size, default=(1280, 720), help="video: WIDTHxHEIGHT")
    ex.add_argument(
        "--gsd",
        type=number(0.01, 100.0),
        default=None,
        help="ortho: metres a cell (default: the video's ground sampling, rounded up to 5 cm)",
    )
    ex.add_argument(
        "--crs",
        default=None,
        help="ortho: a projected CRS, e.g. EPSG:25832 (default: the site's UTM zone)",
    )
    ex.add_argument(
        "--area",
        type=Path,
        default=None,
        metavar="GEOJSON",
        help="ortho: the area, a GeoJSON polygon's box (default: what the frames see)",
    )
    ex.add_argument(
        "--rule",
        choices=("newest", "best", "first"),
        default="newest",
        help="ortho, model: what a cell or texel keeps: the newest frame that saw it, the best (range, incidence) or the first",
    )
    ex.add_argument(
        "--every-s",
        type=number(0.0, 3600.0),
        default=0.2,
        help="ortho, model: seconds of video between frames painted (0: every frame)",
    )
    ex.add_argument(
        "--keyframes-s",
        type=number(0.05, 60.0),
        default=None,
        help=f"ortho, model: with --source registered, seconds of video between keyframes registered (default {ORTHO_KEYFRAMES_S:g} for ortho, {KEYFRAMES_S:g} for model)",
    )
    ex.add_argument(
        "--max-texels",
        type=count(1000, 256_000_000),
        default=None,
        help="model: one atlas of at most this many texels (the texel size follows; memory ~32 bytes a texel) "
        "instead of pages at the video's ground sampling",
    )
    ex.add_argument(
        "--finest-m",
        type=number(0.001, 100.0),
        default=0.02,
        help="model: no texel finer than this (m) where the video sees a surface from near",
    )
    ex.add_argument(
        "--memory-mb",
        type=number(16.0, 1_000_000.0),
        default=256.0,
        help="model: the pages held at once (MB); past it the least recently used go to disk",
    )
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
    add_srt_option(ex, SRT_HELP)
    add_lens_option(ex)
    add_layer_options(ex)
    add_fov_option(ex)
    add_pitch_option(ex, "a drone clip without gimbal attitude: the camera's pitch, degrees")
    ex.set_defaults(job="export")


def _register(sub: Commands) -> None:
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
    add_source_option(
        rg,
        "the pose source to correct (default: offline, else the first the session offers)",
        filter_alias=False,
    )
    rg.add_argument(
        "--write",
        action="store_true",
        help="keep the points in NAME.control.csv beside the input (never in an input); the registered source then starts from their correction",
    )
    add_lens_option(rg, "a gyroflow lens profile (JSON) for a clip")
    rg.set_defaults(job="register")


def _sync(sub: Commands) -> None:
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
    add_lens_option(sy, "a gyroflow lens profile (JSON) for a clip")
    sy.set_defaults(job="sync")


def _telemetry(sub: Commands) -> None:
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


def _cache(sub: Commands) -> None:
    ca = sub.add_parser(
        "cache",
        help="the tile cache of worlds (app.world): list it, clear it, or pre-fetch a clip's or an area's tiles for offline use",
    )
    ca.add_argument(
        "clips",
        nargs="*",
        type=Path,
        metavar="CLIP",
        help="pre-fetch what these clips' scenes need",
    )
    ca.add_argument(
        "--bbox",
        type=lambda s: floats(
            s, 4, ((-180, 180, "W"), (-90, 90, "S"), (-180, 180, "E"), (-90, 90, "N"))
        ),
        default=None,
        metavar="W,S,E,N",
        help="pre-fetch this area (degrees) instead",
    )
    ca.add_argument(
        "--gsd",
        type=number(0.05, 1000.0),
        default=0.5,
        metavar="M",
        help="--bbox: the imagery's ground sampling, metres a pixel (terrain 4 times coarser; default 0.5)",
    )
    ca.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="AREA.mbtiles",
        help="also write the tiles into archives that --imagery/--terrain open offline: imagery here, terrain beside it (AREA-terrain...); .gpkg for tiles not in Web Mercator",
    )
    ca.add_argument(
        "--clear",
        nargs="?",
        const="",
        default=None,
        metavar="SOURCE",
        help="remove what the cache holds (of the sources whose location holds SOURCE, or of the [[world]] SOURCE)",
    )
    ca.add_argument(
        "--providers",
        nargs="?",
        const="",
        default=None,
        metavar="TEXT",
        help="list the providers --imagery/--terrain and [[world]] tables may name (those whose name holds TEXT): levels, key, attribution, and whether their terms forbid bulk download",
    )
    ca.add_argument(
        "--world",
        default=None,
        metavar="NAME",
        help="the [[world]] to pre-fetch (default: the settings' first)",
    )
    ca.add_argument(
        "--imagery", default=None, metavar="SRC", help="imagery to pre-fetch (as for view)"
    )
    ca.add_argument(
        "--terrain", default=None, metavar="SRC", help="terrain to pre-fetch (as for view)"
    )
    ca.add_argument(
        "--buildings",
        default=None,
        metavar="overpass:[URL]",
        help="OpenStreetMap buildings to pre-fetch from an Overpass API (as for view; --out: AREA-buildings.osm beside)",
    )
    ca.set_defaults(job="cache")


def _simulate(sub: Commands) -> None:
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
        help="the sample session: a phone filming the sample site while walking (or a drone's survey or orbit, --flight), with truth",
    )
    ss.add_argument("--out", required=True, type=Path)
    ss.add_argument(
        "--scene", type=Path, default=None, help="the site GLB (default: the bundled sample)"
    )
    ss.add_argument("--seed", type=int, default=2026)
    ss.add_argument(
        "--flight",
        choices=("walk", "survey", "orbit"),
        default="walk",
        help="walk: a phone carried past the hall (the bundled sample); survey: a drone's lawn-mower lines at 70 m, camera looking down; orbit: a drone circling the hall at 60 m, camera on it",
    )
    ss.add_argument("--duration", type=number(1.0, 3600.0), default=80.0, help="seconds of video")
    ss.add_argument(
        "--model-world",
        action="store_true",
        help="render the video from the plain model itself (the old sample), not from a world that differs from it",
    )
    ss.add_argument(
        "--city",
        action="store_true",
        help="the session's scene is the site as a city publishes it: an untextured LoD2 CityJSON (site.city.json, written beside it; the video as without), registered by its geometry",
    )
    ss.set_defaults(job="simulate:session")
    sy = ssub.add_parser(
        "city",
        help="the sample site's buildings as an untextured LoD2 city model (UTM + EGM2008), as a city publishes them",
    )
    sy.add_argument(
        "--out",
        required=True,
        type=Path,
        help="the file: .city.json or .city.jsonl (CityJSON 2.0), .gml (CityGML 2.0)",
    )
    sy.set_defaults(job="simulate:city")
    sp = ssub.add_parser(
        "photo",
        help="the sample photo: the site seen from the sample pose, plus a banner, people, a car",
    )
    sp.add_argument("--scene", required=True, type=Path)
    sp.add_argument("--out", required=True, type=Path)
    sp.set_defaults(job="simulate:photo")
    sf = ssub.add_parser(
        "feed",
        help="a drone's downlink: an orbiting aircraft's H.264 MPEG-TS with MISB ST 0601 KLV, written and optionally sent over UDP in real time",
    )
    sf.add_argument("--out", required=True, type=Path, help="the .ts to write")
    sf.add_argument("--seconds", type=number(1.0, 3600.0), default=20.0)
    sf.add_argument("--size", type=size, default=(1280, 720), help="WIDTHxHEIGHT")
    sf.add_argument(
        "--klv-hz",
        type=number(0.1, 240.0),
        default=None,
        help="KLV at its own rate (default: a set per frame, synchronous)",
    )
    sf.add_argument(
        "--send",
        default=None,
        metavar="HOST:PORT",
        help="then send it over UDP in real time (1316-byte datagrams, paced by its clock)",
    )
    sf.add_argument(
        "--loss",
        type=number(0.0, 0.9),
        default=0.0,
        help="with --send: the fraction of datagrams dropped (a lossy link)",
    )
    sf.add_argument(
        "--mavlink",
        default=None,
        metavar="HOST:PORT",
        help="an autopilot's drone instead (ArduPilot, PX4): the sample site seen from a weaving flight, video without KLV; "
        "with --send, its MAVLink telemetry (GLOBAL_POSITION_INT, ATTITUDE, GIMBAL_DEVICE_ATTITUDE_STATUS) sent here beside it, 0.3 s ahead",
    )
    sf.add_argument(
        "--no-fix",
        action="store_true",
        help="with --mavlink: the autopilot has no GNSS fix (GLOBAL_POSITION_INT at 0, 0 with the barometer's height) and sends its HOME_POSITION: "
        "`geofuse live --mavlink ... --scene ...` searches the scene around the home point",
    )
    sf.set_defaults(job="simulate:feed")


def _demo(sub: Commands) -> None:
    d = sub.add_parser("demo", help="render the bundled sample to a PNG")
    d.add_argument("--out", type=Path, default=Path("out/demo.png"))
    d.set_defaults(job="demo")


def _bench(sub: Commands) -> None:
    b = sub.add_parser("bench", help="benchmarks (results go to docs/PERFORMANCE.md)")
    b.add_argument("what", choices=sorted(BENCHMARKS))
    b.add_argument("rest", nargs=argparse.REMAINDER, help="the benchmark's own options")
    b.set_defaults(job="bench")
