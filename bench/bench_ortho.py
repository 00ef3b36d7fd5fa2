"""How true the orthophoto of a survey flight is, and what it costs: a drone's survey of the sample
site (`geofuse simulate session --flight survey`, its video rendered from the world that differs
from the model) painted into an orthophoto (app.export.orthophoto) under each pose source, and
compared with the one the true poses paint at the frames' true times (the world as the video
saw it, seen from above):
the shift between them, by phase correlation in tiles of TILE cells (half overlapping) that
both saw (at least 90 % of their cells) and that have texture, the median and 95th percentile
of the tiles' shifts in metres (a pose error varies along a flight, so one correlation over the
whole grid is no measure: it found 0.16 m where the tiles say 5 m, and was replaced); their
correlation over the cells both saw; the time to write each against the clip's length; the
memory held (the grid's, whatever the clip's length).

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
from app.solve.accuracy import true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from bench.common import table  # noqa: E402

TILE = 128  # cells a side of the tiles whose shifts are measured
MIN_RESPONSE = 0.1  # a tile's phase-correlation peak must reach this to count


def compare(a, b) -> tuple[float, float, float, int, float]:
    """(median shift m, 95th percentile m, correlation, tiles measured, cells compared) of
    orthophoto memory a against b (same grid); see the module docstring."""
    both = a.seen & b.seen
    ga = cv2.cvtColor(a.rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    gb = cv2.cvtColor(b.rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    window = cv2.createHanningWindow((TILE, TILE), cv2.CV_64F)
    shifts = []
    for r in range(0, ga.shape[0] - TILE + 1, TILE // 2):
        for c in range(0, ga.shape[1] - TILE + 1, TILE // 2):
            tile = (slice(r, r + TILE), slice(c, c + TILE))
            if both[tile].mean() < 0.9 or gb[tile].std() < 5.0:
                continue
            (dx, dy), response = cv2.phaseCorrelate(gb[tile].copy(), ga[tile].copy(), window)
            if response >= MIN_RESPONSE:
                shifts.append(np.hypot(dx, dy) * a.grid.gsd)
    corr = float(np.corrcoef(ga[both], gb[both])[0, 1])
    if not shifts:
        return float("nan"), float("nan"), corr, 0, float(both.sum())
    return (
        float(np.median(shifts)),
        float(np.percentile(shifts, 95)),
        corr,
        len(shifts),
        float(both.sum()),
    )


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
    # the true poses at the frames' true times: the session's clock is 80 ms late, as phones and
    # drones are, which at 10 m/s would move the reference 0.8 m along the track
    truth_track = true_track(session)
    t = time.perf_counter()
    reference = paint_clip(session, truth_track, OrthoOptions(gsd=0.2))
    rows = [["truth (reference)", f"{time.perf_counter() - t:.1f} s", "0", "0", "1", "-", "-"]]
    grid = reference.grid
    for source in args.sources.split(","):
        track = solve_track(session, source)
        t = time.perf_counter()
        memory = paint_clip(session, track, OrthoOptions(), grid=grid)
        seconds = time.perf_counter() - t
        shift, p95, corr, tiles, cells = compare(memory, reference)
        rows.append([source, f"{seconds:.1f} s", f"{shift:.2f}", f"{p95:.2f}", f"{corr:.3f}", tiles, f"{cells:,.0f}"])  # fmt: skip
    print(
        time.strftime("%Y-%m-%d"),
        f"survey {clip_s:.0f} s, {grid.shape[1]} x {grid.shape[0]} cells of {grid.gsd} m, "
        f"memory {reference.nbytes / 1e6:.0f} MB",
    )
    print(table(["poses", "written in", "shift median (m)", "shift p95 (m)", "correlation", "tiles", "cells compared"], rows))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
