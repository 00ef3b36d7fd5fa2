"""`geofuse` command line: argument parsing only; the work happens in the modules it calls.

Every GeofuseError (bad file, bad value) is printed as one line naming the file and field, and
the command exits with status 2; no traceback.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from app.constants import (
    DEFAULT_DEPTH_BIAS_M,
    DEFAULT_DEPTH_LONG_SIDE_PX,
    DEFAULT_DEPTH_SLOPE_BIAS,
    DEFAULT_FAR_M,
    DEFAULT_NEAR_M,
    DRONE_DEFAULT_PITCH_DEG,
    FOV_RANGE_DEG,
    SYNC_MIN_CONFIDENCE,
)
from app.errors import GeofuseError
from app.export import EXPORT_SUFFIXES
from app.outputs import CSV_SUFFIXES, IMAGE_SUFFIXES, check_output

MAX_IMAGE_SIDE = 8192  # pixels: what every OpenGL 4 renderbuffer (and llvmpipe) can hold
COMMA_OPTIONS = ("--origin", "--pose", "--view-from", "--look-at")  # values that may start with '-'
GEODETIC = (
    (-90.0, 90.0, "latitude"),
    (-180.0, 360.0, "longitude"),
    (-12_000.0, 100_000.0, "height"),
)
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


def _joined_negative_values(argv: Sequence[str]) -> list[str]:
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
        type=int,
        default=DEFAULT_DEPTH_LONG_SIDE_PX,
        help="depth-map texels on the video's long side",
    )
    p.add_argument(
        "--no-neighbourhood",
        action="store_true",
        help="test only the fragment's own depth texel (not the nine-case rule)",
    )
    p.add_argument(
        "--no-frustum", action="store_true", help="do not draw the depth camera's frustum"
    )


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


def _layers(args: argparse.Namespace, placement=None) -> tuple:
    """The layers --scene/--dem/--ortho name (app.scene.layers), checked: files exist, kinds known."""
    from app.scene.layers import Layer
    from app.scene.tiles.fetch import is_url

    names = list(getattr(args, "scene", None) or [])
    if getattr(args, "dem", None) is not None:
        names.append(str(args.dem))
    out = []
    for name in names:
        if not is_url(name) and not Path(name).exists():
            raise GeofuseError(f"{name}: scene file does not exist")
        layer = Layer.of(name)
        if layer.kind == "dem":
            layer = Layer.of(
                name, ortho=args.ortho, vertical=args.dem_vertical, max_error_m=args.dem_error
            )
        elif layer.kind == "mesh" and placement is not None:
            layer = Layer.of(name, placement=placement)
        out.append(layer)
    if args.ortho is not None:
        if not any(layer.kind == "dem" for layer in out):
            raise GeofuseError("--ortho drapes a DEM: give --dem DEM.tif (or --scene DEM.tif) too")
        if not args.ortho.is_file():
            raise GeofuseError(f"{args.ortho}: orthophoto file does not exist")
    return tuple(out)


def _projection_settings(args: argparse.Namespace):  # values range-checked by ProjectionSettings
    from app.config import ProjectionSettings

    try:
        return ProjectionSettings(
            alpha=args.alpha,
            bias_constant_m=args.bias,
            bias_slope=args.slope_bias,
            neighbourhood=not args.no_neighbourhood,
            depth_long_side=args.depth_size,
        )
    except ValueError as exc:
        raise GeofuseError(f"projection settings: {exc}") from exc


def cmd_render(args: argparse.Namespace) -> int:
    if args.session is not None:
        return _render_session(args)
    from app.scene import Placement

    layers = _layers(
        args, Placement(up_axis=args.up, heading_deg=args.scene_heading, scale=args.scene_scale)
    )
    missing = [f"--{k.replace('_', '-')}" for k in ("image", "pose") if getattr(args, k) is None]
    if not layers:
        missing.insert(0, "--scene (or --dem)")
    if args.origin is None and any(not layer.georeferenced for layer in layers):
        missing.append("--origin (a model's origin)")
    if args.fov is None and args.lens is None:
        missing.append("--fov (or --lens)")
    if missing:
        raise GeofuseError(
            f"render: give --session MANIFEST --time T, or all of {', '.join(missing)}"
        )
    check_output(
        args.out,
        "--out",
        IMAGE_SUFFIXES,
        [*(f for layer in layers for f in layer.files()), args.image, args.lens],
    )
    from app import rotations
    from app.camera import Camera, Intrinsics
    from app.config import OverlaySettings
    from app.geo import LocalFrame
    from app.imageio import read_rgb, write_rgb
    from app.render.still import render_still, window_camera
    from app.scene.layers import load_layers

    lat, lon, h, heading, pitch, roll = args.pose
    frame = LocalFrame(*(args.origin or (lat, lon, h)))
    loaded = load_layers(layers, frame, [[lat, lon]])
    for message in loaded.notes.since(0):
        print(message, file=sys.stderr)
    mesh = loaded.mesh
    image = read_rgb(args.image)
    lens = None
    try:
        if args.lens is not None:
            from app.lens import enclosing_intrinsics, read_profile

            lens = read_profile(args.lens).scaled(image.shape[1], image.shape[0])
            intr = enclosing_intrinsics(lens)
        else:
            intr = Intrinsics.from_fov(image.shape[1], image.shape[0], args.fov)
        view_intr = Intrinsics.from_fov(args.size[0], args.size[1], args.view_fov)
    except ValueError as exc:
        raise GeofuseError(f"--fov: {exc}") from exc
    projector = Camera.create(
        intr,
        frame.geodetic_to_enu(lat, lon, h),
        rotations.camera_quat_from_hpr(heading, pitch, roll),
        near=DEFAULT_NEAR_M,
        far=args.far,
        lens=lens,
    )
    view = window_camera(projector, view_intr, args.view_from, args.look_at, args.far)
    rgb = render_still(
        mesh,
        image,
        projector,
        view,
        _projection_settings(args),
        OverlaySettings(frustum=not args.no_frustum, trajectory=False),
    )
    out = write_rgb(args.out, rgb)
    print(f"wrote {out} ({rgb.shape[1]}x{rgb.shape[0]})")
    return 0


def _render_session(args: argparse.Namespace) -> int:

    from app.camera import Intrinsics
    from app.config import OverlaySettings
    from app.frame_time import frame_at
    from app.imageio import write_rgb
    from app.io.video import read_frame
    from app.render.still import render_still, window_camera

    if args.time is None:
        raise GeofuseError("render --session needs --time T (seconds from the video's first frame)")
    check_output(args.out, "--out", IMAGE_SUFFIXES, [args.session, args.lens])
    session, source = _open_with_source(args.session, args, IMAGE_SUFFIXES)
    pts = session.video.pts_s
    if not pts[0] - 0.5 <= args.time <= pts[-1] + 0.5:
        raise GeofuseError(
            f"--time {args.time:g}: the video runs from {pts[0]:.3f} to {pts[-1]:.3f} s"
        )
    _print_messages(session)
    index = frame_at(pts, args.time)
    try:
        track = _solved(session, source).with_clip(DEFAULT_NEAR_M, args.far)
    except ValueError as exc:
        raise GeofuseError(f"--source: {exc}") from exc
    projector = track.frame_camera(index)
    image = read_frame(session.video.path, index, session.video)
    view = window_camera(
        projector,
        Intrinsics.from_fov(args.size[0], args.size[1], args.view_fov),
        args.view_from,
        args.look_at,
        args.far,
    )
    rgb = render_still(
        session.scene(),
        image,
        projector,
        view,
        _projection_settings(args),
        OverlaySettings(frustum=not args.no_frustum),
        trajectory=track.frame_poses().enu,
    )
    out = write_rgb(args.out, rgb)
    print(f"wrote {out}: frame {index} at {pts[index]:.3f} s, attitude from {source}")
    return 0


def _solved(session, source: str):
    """The session's camera track under `source` (a progress bar on stderr while registering),
    printing the registration's summary line."""
    from app.progress import ProgressBar
    from app.solve import solve_track

    track = solve_track(
        session,
        source,
        progress=ProgressBar(f"registering ({source})", sys.stderr),
    )
    if track.registration is not None:
        print(track.registration.summary(), file=sys.stderr)
    _print_messages(session)
    return track


