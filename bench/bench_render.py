"""Render benchmark: frame time of the sample scene with projection on vs off, the depth-pass cost
against depth-map size, and the load time of a large scene.

    python bench/bench_render.py [--frames 120] [--size 1280x720] [--big-triangles 1000000]
        [--city-detail 24] [--dem-samples 4001] [--no-gis]

The GIS part (bench/bench_gis.py): a generated 3D Tiles city of 5 million triangles and a DEM of
4001 x 4001 samples, each against the sample's frame time measured in the same run.

Runs off-screen through EGL (Mesa llvmpipe on a machine without a GPU). Frame times are medians
over `--frames` frames, each closed with glFinish; on/off frames are interleaved so that machine
noise hits both alike, and their ratio is taken in the same run.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import (  # noqa: E402
    drawing_paths,
    interleaved,
    machine,
    median_ms,
    on_off_table,
    table,
    time_calls,
    write_json,
)


def _big_scene(path: Path, triangles: int) -> None:
    import trimesh

    n = int(np.sqrt(triangles / 2))
    grid = trimesh.creation.box()  # replaced below
    y, x = np.mgrid[0 : n + 1, 0 : n + 1].astype(np.float64)
    z = np.sin(x / 7.0) * np.cos(y / 5.0)
    verts = np.column_stack([x.ravel(), z.ravel(), -y.ravel()])
    idx = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[:-1, 1:].ravel(),
        idx[1:, 1:].ravel(),
        idx[1:, :-1].ravel(),
    )
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    grid = trimesh.Trimesh(vertices=verts, faces=faces, process=False)
    grid.export(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--big-triangles", type=int, default=1_000_000)
    parser.add_argument(
        "--city-detail",
        type=int,
        default=24,
        help="wall quads per side of a full-detail block (24: 5.0 M triangles in all)",
    )
    parser.add_argument("--dem-samples", type=int, default=4001)
    parser.add_argument("--no-gis", action="store_true", help="skip the city tileset and the DEM")
    parser.add_argument(
        "--projectors-only",
        action="store_true",
        help="only the projectors' tables: 1, 2, 4 and 8 at once, the sample and the city on/off",
    )
    parser.add_argument(
        "--terrain-only",
        action="store_true",
        help="only the DEM's frames, against the sample's frame time measured in the same run",
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="also write the figures of --projectors-only or --terrain-only to this file",
    )
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))

    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import depth_map_size
    from app.core.imageio import read_rgb
    from app.core.settings import ProjectionSettings
    from app.geodesy.enu import LocalFrame
    from app.render.context import create_offscreen_context, describe
    from app.render.offscreen import OffscreenTarget
    from app.render.renderer import FusionRenderer
    from app.render.still import window_camera
    from app.scene import load_scene
    from app.simulate.photo import photo_camera
    from app.simulate.sample import SAMPLE_ORIGIN, SAMPLE_PHOTO, SAMPLE_PHOTO_POSE, SAMPLE_SCENE

    frame = LocalFrame(*SAMPLE_ORIGIN)
    mesh = load_scene(SAMPLE_SCENE, frame)
    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, mesh)
    photo = read_rgb(SAMPLE_PHOTO)
    renderer.set_video_frame(photo)
    projector = photo_camera(SAMPLE_PHOTO_POSE, frame)
    renderer.set_projector(projector)
    view = window_camera(
        projector, Intrinsics.from_fov(w, h, 60.0), (35.0, -160.0, 40.0), (0.0, -20.0, 8.0), 2000.0
    )
    target = OffscreenTarget(ctx, w, h)

    print(
        f"# render benchmark\n\n{machine()}; GL: {describe(ctx)}; view {w}x{h}; sample scene {mesh.triangle_count} triangles\n"
    )

    on, off = ProjectionSettings(), ProjectionSettings(enabled=False)
    if args.projectors_only or args.terrain_only:
        from bench import bench_gis

        if args.projectors_only:
            figures = projectors(ctx, renderer, view, target, photo, frame, args.frames)
            renderer.set_extra_projectors([])
            renderer.set_projector(projector)
            figures["sample_on_off"] = sample_on_off(ctx, renderer, view, target, args.frames)
            if not args.no_gis:
                frames = max(10, args.frames // 4)
                city = bench_gis.city(ctx, photo, target, w, h, frames, None, args.city_detail)
                figures["city"] = city
                figures["city_on_off"] = city[figures["path"]]["ratio"]
            figures["sample_on_off_ratio"] = figures["sample_on_off"][figures["path"]]["ratio"]
        else:
            sample = sample_on_off(ctx, renderer, view, target, args.frames)
            off_ms = sample["deferred" if renderer.deferred else "forward"]["off_ms"]
            dem = bench_gis.dem(ctx, photo, target, w, h, args.frames, off_ms, args.dem_samples)
            figures = {"sample_on_off": sample, "dem": dem}
        figures.update(machine=machine(), gl=describe(ctx), view=[w, h])
        write_json(args.json, figures)
        renderer.release()
        target.release()
        return 0

    def draw(settings: ProjectionSettings) -> None:
        renderer.draw(view, target.fbo, settings)
        ctx.finish()

    t_on, t_off = interleaved(draw, on, off, args.frames, warmup=5)
    ratio = median_ms(t_on) / median_ms(t_off)
    print("## Frame time, projection on vs off (depth map cached: the pose does not change)\n")
    print(on_off_table(t_on, t_off))
    print(f"\nratio on/off (medians, same run): **{ratio:.3f}** (goal <= 1.35)\n")

    print(
        "## Depth pass against depth-map size (redrawn every frame: the pose changes each frame)\n"
    )
    rows = []
    for long_side in (1024, 2048, 4096):
        settings = ProjectionSettings(depth_long_side=long_side)
        size = depth_map_size(projector.intrinsics.width, projector.intrinsics.height, long_side)
        k = [0]

        def depth_only(k: list[int] = k, size: tuple[int, int] = size) -> None:
            k[0] += 1
            cam = photo_camera(
                SAMPLE_PHOTO_POSE.__class__(
                    **{
                        **SAMPLE_PHOTO_POSE.__dict__,
                        "heading_deg": SAMPLE_PHOTO_POSE.heading_deg + 1e-3 * (k[0] % 2),
                    }
                ),
                frame,
            )
            renderer.depth.update(cam, size)
            ctx.finish()

        def full_frame(settings: ProjectionSettings = settings, depth_only=depth_only) -> None:
            depth_only()
            renderer.set_projector(renderer.depth.camera)
            draw(settings)

        d = time_calls(depth_only, max(20, args.frames // 3))
        f = time_calls(full_frame, max(20, args.frames // 3))
        rows.append(
            [
                f"{size[0]}x{size[1]}",
                f"{median_ms(d):.2f}",
                f"{median_ms(f):.2f}",
                f"{1000 / median_ms(f):.1f}",
            ]
        )
    print(
        table(
            ["depth map", "depth pass median ms", "frame with depth redraw median ms", "fps"], rows
        )
    )

    print("\n## Scene load (trimesh -> ENU arrays) of a large mesh\n")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.glb"
        _big_scene(path, args.big_triangles)
        loads = time_calls(lambda: load_scene(path, frame), 3, warmup=1)
        big = load_scene(path, frame)
        t0 = time.perf_counter()
        big_renderer = FusionRenderer(ctx, big)
        ctx.finish()
        upload = time.perf_counter() - t0
        print(
            table(
                ["triangles", "load median s", "GPU upload s"],
                [[big.triangle_count, f"{median_ms(loads) / 1000:.2f}", f"{upload:.2f}"]],
            )
        )
        dense_scene(ctx, big_renderer, big, photo, target, w, h, args.frames)
        big_renderer.release()
    projectors(ctx, renderer, view, target, photo, frame, max(20, args.frames // 3))
    further_frames(ctx, renderer, view, target, max(5, args.frames // 12))
    if not args.no_gis:
        from bench import bench_gis

        gis_frames = max(20, args.frames // 3)
        bench_gis.city(ctx, photo, target, w, h, gis_frames, median_ms(t_off), args.city_detail)
        bench_gis.dem(ctx, photo, target, w, h, gis_frames, median_ms(t_off), args.dem_samples)
    renderer.release()
    target.release()
    return 0


def dense_scene(ctx, renderer, mesh, photo, target, w: int, h: int, frames: int) -> None:
    """The large mesh drawn whole: the window camera sees all of it, the projector a part; the
    depth map is redrawn every frame (the projector turns by a millidegree each frame, as a
    moving video's does), projection on and off interleaved in the same run."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera, look_at_quat
    from app.core.settings import ProjectionSettings
    from app.geodesy import rotations

    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    span = float(max(hi - lo))
    eye = centre + np.array([0.0, -0.9 * span, 0.6 * span])
    view = Camera.create(
        Intrinsics.from_fov(w, h, 60.0), eye, look_at_quat(eye, centre), 0.5, 4.0 * span
    )
    seen, _ = view.project(
        np.concatenate([p.positions for p in mesh.primitives]).astype(np.float64)
    )
    inside = float(
        np.mean((seen[:, 0] >= 0) & (seen[:, 0] <= w) & (seen[:, 1] >= 0) & (seen[:, 1] <= h))
    )
    p_eye = centre + np.array([0.0, -0.3 * span, 0.15 * span])
    q0 = look_at_quat(p_eye, centre)
    renderer.set_video_frame(photo)
    k = [0]

    def draw(settings: ProjectionSettings) -> None:
        k[0] += 1
        turn = rotations.heading_turn(
            1e-3 * ((k[0] // 2) % 2)
        )  # on and off alternate: every on-frame turns the projector
        renderer.set_projector(
            Camera.create(
                Intrinsics.from_fov(photo.shape[1], photo.shape[0], 66.0),
                p_eye,
                rotations.multiply(turn, q0),
                0.5,
                4.0 * span,
            )
        )
        renderer.draw(view, target.fbo, settings)
        ctx.finish()

    on, off = ProjectionSettings(), ProjectionSettings(enabled=False)
    interleaved(draw, on, off, 3, warmup=0)  # warm-up
    redraws = renderer.depth.renders
    t_on, t_off = interleaved(draw, on, off, max(20, frames // 3), warmup=0)
    if renderer.depth.renders - redraws != len(t_on):  # the measurement means nothing otherwise
        raise RuntimeError(
            f"the depth map was redrawn {renderer.depth.renders - redraws} times in {len(t_on)} projection-on frames"
        )
    print(
        f"\n## A dense scene drawn whole: {mesh.triangle_count} triangles, {100 * inside:.0f} % of its vertices inside the view\n"
    )
    print("Projection on: depth map (2048 texels) redrawn every frame; off: no depth pass.\n")
    print(on_off_table(t_on, t_off, "on, depth redrawn"))
    print(f"\nratio on/off (medians, same run): **{median_ms(t_on) / median_ms(t_off):.3f}**")


def projectors(ctx, renderer, view, target, photo, frame, frames: int) -> dict:
    """The sample drawn with 1, 2, 4 and 8 projectors at once (several clips), every depth map
    redrawn every frame (each projector turns by a millidegree a frame), on both drawing paths:
    the deferred decals (each projector over its reach, adaptive depth maps) and the forward
    full-cost pass. Counts, paths and moving/still frames are interleaved frame by frame in the
    same run; ratios are taken against one projector on the same path. Timed: the renderer's
    draw to glFinish (wall), and the GPU's own time for it (a GL timer query), the cameras made
    beforehand (the viewer takes them from its tracks). Raises unless every depth map a moving
    frame claims to redraw was redrawn. Returns the medians and ratios (JSON)."""
    from app.core.settings import ProjectionSettings
    from app.simulate.photo import photo_camera
    from app.simulate.sample import SAMPLE_PHOTO_POSE

    settings = ProjectionSettings()
    counts = (1, 2, 4, 8)
    paths = drawing_paths(renderer)
    default = renderer.deferred  # the path this context draws by default

    def camera(k: int, tick: int):
        # Every moving frame turns each projector to a heading it had in none of the last 999
        # frames (a turn that came back sooner would give a projector drawn again on its old
        # heading its old depth map: no redraw, as the check below would say).
        pose = SAMPLE_PHOTO_POSE.__dict__
        heading = pose["heading_deg"] + 6.0 * (k - 3.5) + 1e-4 * (tick % 1000)
        return photo_camera(SAMPLE_PHOTO_POSE.__class__(**{**pose, "heading_deg": heading}), frame)

    renderer.set_extra_projectors([(camera(k, 0), photo, 0.0) for k in range(1, max(counts))])
    extras = list(renderer.extras)
    tick = [0]
    missed = []
    query = ctx.query(time=True)

    def draw(path: str, n: int, move: bool, whole: bool = True) -> tuple[float, float]:
        """One frame: (wall s, GPU s; 0 where `whole` is False: the pass timer's queries are
        running, and timer queries cannot nest)."""
        tick[0] += move
        renderer.deferred = paths[path]
        renderer.extras = extras[: n - 1]
        renderer.set_projector(camera(0, tick[0]))
        for k, e in enumerate(renderer.extras, start=1):
            e.camera = camera(k, tick[0])
        depths = [renderer.depth] + [e.depth for e in renderer.extras]
        before = [d.renders for d in depths]
        t0 = time.perf_counter()
        with query if whole else nullcontext():
            renderer.draw(view, target.fbo, settings)
        ctx.finish()
        wall = time.perf_counter() - t0
        redrawn = sum(d.renders - b for d, b in zip(depths, before, strict=True))
        if move and redrawn != n:
            missed.append((path, n, redrawn))
        return wall, query.elapsed / 1e9 if whole else 0.0

    keys = [(path, n, move) for path in paths for n in counts for move in (True, False)]
    times: dict = {key: [] for key in keys}
    gpu: dict = {key: [] for key in keys}
    for _ in range(3):
        for key in keys:
            draw(*key)
    for _ in range(frames):
        for key in keys:
            wall, busy = draw(*key)
            times[key].append(wall)
            gpu[key].append(busy)
    sections = _where_the_time_goes(ctx, renderer, paths, draw, max(5, frames // 4))
    renderer.extras = extras
    renderer.deferred = default
    if missed:
        raise RuntimeError(
            f"depth maps not redrawn on moving frames (path, count, redrawn): {missed[:5]}"
        )
    goal = {1: "", 2: "", 4: "1.5x", 8: "2x"}
    out: dict = {"frames": frames, "paths": {}}
    print("\n## Several projectors at once (every depth map redrawn every frame)\n")
    for path in paths:
        base, gpu_base = median_ms(times[path, 1, True]), median_ms(gpu[path, 1, True])
        rows, medians, ratios, gpu_medians, gpu_ratios = [], {}, {}, {}, {}
        for n in counts:
            moving, still = median_ms(times[path, n, True]), median_ms(times[path, n, False])
            busy = median_ms(gpu[path, n, True])
            medians[str(n)], ratios[str(n)] = round(moving, 2), round(moving / base, 3)
            gpu_medians[str(n)], gpu_ratios[str(n)] = round(busy, 3), round(busy / gpu_base, 3)
            rows.append([n, f"{moving:.2f}", f"{moving / base:.2f}x", goal[n], f"{still:.2f}",
                         f"{busy:.3f}", f"{busy / gpu_base:.2f}x"])  # fmt: skip
        out["paths"][path] = {
            "frame_median_ms": medians,
            "projector_ratios": ratios,
            "gpu_median_ms": gpu_medians,
            "gpu_ratios": gpu_ratios,
            "sections": sections[path],
        }
        print(f"### {path}\n")
        print(table(["projectors", "frame median ms", "against one (same path, same run)", "goal",
                     "depth maps kept ms", "GPU ms (timer query)", "GPU against one"], rows))  # fmt: skip
        print()
    if "forward" in out["paths"] and "deferred" in out["paths"]:
        rel = {
            n: median_ms(times["deferred", n, True]) / median_ms(times["forward", n, True])
            for n in counts
        }
        print(
            "deferred / forward, same count: "
            + ", ".join(f"{n}: {r:.2f}x" for n, r in rel.items())
            + "\n"
        )
    print(
        "### Where the time goes (moving frames; CPU: wall time of the section, GPU: its timer query)\n"
    )
    print(table(["path", "projectors", "pass", "CPU median ms", "GPU median ms"], [
        [path, n, name, f"{t['cpu_ms']:.3f}", f"{t['gpu_ms']:.3f}"]
        for path, by_count in sections.items() for n, by_name in by_count.items()
        for name, t in by_name.items()
    ]))  # fmt: skip
    print()
    first = "deferred" if default else "forward"
    out["projector_ratios"] = out["paths"][first]["projector_ratios"]
    out["frame_median_ms"] = out["paths"][first]["frame_median_ms"]
    out["gpu_ratios"] = out["paths"][first]["gpu_ratios"]
    out["path"] = first
    return out


def _where_the_time_goes(ctx, renderer, paths, draw, frames: int) -> dict:
    """{path: {count: {pass: {"cpu_ms", "gpu_ms"}}}}: medians over `frames` moving frames of one
    and of eight projectors, each pass timed by app.render.pass_timer."""
    from app.render.pass_timer import PassTimer

    renderer.timer = timer = PassTimer(ctx)
    out: dict = {}
    try:
        for path in paths:
            for n in (1, 8):
                timer.clear()
                for _ in range(frames):
                    draw(path, n, True, whole=False)
                    timer.end_frame()
                out.setdefault(path, {})[str(n)] = {
                    name: {
                        "cpu_ms": round(median_ms(timer.cpu_s[name]), 3),
                        "gpu_ms": round(median_ms(timer.gpu_s[name]), 3),
                    }
                    for name in timer.cpu_s
                }
    finally:
        renderer.timer = None
    return out


def sample_on_off(ctx, renderer, view, target, frames: int) -> dict:
    """The sample with projection on and off (the depth map kept), on each path, interleaved:
    medians and the on/off ratio per path."""
    from app.core.settings import ProjectionSettings

    on, off = ProjectionSettings(), ProjectionSettings(enabled=False)
    paths = drawing_paths(renderer)
    default = renderer.deferred
    keys = [(path, s) for path in paths for s in (on, off)]
    times = {k: [] for k in range(len(keys))}
    for _ in range(3):
        for path, s in keys:
            renderer.deferred = paths[path]
            renderer.draw(view, target.fbo, s)
            ctx.finish()
    for _ in range(frames):
        for k, (path, s) in enumerate(keys):
            renderer.deferred = paths[path]
            t0 = time.perf_counter()
            renderer.draw(view, target.fbo, s)
            ctx.finish()
            times[k].append(time.perf_counter() - t0)
    renderer.deferred = default
    out = {}
    rows = []
    for i, path in enumerate(paths):
        t_on, t_off = median_ms(times[2 * i]), median_ms(times[2 * i + 1])
        out[path] = {
            "on_ms": round(t_on, 2),
            "off_ms": round(t_off, 2),
            "ratio": round(t_on / t_off, 3),
        }
        rows.append([path, f"{t_on:.2f}", f"{t_off:.2f}", f"{t_on / t_off:.3f}"])
    print("\n## The sample, projection on vs off (depth map kept), both paths in one run\n")
    print(table(["path", "on median ms", "off median ms", "on / off (goal <= 1.35)"], rows))
    return out


def further_frames(ctx, renderer, view, target, frames: int) -> None:
    """A further clip's playback frame: made ready to draw, converted to RGB and turned on the
    CPU (numpy, the reference conversion the viewer used before) against its planes uploaded as
    they are (what the viewer does: the scene shader turns and converts them), alternated in the
    same run, per frame size; and what the planes cost the scene pass (one further projector,
    its depth map kept), RGB and planes alternated."""
    from app.core.settings import ProjectionSettings
    from app.render.video_texture import ExtraVideo, YuvPlanes, yuv_to_rgb

    shown = ExtraVideo(ctx)
    rng = np.random.default_rng(0)
    rows = []
    planes = {}
    for w, h in ((640, 360), (1920, 1080), (3840, 2160)):
        y = rng.integers(16, 235, (h, w), dtype=np.uint8)
        u = rng.integers(16, 240, (h // 2, w // 2), dtype=np.uint8)
        v = rng.integers(16, 240, (h // 2, w // 2), dtype=np.uint8)
        planes[w] = YuvPlanes(y, u, v, 90)

        def ready(on_cpu: bool, y=y, u=u, v=v, w=w) -> None:
            if on_cpu:
                shown.set(np.ascontiguousarray(np.rot90(yuv_to_rgb(y, u, v), k=-1)))
            else:
                shown.set(planes[w])
            ctx.finish()

        n = max(3, frames // (4 if w > 1000 else 1))
        t_cpu, t_gpu = interleaved(ready, True, False, n, warmup=1)
        rows.append(
            [
                f"{w}x{h}",
                f"{median_ms(t_cpu):.1f}",
                f"{median_ms(t_gpu):.1f}",
                f"{median_ms(t_cpu) / median_ms(t_gpu):.1f}x",
            ]
        )
    shown.release()
    print("\n## A further clip's playback frame made ready to draw (turned 90 degrees)\n")
    print(
        table(
            [
                "frame",
                "RGB on the CPU (numpy) + upload, median ms",
                "planes uploaded, median ms",
                "CPU / planes",
            ],
            rows,
        )
    )
    settings = ProjectionSettings()
    first = renderer.projector
    frame_yuv = planes[1920]
    frame_rgb = np.ascontiguousarray(
        np.rot90(yuv_to_rgb(frame_yuv.y, frame_yuv.u, frame_yuv.v), k=-1)
    )

    def draw(frame) -> None:
        renderer.set_extra_projectors([(first, frame, 0.0)])
        renderer.draw(view, target.fbo, settings)
        ctx.finish()

    t_rgb, t_yuv = interleaved(draw, frame_rgb, frame_yuv, max(10, frames), warmup=2)
    print(
        f"\nOne further projector (1920x1080, uploaded each frame) in the sample's frame: RGB"
        f" {median_ms(t_rgb):.1f} ms, planes {median_ms(t_yuv):.1f} ms median (same run)."
    )


if __name__ == "__main__":
    raise SystemExit(main())
