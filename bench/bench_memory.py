"""What the viewer's scene memory costs (app.ui.memory): the sample walk painted by a
MemoryPainter as the viewer runs it, without a window (a frame every EVERY_S of video, the true
poses): the time to lay out the atlas and to paint against the clip's length, the bytes held,
and the time to compose each view's texture (the painter thread's work when the timeline moves)
and to build its mipmaps on upload (the frame loop's), medians of repeated runs.

    python bench/bench_memory.py [--every-s 0.2] [--max-texels 2000000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.export.memory_view import VIEWS, view_colours  # noqa: E402
from app.export.painting import ClipToPaint  # noqa: E402
from app.render.context import create_offscreen_context  # noqa: E402
from app.render.gpu_scene import GpuScene  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.camera_track import camera_track  # noqa: E402
from app.ui.memory import MemoryPainter  # noqa: E402
from bench.common import machine, median_ms, table, time_calls  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every-s", type=float, default=0.2)
    ap.add_argument("--max-texels", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    times = np.asarray(session.frame_times, np.float64) - float(session.frame_times[0])
    clip_s = float(times[-1])
    t0 = time.perf_counter()
    p = MemoryPainter(
        session.scene(), [ClipToPaint(session, track, times)], "newest", a.every_s, a.max_texels
    ).start()
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
    held = (m.nbytes + atlas.base.nbytes + atlas.pixels.nbytes) / 1e6
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


if __name__ == "__main__":
    raise SystemExit(main())