def _open_with_source(path: Path, args: argparse.Namespace, suffixes: tuple[str, ...]):
    """(session, source) for a command that writes --out: the session or clip opened, --out
    checked against every file it reads, --source checked against what it offers."""
    from app.clips import open_any

    session = open_any(
        path,
        getattr(args, "srt", None),
        getattr(args, "fov", None),
        getattr(args, "pitch", DRONE_DEFAULT_PITCH_DEG),
        args.lens,
        _layers(args),
    )
    check_output(args.out, "--out", suffixes, list(session.inputs))
    source = args.source or session.sources[0]
    if source not in session.sources:
        raise GeofuseError(f"--source {source}: this session offers {', '.join(session.sources)}")
    return session, source


_PRINTED: dict[int, int] = {}  # id of a session's messages -> how many this command has printed


def _print_messages(session) -> None:
    """The session's messages this command has not printed yet, each with its level ("note:" for
    information, "warning:", "error:"): called when a session opens and again after work that
    may add some (solving, registering, exporting)."""
    key = id(session.messages)
    new = session.messages.since(_PRINTED.get(key, 0))
    for message in new:
        print(message, file=sys.stderr)
    _PRINTED[key] = _PRINTED.get(key, 0) + len(new)


def cmd_solve(args: argparse.Namespace) -> int:
    from app.solve import solve_to_csv

    check_output(args.out, "--out", CSV_SUFFIXES, [args.manifest, args.srt])
    session, source = _open_with_source(args.manifest, args, CSV_SUFFIXES)
    _print_messages(session)
    rows = solve_to_csv(session, source, args.out, progress=sys.stderr)
    _print_messages(session)
    print(f"wrote {args.out}: {rows} frames, attitude from {source}")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    import logging

    from app.ui.script import parse_script
    from app.ui.viewer import Options, Viewer

    if args.script is not None:
        parse_script(args.script)  # a bad script is refused before a window opens
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    return Viewer(
        Options(
            args.manifest,
            args.size,
            args.script,
            args.screenshot,
            args.play,
            srt=args.srt,
            lens=args.lens,
            layers=_layers(args),
        )
    ).run()


