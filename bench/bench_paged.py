"""What the paged memory (app.export.paged) costs and holds: the sample walk painted at the
video's ground sampling under the true poses (a frame every EVERY_S), once with room for every
page and once held to --memory-mb, the least recently used pages going to disk; the two must
paint the same (checked here: the samples seen and their colours, page by page). Then, with
--long-minutes M, an M-minute survey flight over the site painted in pages held to --memory-mb
(each frame a flat synthetic image of its own colour: what is measured is the memory), the
process's resident memory (RSS) and the pages' bytes at each quarter (no history: the
exports keep none).

    python bench/bench_paged.py [--every-s 0.2] [--memory-mb 64]
    python bench/bench_paged.py --long-minutes 20 [--memory-mb 128]
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

from app.camera.intrinsics import Intrinsics  # noqa: E402
from app.camera.pinhole import Camera  # noqa: E402
from app.export.paged import PagedMemory  # noqa: E402
from app.export.painted import ModelOptions, paint_model_paged  # noqa: E402
from app.export.painting import DECODE_LONG_SIDE, paint_one  # noqa: E402
from app.export.sampling import texel_targets  # noqa: E402
from app.geodesy import rotations  # noqa: E402
from app.render.views import ModelViews  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.camera_track import camera_track  # noqa: E402
from app.simulate.flights import survey  # noqa: E402
from bench.bench_memory import rss_mb  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402


def _row(name: str, paged: PagedMemory, seconds: float, clip_s: float) -> list:
    s = paged.stats
    seen, samples = paged.seen_count()
    return [name, f"{paged.texel_m:.3f}", f"{len(paged.triangles):,}", f"{s.pages:,}", f"{s.made:,}",
            f"{samples:,}", f"{100 * seen / max(1, samples):.0f}", f"{s.peak_bytes / 1e6:.0f}",
            f"{s.evicted:,}", f"{s.reloaded:,}", f"{s.spilled_bytes / 1e6:.0f}",
            f"{seconds:.1f}", f"{seconds / clip_s:.2f}"]  # fmt: skip


def _same(a: PagedMemory, b: PagedMemory) -> bool:
    for (_, _, ma), (_, _, mb) in zip(a.each_page(), b.each_page(), strict=True):
        if not (np.array_equal(ma.seen, mb.seen) and np.array_equal(ma.rgb, mb.rgb)):
            return False
    return True


def walk(every_s: float, memory_mb: float, json_path: Path | None = None) -> int:
    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    clip_s = float(session.frame_times[-1] - session.frame_times[0])
    rows, runs, figures = [], [], []
    for name, mb in (("room for all", 1e6), (f"held to {memory_mb:g} MB", memory_mb)):
        t0 = time.perf_counter()
        paged = paint_model_paged(session, track, ModelOptions(every_s=every_s, resident_mb=mb))
        seconds = time.perf_counter() - t0
        rows.append(_row(name, paged, seconds, clip_s))
        runs.append(paged)
        figures.append({"memory": name, "painted_s": round(seconds, 2), "x_clip": round(seconds / clip_s, 3),
                        "pages": paged.stats.pages, "evicted": paged.stats.evicted,
                        "peak_held_mb": round(paged.stats.peak_bytes / 1e6, 1)})  # fmt: skip
    same = _same(*runs)
    for p in runs:
        p.close()
    print(
        f"# {machine()}: the sample walk ({clip_s:.0f} s), a frame every {every_s:g} s, true poses"
    )
    print(table(["pages", "finest texel (m)", "triangles", "pages", "made", "samples", "seen (%)", "peak held (MB)",
                 "evicted", "read back", "to disk (MB)", "painted in (s)", "x clip"], rows))  # fmt: skip
    print(f"same painting both ways: {same}")
    write_json(json_path, {"clip_s": round(clip_s, 2), "every_s": every_s, "runs": figures,
                           "same": same, "machine": machine()})  # fmt: skip
    return 0 if same else 1


def long_clip(minutes: float, every_s: float, memory_mb: float) -> int:
    session = open_session(ROOT / "assets/sample/session.toml")
    scene = session.scene()
    times = np.arange(0.0, minutes * 60.0, every_s)
    flight = survey()
    quats = rotations.camera_quat_from_hpr(*flight.hpr(times).T)
    positions = flight.position(times)
    intr = Intrinsics.from_fov(960, 540, 70.0)
    cameras = [Camera.create(intr, positions[k], quats[k], far=2000.0) for k in range(len(times))]
    paged = PagedMemory(scene, lambda t: texel_targets(t, cameras, DECODE_LONG_SIDE),
                        resident_bytes=memory_mb * 1e6)  # fmt: skip
    views = ModelViews(scene)
    rows, t0 = [], time.perf_counter()
    for k, t in enumerate(times):
        frame = np.full((540, 960, 3), (k * 7 % 256, k * 13 % 256, 200), np.uint8)
        paint_one(paged, views, frame, cameras[k], float(t))
        if (k + 1) % (len(times) // 4) == 0 or k == 0:
            s = paged.stats
            rows.append([f"{t / 60:.1f}", k + 1, f"{rss_mb():.0f}", f"{paged.nbytes / 1e6:.0f}", f"{s.made:,}", f"{s.evicted:,}", f"{s.reloaded:,}", f"{time.perf_counter() - t0:.0f}"])  # fmt: skip
    views.release()
    print(
        f"# {machine()}: a {minutes:g}-minute survey, a frame every {every_s:g} s, pages held to {memory_mb:g} MB, "
        f"finest texel {paged.texel_m:.3f} m, {len(paged.pages):,} pages ({paged.samples:,} texels)"
    )
    print(table(["minute", "frames", "RSS (MB)", "pages held (MB)", "made", "evicted", "read back", "elapsed (s)"], rows))  # fmt: skip
    print(paged.stats.said())
    paged.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every-s", type=float, default=0.2)
    ap.add_argument("--memory-mb", type=float, default=None, help="default: 64 (walk), 128 (long)")
    ap.add_argument("--long-minutes", type=float, default=None)
    ap.add_argument("--json", type=Path, default=None, help="also write the walk's figures here")
    a = ap.parse_args(argv)
    if a.long_minutes:
        return long_clip(a.long_minutes, a.every_s, a.memory_mb or 128.0)
    return walk(a.every_s, a.memory_mb or 64.0, a.json)


if __name__ == "__main__":
    raise SystemExit(main())
