"""What the viewer's scene memory costs (app.ui.memory): the sample walk painted by a
MemoryPainter as the viewer runs it, without a window (a frame every EVERY_S of video, the true
poses): the time to lay out the atlas and to paint against the clip's length, the bytes held,
and the time to compose each view's texture (the painter thread's work when the timeline moves)
and to build its mipmaps on upload (the frame loop's), medians of repeated runs.

    python bench/bench_memory.py [--every-s 0.2] [--max-texels 2000000] [--repeats 5]
    python bench/bench_memory.py --long-minutes 20
    python bench/bench_memory.py --paged [--max-texels 100000] [--every-s 1]

--long-minutes M: the memory over an M-minute survey flight instead (app.simulate.flights; a frame
every EVERY_S, each a flat synthetic image of its own colour: what is measured is the memory,
not the video), the process's resident memory (RSS) and the memory's bytes read at each quarter:
they must not grow with the clip.

--paged: the viewer's paged memory (--max-texels low enough that one atlas would be more than 4
times coarser a side than the video): painted, then the pages the video's camera at mid-clip
meets composed for a moment of the timeline (the painter's work when the slider moves: medians
over --repeats moments), and uploaded (the frame loop's), with the pages made, spilled, read back
and the GPU bytes held.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.intrinsics import Intrinsics  # noqa: E402
from app.camera.pinhole import Camera  # noqa: E402
from app.export.atlas import layout  # noqa: E402
from app.export.memory import SurfaceMemory  # noqa: E402
from app.export.memory_view import VIEWS, view_colours  # noqa: E402
from app.export.paged import pages_in_view  # noqa: E402
from app.export.painting import ClipToPaint, paint_one  # noqa: E402
from app.geodesy import rotations  # noqa: E402
from app.render.context import create_offscreen_context  # noqa: E402
from app.render.gpu_scene import GpuScene  # noqa: E402
from app.render.views import ModelViews  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.camera_track import camera_track  # noqa: E402
from app.simulate.flights import survey  # noqa: E402
from app.ui.memory import MemoryPainter  # noqa: E402
from bench.common import machine, median_ms, table, time_calls  # noqa: E402


def rss_mb() -> float:
    """This process's resident memory now (Linux /proc), MB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def long_clip(minutes: float, every_s: float, max_texels: int) -> int:
    """The memory over a long survey (see the module docstring): RSS and bytes at each quarter."""
    session = open_session(ROOT / "assets/sample/session.toml")
    scene = session.scene()
    atlas = layout(scene, max_texels)
    times = np.arange(0.0, minutes * 60.0, every_s)
    memory = SurfaceMemory(atlas.points, atlas.normals, "newest", (0.0, float(times[-1]), 16))
    views = ModelViews(scene)
    flight = survey()
    quats = rotations.camera_quat_from_hpr(*flight.hpr(times).T)
    positions = flight.position(times)
    intr = Intrinsics.from_fov(960, 540, 70.0)
    rows, t0 = [], time.perf_counter()
    for k, t in enumerate(times):
        cam = Camera.create(intr, positions[k], quats[k], far=2000.0)
        frame = np.full((540, 960, 3), (k * 7 % 256, k * 13 % 256, 200), np.uint8)
        paint_one(memory, views, frame, cam, float(t))
        if (k + 1) % (len(times) // 4) == 0 or k == 0:
            rows.append([f"{t / 60:.1f}", k + 1, f"{rss_mb():.0f}", f"{memory.nbytes / 1e6:.0f}", f"{100 * memory.seen.mean():.0f}", f"{time.perf_counter() - t0:.0f}"])  # fmt: skip
    views.release()
    print(
        f"# {machine()}: a {minutes:g}-minute survey, a frame every {every_s:g} s, {len(atlas.points):,} samples"
    )
    print(table(["minute", "frames", "RSS (MB)", "memory (MB)", "seen (%)", "elapsed (s)"], rows))
    return 0


def _painting(every_s: float, max_texels: int):
    """The sample walk being painted by a MemoryPainter under the true poses: (session, track,
    the clip's length s, the perf_counter when it started, the painter)."""
    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    times = np.asarray(session.frame_times, np.float64) - float(session.frame_times[0])
    t0 = time.perf_counter()
    p = MemoryPainter(
        session.scene(), [ClipToPaint(session, track, times)], "newest", every_s, max_texels
    ).start()
    return session, track, float(times[-1]), t0, p


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every-s", type=float, default=0.2)
    ap.add_argument("--max-texels", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--long-minutes", type=float, default=None)
    ap.add_argument("--paged", action="store_true")
    a = ap.parse_args(argv)
    if a.long_minutes:
        return long_clip(a.long_minutes, a.every_s, a.max_texels)
    if a.paged:
        return paged(a.every_s, a.max_texels, a.repeats)
    session, track, clip_s, t0, p = _painting(a.every_s, a.max_texels)
    while p.atlas is None and not p.done:
        time.sleep(0.01)
    layout_s = time.perf_counter() - t0
    p.wait()
    paint_s = time.perf_counter() - t0
    p.stop()
    if p.error:
        print(p.error)
        return 1
    m, atlas = p.memory, p.atlas
    held = p.nbytes / 1e6
    print(f"# {machine()}")
    print(
        table(
            ["clip (s)", "frames", "atlas (texels)", "texel (m)", "samples", "layout (s)", "painted in (s)", "x clip", "held (MB)"],
            [[f"{clip_s:.1f}", p.frames_painted, f"{atlas.size[0] * atlas.size[1]:,}", f"{atlas.texel_m:.2f}", f"{len(m.points):,}", f"{layout_s:.1f}", f"{paint_s:.1f}", f"{paint_s / clip_s:.2f}", f"{held:.0f}"]],
        )
    )  # fmt: skip
    rows = []
    at_s = clip_s / 2
    for view in VIEWS[1:]:
        compose = time_calls(lambda v=view: atlas.texture(view_colours(m, atlas.base, v, at_s, atlas.triangle)), a.repeats, 1)  # fmt: skip
        rows.append([view, f"{median_ms(compose):.0f}"])
    ctx = create_offscreen_context()
    scene = GpuScene(ctx, session.scene())
    texture = atlas.texture(atlas.base)
    scene.set_memory(atlas.primitive(atlas.base))

    def upload() -> None:
        scene.write_memory_texture(texture)
        ctx.finish()

    up = median_ms(time_calls(upload, a.repeats, 1))
    print(table(["view (at mid-clip)", "compose (ms)"], rows))
    print(f"upload with mipmaps: {up:.0f} ms ({ctx.info['GL_RENDERER']})")
    scene.release()
    ctx.release()
    return 0


def paged(every_s: float, max_texels: int, repeats: int) -> int:
    """The viewer's memory in pages (module docstring)."""
    session, track, clip_s, t0, p = _painting(every_s, max_texels)
    p.wait()
    paint_s = time.perf_counter() - t0
    if p.error or p.boxes is None:
        p.stop()
        print(p.error or f"--max-texels {max_texels}: one atlas, not paged (lower it)")
        return 1
    mid = len(session.frame_times) // 2
    view = track.frame_camera(mid).pinhole(1280 / 640)  # a 1280 x 720 window
    wanted = pages_in_view(view, *p.boxes, p.max_pages)
    ctx = create_offscreen_context()
    scene = GpuScene(ctx, session.scene())

    def shown(at_s: float) -> float:
        """Seconds until the pages for the moment at_s are composed and uploaded."""
        start = time.perf_counter()
        p.request("memory", at_s, wanted)
        while True:
            taken = p.take_pages()
            if taken is not None:
                for k, prim in taken[0].items():
                    scene.put_memory_page(k, prim)
                scene.keep_memory_pages(taken[1])
                ctx.finish()
            if p.current():
                return time.perf_counter() - start
            time.sleep(0.002)

    shown(clip_s)
    moments = [shown(clip_s * (k + 1) / (repeats + 1)) for k in range(repeats)]
    held = len(scene.memory_pages)
    s = p.page_stats
    print(f"# {machine()}")
    print(
        table(
            ["clip (s)", "frames", "painted in (s)", "x clip", "pages", "made", "spilled", "read back", "held (MB)", "finest texel (m)"],
            [[f"{clip_s:.1f}", p.frames_painted, f"{paint_s:.1f}", f"{paint_s / clip_s:.2f}", s.pages, s.made, s.evicted, s.reloaded, f"{p.nbytes / 1e6:.0f}", f"{p.memory.texel_m:.3f}"]],
        )
    )  # fmt: skip
    print(
        table(
            ["pages in view", "painted (held on the GPU)", "fine", "a moment shown (ms, median)", "GPU (MB)"],
            [[len(wanted), held, min(held, p.fine_pages), f"{1000 * float(np.median(moments)):.0f}", f"{scene.memory_pages_bytes / 1e6:.1f}"]],
        )
    )  # fmt: skip
    p.stop()
    scene.release()
    ctx.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