def cmd_export(args: argparse.Namespace) -> int:
    """footprints / fmv-csv / klv / video of a session or clip (app/export)."""

    from app.export.gis import write_records
    from app.export.records import frame_records
    from app.frame_time import frame_at
    from app.outputs import write_atomically, write_via_path
    from app.progress import ProgressBar

    suffixes = EXPORT_SUFFIXES[args.what]
    check_output(args.out, "--out", suffixes, [args.input, args.srt])
    if args.preview is not None:
        check_output(args.preview, "--preview", IMAGE_SUFFIXES, [args.input, args.srt, args.out])
    session, source = _open_with_source(args.input, args, suffixes)
    _print_messages(session)
    track = _solved(session, source)
    bar = ProgressBar(f"export {args.what}", sys.stderr)
    out = Path(args.out)
    if args.what == "video":
        from app.export.video import export_video

        pts = session.video.pts_s
        first = frame_at(pts, args.start) if args.start is not None else 0
        last = frame_at(pts, args.end) if args.end is not None else len(pts) - 1
        if not 0 <= first <= last < len(pts):
            raise GeofuseError(
                f"--from/--to: no frame between {args.start} and {args.end} s (the video runs 0 to {pts[-1]:.3f} s)"
            )
        n = [0]
        write_via_path(
            out,
            "--out",
            lambda tmp: n.__setitem__(
                0,
                export_video(
                    session.video,
                    session.rotation_cw,
                    track,
                    session.scene(),
                    tmp,
                    args.size,
                    args.view,
                    first,
                    last,
                    bar,
                ),
            ),
        )
        print(
            f"wrote {out}: {n[0]} frames, {args.size[0]}x{args.size[1]}, view {args.view}, attitude from {source}"
        )
        return 0
    records = list(frame_records(session, source, args.every, progress=bar, track=track))
    if args.what == "klv":
        from app.export.klv import write_klv_ts

        n = [0]
        write_via_path(
            out, "--out", lambda tmp: n.__setitem__(0, write_klv_ts(session.video, records, tmp))
        )
        print(f"wrote {out}: the video with {n[0]} MISB ST 0601 local sets, attitude from {source}")
        return 0
    binary = out.suffix.lower() == ".kmz"
    write_atomically(
        out,
        "--out",
        lambda f: write_records(records, f, out.suffix.lower(), Path(args.input).stem),
        binary=binary,
    )
    if args.preview is not None:
        from app.export.preview import footprint_preview
        from app.imageio import write_rgb

        write_rgb(
            args.preview,
            footprint_preview(session.scene(), session.frame, records, args.size),
            "--preview",
        )
    clipped = sum(r.clipped for r in records)
    print(
        f"wrote {out}: {len(records)} frames, attitude from {source}"
        + (f"; {clipped} footprints clipped at the range limit" if clipped else "")
    )
    return 0


