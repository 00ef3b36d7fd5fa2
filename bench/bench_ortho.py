"""How true the orthophoto of a survey flight is, and what it costs: a drone's survey of the sample
site (`geofuse simulate session --flight survey`, its video rendered from the world that differs
from the model) painted into an orthophoto (app.export.orthophoto) under each pose source, and
compared with the one the true poses paint (the world as the video saw it, seen from above):
the shift between them (phase correlation, metres) and their correlation over the cells both
saw; the time to write each against the clip's length; the memory held (the grid's, whatever
the clip's length).

    python bench/bench_ortho.py [--seconds S] [--sources offline,registered] [--keep DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.export.orthophoto import OrthoOptions, paint_clip  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.simulate.session import SampleConfig, write_sample_session  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from bench.common import table  # noqa: E402


def compare(a, b) -> tuple[float, float, float]:
    """(shift m, correlation, cells compared) of orthophoto memory a against b (same grid)."""
    both = a.seen & b.seen
    ga = cv2.cvtColor(a.rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    gb = cv2.cvtColor(b.rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    ga[~both], gb[~both] = ga[both].mean(), gb[both].mean()
    (dx, dy), _ = cv2.phaseCorrelate(gb, ga, cv2.createHanningWindow(ga.shape[::-1], cv2.CV_64F))
    corr = float(np.corrcoef(ga[both], gb[both])[0, 1])
    return float(np.hypot(dx, dy) * a.grid.gsd), corr, float(both.sum())


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=40.0)
    p.add_argument("--sources", default="offline,registered")
    p.add_argument("--keep", type=Path, default=None)
    args = p.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_ortho_"))
    manifest = folder / "session.toml"
    if not manifest.exists():
        write_sample_session(
            folder, SAMPLE_SCENE, replace(SampleConfig(), duration_s=args.seconds, flight="survey")
        )
    session = open_session(manifest)
    clip_s = float(session.video.pts_s[-1] - session.video.pts_s[0])
    truth_track = solve_track(session, "truth")
    t = time.perf_counter()
    reference = paint_clip(session, truth_track, OrthoOptions(gsd=0.2))
    rows = [["truth (reference)", f"{time.perf_counter() - t:.1f} s", "0", "1", "-"]]
    grid = reference.grid
    for source in args.sources.split(","):
        track = solve_track(session, source)
        t = time.perf_counter()
        memory = paint_clip(session, track, OrthoOptions(), grid=grid)
        seconds = time.perf_counter() - t
        shift, corr, cells = compare(memory, reference)
        rows.append([source, f"{seconds:.1f} s", f"{shift:.2f}", f"{corr:.3f}", f"{cells:,.0f}"])
    print(
        time.strftime("%Y-%m-%d"),
        f"survey {clip_s:.0f} s, {grid.shape[1]} x {grid.shape[0]} cells of {grid.gsd} m, "
        f"memory {reference.nbytes / 1e6:.0f} MB",
    )
    print(table(["poses", "written in", "shift (m)", "correlation", "cells compared"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
