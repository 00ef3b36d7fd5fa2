"""GIS scenes in the render benchmark: a generated city as 3D Tiles (millions of triangles in four
levels of detail) and a DEM of 4001 x 4001 samples.

For each: the time from opening to the first full-detail frame (the frame loop runs all along,
uploading what the workers finished within its budget: the frame times while loading are
reported too), then frame times with the projection on (depth map redrawn every frame) and off,
interleaved in the same run, the triangles drawn from the view and into the depth map, and the
GPU memory held. The 62-triangle sample's frame time, measured in the same run, is the yardstick.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import drawing_paths, interleaved, median_ms, on_off_table, p95_ms, table

CITY_ORIGIN = (47.0, 8.0, 400.0)


def _cameras(w: int, h: int, eye, target, p_eye, p_target, photo_shape):
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera, look_at_quat

    view = Camera.create(
        Intrinsics.from_fov(w, h, 60.0), eye, look_at_quat(eye, target), 0.5, 5000.0
    )
    projector = Camera.create(
        Intrinsics.from_fov(photo_shape[1], photo_shape[0], 66.0),
        p_eye,
        look_at_quat(p_eye, p_target),
        0.5,
        2000.0,
    )
    return view, projector


def _steady(ctx, renderer, view, projector, target, frames: int):
    """Interleaved on/off frame times (s); the projector turns by a millidegree every frame."""
    from app.core.settings import ProjectionSettings
    from app.geodesy import rotations

    on, off = ProjectionSettings(), ProjectionSettings(enabled=False)
    k = [0]

    def draw(settings) -> None:
        k[0] += 1
        turn = rotations.heading_turn(
            1e-3 * ((k[0] // 2) % 2)
        )  # on and off alternate: every on-frame turns the projector
        renderer.set_projector(
            type(projector).create(
                projector.intrinsics,
                projector.position,
                rotations.multiply(turn, np.asarray(projector.orientation)),
                projector.near,
                projector.far,
            )
        )
        renderer.draw(view, target.fbo, settings)
        ctx.finish()

    interleaved(draw, on, off, 3, warmup=0)  # warm-up
    redraws = renderer.depth.renders
    t_on, t_off = interleaved(draw, on, off, frames, warmup=0)
    if renderer.depth.renders - redraws != frames:
        raise RuntimeError(
            f"the depth map was redrawn {renderer.depth.renders - redraws} times in {frames} projection-on frames"
        )
    return t_on, t_off


def _first_full_frame(ctx, renderer, view, target, start: float, limit_s: float = 600.0):
    """Draw frames as the viewer does until the view's tiles are complete: (seconds since
    `start`, frame times while loading)."""
    from app.core.settings import ProjectionSettings

    times = []
    while time.perf_counter() - start < limit_s:
        t0 = time.perf_counter()
        renderer.draw(view, target.fbo, ProjectionSettings())
        ctx.finish()
        times.append(time.perf_counter() - t0)
        if all(
            layer.complete(view, None, "view") and not layer.stream.pending
            for layer in renderer.scene.tilesets
        ):
            break
    renderer.draw(view, target.fbo, ProjectionSettings())
    ctx.finish()
    return time.perf_counter() - start, times


def city(
    ctx,
    photo,
    target,
    w: int,
    h: int,
    frames: int,
    sample_off_ms: float | None,
    leaf_detail: int = 24,
) -> dict:
    """The generated city's load and frame times, projection on and off on each drawing path
    (deferred decals where the context has them, and the forward pass): {path: {"on_ms",
    "off_ms", "ratio"}}. sample_off_ms: the sample's frame time without projection from the
    same run, for the city/sample ratio (None: not printed)."""
    from app.geodesy.enu import LocalFrame
    from app.render.renderer import FusionRenderer
    from app.scene.mesh import MeshData
    from app.scene.tiles.tileset import Tileset
    from app.simulate.tileset import write_city

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        stats = write_city(
            Path(tmp) / "city",
            CITY_ORIGIN,
            size_m=800.0,
            levels=4,
            blocks_per_leaf=16,
            leaf_detail=leaf_detail,
        )
        written = time.perf_counter() - t0
        frame = LocalFrame(*CITY_ORIGIN)
        view, projector = _cameras(
            w,
            h,
            [-360.0, -380.0, 45.0],
            [0.0, 0.0, 0.0],
            [-300.0, -320.0, 30.0],
            [-150.0, -100.0, 0.0],
            photo.shape,
        )
        start = time.perf_counter()
        renderer = FusionRenderer(ctx, MeshData(tilesets=[Tileset(str(stats.path), frame)]))
        renderer.set_video_frame(photo)
        renderer.set_projector(projector)
        first_s, loading = _first_full_frame(ctx, renderer, view, target, start)
        steady, default = {}, renderer.deferred
        for path, flag in drawing_paths(renderer).items():
            renderer.deferred = flag
            steady[path] = _steady(ctx, renderer, view, projector, target, frames)
        renderer.deferred = default
        layer = renderer.scene.tilesets[0]
        print(
            f"\n## A city as 3D Tiles: {stats.triangles:,} triangles in {stats.tiles} tiles, {stats.levels} levels ({stats.leaf_triangles:,} at full detail)\n"
        )
        print(
            f"Written in {written:.1f} s (b3dm, RTC_CENTER, region volumes, REPLACE). View at 45 m above a corner of the 800 m city, looking across it; the projector 30 m up.\n"
        )
        print(table(["", "value"], [
            ["open -> first full-detail frame", f"{first_s:.2f} s ({len(loading)} frames drawn meanwhile, median {median_ms(loading):.1f} ms, max {1000 * max(loading):.0f} ms)"],
            ["triangles drawn from the view", f"{renderer.scene_pass.triangles:,}"],
            ["triangles in the depth map", f"{renderer.depth.triangles:,}"],
            ["tiles on the GPU / GPU memory held", f"{len(layer.resident)} / {layer.bytes_held / 2**20:.0f} MiB (cap {layer.cache_bytes / 2**20:.0f} MiB)"],
        ]))  # fmt: skip
        out: dict = {"first_full_frame_s": round(first_s, 2)}
        for path, (t_on, t_off) in steady.items():
            ratio = median_ms(t_on) / median_ms(t_off)
            out[path] = {
                "on_ms": round(median_ms(t_on), 2),
                "off_ms": round(median_ms(t_off), 2),
                "ratio": round(ratio, 3),
            }
            print(f"\n{path}:\n")
            print(on_off_table(t_on, t_off, "on, depth redrawn every frame"))
            versus = (
                ""
                if sample_off_ms is None
                else f"; city off / sample off: **{median_ms(t_off) / sample_off_ms:.2f}** (goal <= 1.5)"
            )
            print(f"\nratio on/off: **{ratio:.3f}** (goal <= 1.35){versus}")
        renderer.release()
        return out


def dem(
    ctx, photo, target, w: int, h: int, frames: int, sample_off_ms: float, samples: int = 4001
) -> dict:
    """The generated DEM's load and frame times, projection on (depth map redrawn every frame)
    and off, interleaved; returns the figures (seconds, milliseconds, medians and p95)."""
    import pyproj

    from app.geodesy.enu import LocalFrame
    from app.render.renderer import FusionRenderer
    from app.scene.terrain import read_terrain
    from app.simulate.terrain import hills, write_geotiff

    lat0, lon0, _ = CITY_ORIGIN
    e0, n0 = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(
        lon0, lat0
    )
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        half = samples / 2.0
        path = write_geotiff(
            Path(tmp) / "dem.tif",
            hills(samples, samples, 1.0),
            "EPSG:32632+5773",
            e0 - half,
            n0 + half,
            1.0,
            1.0,
        )
        written = time.perf_counter() - t0
        frame = LocalFrame(*CITY_ORIGIN)
        start = time.perf_counter()
        terrain = read_terrain(path, frame, None, max_error_m=0.5)
        loaded = time.perf_counter() - start
        renderer = FusionRenderer(ctx, terrain.mesh)
        ctx.finish()
        uploaded = time.perf_counter() - start
        zc = float(terrain.mesh.primitives[0].positions[:, 2].mean())
        view, projector = _cameras(
            w,
            h,
            [-1500.0, -1600.0, zc + 250.0],
            [0.0, 0.0, zc],
            [-600.0, -600.0, zc + 120.0],
            [-200.0, -200.0, zc],
            photo.shape,
        )
        renderer.set_video_frame(photo)
        renderer.set_projector(projector)
        t_on, t_off = _steady(ctx, renderer, view, projector, target, frames)
        print(
            f"\n## Terrain from a DEM of {samples} x {samples} samples (1 m, UTM + EGM96, {path.stat().st_size / 2**20:.0f} MiB GeoTIFF written in {written:.1f} s)\n"
        )
        print(table(["", "value"], [
            ["read + RTIN mesh + placement", f"{loaded:.2f} s"],
            ["open -> first frame (GPU upload included)", f"{uploaded:.2f} s"],
            ["grid meshed / triangles / measured error", f"{terrain.grid_shape[0]} x {terrain.grid_shape[1]} / {terrain.mesh.triangle_count:,} / {terrain.error_m:.3f} m (bound 0.5 m)"],
        ]))  # fmt: skip
        print()
        print(on_off_table(t_on, t_off, "on, depth redrawn every frame"))
        print(
            f"\nratio on/off: **{median_ms(t_on) / median_ms(t_off):.3f}**; terrain off / sample off: **{median_ms(t_off) / sample_off_ms:.2f}**"
        )
        renderer.release()
        return {
            "samples": samples,
            "loaded_s": round(loaded, 2),
            "first_frame_s": round(uploaded, 2),
            "triangles": terrain.mesh.triangle_count,
            "on_ms": round(median_ms(t_on), 2),
            "off_ms": round(median_ms(t_off), 2),
            "on_p95_ms": round(p95_ms(t_on), 2),
            "off_p95_ms": round(p95_ms(t_off), 2),
            "ratio": round(median_ms(t_on) / median_ms(t_off), 3),
            "off_vs_sample_off": round(median_ms(t_off) / sample_off_ms, 2),
        }