def cmd_sync(args: argparse.Namespace) -> int:
    """The video <-> gyroscope time offset of a session or clip (app/sync/)."""
    from app.clips import open_any
    from app.outputs import write_atomically
    from app.progress import ProgressBar
    from app.sync import settings_path, settings_text, sync_session, timed_by

    base = 0.0
    if (
        Path(args.input).suffix.lower() == ".toml"
    ):  # the manifest's own timing, never an "auto" offset
        from app.session import assemble, read_config

        cfg = read_config(args.input)
        base = cfg.video.time_offset_s
        session = assemble(cfg)
    else:
        session = open_any(args.input, lens=args.lens)
    _print_messages(session)
    result = sync_session(session, ProgressBar("optical flow", sys.stderr))
    ms = 1000 * result.offset_s
    print(
        f"{args.input}: the video's times need {ms:+.1f} ms (confidence {result.confidence:.3f}; coarse {1000 * result.coarse_s:+.0f} ms), timed by {timed_by(session)}"
    )
    if result.drift_ppm:
        print(
            f"clock drift: the video's clock runs {result.drift_ppm:+.0f} ppm against the sensors' ({result.drift_ppm * 1e-6 * 60 * 1000:+.1f} ms a minute); the offset holds at {result.reference_s - float(session.frame_times[0]):.1f} s"
        )
    print(
        f"fitted on {len(result.windows)} windows of {result.windows[0][1] - result.windows[0][0]:.1f} s that say most about time (where the rates change fastest)"
        if result.windows
        else "no window with rotation"
    )
    if args.write and result.confidence < SYNC_MIN_CONFIDENCE and not args.force:
        print(
            f"not written: confidence {result.confidence:.3f} is below {SYNC_MIN_CONFIDENCE} (the video's rotation hardly "
            "follows the reference: stabilised video, too little turning, or the wrong clip); --force keeps it anyway",
            file=sys.stderr,
        )
        return 1
    if args.write:
        out = check_output(
            settings_path(Path(args.input)), "--write", (".toml",), list(session.inputs)
        )
        write_atomically(
            out, "--write", lambda f: f.write(settings_text(result, base + result.offset_s))
        )
        print(f'wrote {out}: a manifest with video.time_offset_s = "auto" reads it')
    return 0


def cmd_register(args: argparse.Namespace) -> int:
    """Control points by hand: the clip's boresight and position correction (app/register/points.py)."""
    from app.clips import open_any
    from app.register.points import control_path, read_points, solve_control, write_points
    from app.register.solve import default_prior
    from app.solve import solve_track

    points = read_points(args.points)
    session = open_any(args.input, lens=args.lens)
    _print_messages(session)
    source = args.source or default_prior(session)
    try:
        session.check_source(source)
    except ValueError as exc:
        raise GeofuseError(f"--source: {exc}") from exc
    solution = solve_control(solve_track(session, source), points)
    print(f"{args.input}: {len(points)} control points against {source}")
    print(solution.report())
    if args.write:
        out = check_output(
            control_path(Path(args.input)),
            "--write",
            (".csv",),
            list(session.inputs) + [args.points],
        )
        write_points(out, points)
        print(f"wrote {out}: the registered source starts from this correction")
    return 0


def cmd_telemetry(args: argparse.Namespace) -> int:
    from app.telemetry import describe, inspect, write_csv

    if args.csv is not None:
        check_output(args.csv, "--csv", CSV_SUFFIXES, [args.file])
    tel = inspect(args.file)
    print(describe(tel))
    if args.csv is not None:
        print(f"wrote {args.csv}: {write_csv(tel, args.csv)} positions")
    return 0


def cmd_simulate_scene(args: argparse.Namespace) -> int:
    from app.simulate.stadium import write_site

    out = write_site(args.out, seed=args.seed)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return 0


def cmd_simulate_photo(args: argparse.Namespace) -> int:
    from app.demo import SAMPLE_ORIGIN, SAMPLE_PHOTO_POSE
    from app.geo import LocalFrame
    from app.imageio import write_rgb
    from app.scene import load_scene
    from app.simulate.photo import make_photo, photo_camera

    frame = LocalFrame(*SAMPLE_ORIGIN)
    mesh = load_scene(args.scene, frame)
    out = write_rgb(args.out, make_photo(mesh, photo_camera(SAMPLE_PHOTO_POSE, frame)))
    print(f"wrote {out}")
    return 0


def cmd_simulate_session(args: argparse.Namespace) -> int:
    from app.demo import SAMPLE_SCENE
    from app.simulate.session import SampleConfig, write_sample_session

    scene = args.scene or SAMPLE_SCENE
    if not Path(scene).is_file():
        raise GeofuseError(
            f"{scene}: scene file does not exist (make one with `geofuse simulate scene`)"
        )
    manifest = write_sample_session(
        args.out,
        scene,
        SampleConfig(seed=args.seed, duration_s=args.duration, world=not args.model_world),
    )
    total = sum(p.stat().st_size for p in Path(args.out).iterdir() if p.is_file())
    print(f"wrote {manifest} ({total / 1e6:.1f} MB in {args.out})")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Without a display: a still of the sample session as the viewer opens it (the walk's video
    draped on the model at 20 s, seen from above the site)."""
    from app.demo import SAMPLE_DIR

    argv = [
        "render",
        "--session", str(SAMPLE_DIR / "session.toml"),
        "--time", str(DEMO_TIME_S),
        "--view-from", "35,-160,40",
        "--look-at", "0,-20,8",
        "--alpha", "0.85",
        "--out", str(args.out),
    ]  # fmt: skip
    code = main(argv)
    if code == 0:
        print(
            f"The demo still is at {Path(args.out).resolve()}; with a display, `geofuse view` opens the interactive viewer."
        )
    return code


DEMO_TIME_S = 20.0  # the demo still's moment of the sample walk (the hall's front in view)


BENCHMARKS = {
    "render": "bench_render.py",
    "attitude": "bench_attitude.py",
    "accuracy": "bench_accuracy.py",
    "playback": "bench_playback.py",
    "lens": "bench_lens.py",
    "sync": "bench_sync.py",
    "registration": "bench_registration.py",
}


def cmd_bench(args: argparse.Namespace) -> int:
    import runpy

    from app.demo import ROOT

    script = ROOT / "bench" / BENCHMARKS[args.what]
    if not script.is_file():
        raise GeofuseError(
            f"{script}: benchmark script not found (benchmarks run from a source checkout)"
        )
    return int(runpy.run_path(str(script))["main"](args.rest))


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors (`geofuse: error: ...`, exit status 2)."""

    def error(self, message: str):
        self.exit(
            2,
            f"geofuse: error: {self.prog.split(' ', 1)[-1]}: {message}\n"
            if " " in self.prog
            else f"geofuse: error: {message}\n",
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
        default=None,
        help="a session manifest: the frame at --time with its solved pose",
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
    _add_layer_options(r, placed_models=True)
    r.add_argument(
        "--origin",
        type=lambda s: _floats(s, 3, GEODETIC),
        metavar="LAT,LON,H",
        help="the scene's origin: degrees, degrees, ellipsoidal metres",
    )
    r.add_argument(
        "--up",
        choices=["Y", "Z"],
        default=None,
        help="the scene's up axis (default: Y for glTF, Z otherwise)",
    )
    r.add_argument(
        "--scene-heading",
        type=_number(-360.0, 360.0),
        default=0.0,
        help="rotate the scene clockwise about Up, degrees",
    )
    r.add_argument(
        "--scene-scale",
        type=_number(0.0, 1e6, open_low=True),
        default=1.0,
        help="scene units -> metres",
    )
    r.add_argument("--image", type=Path, help="the image (video frame) to project: PNG or JPEG")
    r.add_argument(
        "--pose",
        type=lambda s: _floats(s, 6, GEODETIC + ATTITUDE),
        metavar="LAT,LON,H,HEADING,PITCH,ROLL",
        help="the image's camera: position (deg, deg, ellipsoidal m) and optical-axis heading (deg from true north, clockwise), pitch (deg above horizon), roll (deg)",
    )
    r.add_argument(
        "--fov",
        type=_number(*FOV_RANGE_DEG),
        help="the image's horizontal field of view, degrees",
    )
    r.add_argument(
        "--lens",
        type=Path,
        default=None,
        help="a gyroflow lens profile (JSON) of the image's camera, instead of --fov; with --session, of a clip",
    )
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
    r.set_defaults(func=cmd_render)

    v = sub.add_parser(
        "view", help="the interactive viewer (the bundled sample when no manifest is given)"
    )
    v.add_argument(
        "manifest",
        nargs="?",
        type=Path,
        default=None,
        help="a session manifest, a GoPro MP4 or a DJI clip (default: the bundled sample)",
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
    v.set_defaults(func=cmd_view)

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
    so.set_defaults(func=cmd_solve)

    ex = sub.add_parser(
        "export",
        help="footprints (GeoJSON/KML/KMZ), an FMV metadata CSV, MISB KLV in MPEG-TS, or the fused view as a video",
    )
    ex.add_argument(
        "what",
        choices=sorted(EXPORT_SUFFIXES),
        help="footprints: .geojson/.kml/.kmz; fmv-csv: .csv; klv: .ts; video: .mp4",
    )
    ex.add_argument("input", type=Path, help="a session manifest, a GoPro MP4 or a DJI clip")
    ex.add_argument("--out", type=Path, required=True)
    ex.add_argument(
        "--source",
        "--filter",
        dest="source",
        default=None,
        help="attitude source (default: the first the session offers)",
    )
    ex.add_argument("--every", type=int, default=1, help="footprints, CSV, KLV: every Nth frame")
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
    ex.set_defaults(func=cmd_export)

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
    rg.set_defaults(func=cmd_register)

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
    sy.set_defaults(func=cmd_sync)

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
    te.set_defaults(func=cmd_telemetry)

    s = sub.add_parser("simulate", help="generate sample data")
    ssub = s.add_subparsers(dest="what", required=True)
    sc = ssub.add_parser(
        "scene", help="the procedural sample site (stadium hall and surroundings) as GLB"
    )
    sc.add_argument("--out", required=True, type=Path)
    sc.add_argument("--seed", type=int, default=7)
    sc.set_defaults(func=cmd_simulate_scene)
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
    ss.set_defaults(func=cmd_simulate_session)
    sp = ssub.add_parser(
        "photo",
        help="the sample photo: the site seen from the sample pose, plus a banner, people, a car",
    )
    sp.add_argument("--scene", required=True, type=Path)
    sp.add_argument("--out", required=True, type=Path)
    sp.set_defaults(func=cmd_simulate_photo)

    d = sub.add_parser("demo", help="render the bundled sample to a PNG")
    d.add_argument("--out", type=Path, default=Path("out/demo.png"))
    d.set_defaults(func=cmd_demo)

    b = sub.add_parser("bench", help="benchmarks (results go to docs/PERFORMANCE.md)")
    b.add_argument("what", choices=sorted(BENCHMARKS))
    b.add_argument("rest", nargs=argparse.REMAINDER, help="the benchmark's own options")
    b.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(_joined_negative_values(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:  # --help, or an argument error already printed as one line
        return int(exc.code or 0)
    try:
        return int(args.func(args))
    except GeofuseError as exc:
        print(f"geofuse: error: {exc}", file=sys.stderr)
        return 2
    except (
        OSError
    ) as exc:  # the file system said no (a folder given for a file, no permission, a full disk)
        print(f"geofuse: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
