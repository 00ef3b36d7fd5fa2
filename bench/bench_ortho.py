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

    python bench/bench_ortho.py [--seconds S] [--sources offline,registered,registered:1.0] [--keep DIR]

With --command: the whole `geofuse export ortho --source registered` of the survey, run in this
process as a user runs it, its wall and CPU time against the clip's length, and where the time
goes (the command under cProfile: each part's cumulative time, the registration's OpenCV calls
by name), `--repeats` times (the medians are reported).

    python bench/bench_ortho.py --command [--seconds 40] [--repeats 1] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import pstats
import statistics
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

from app.cli import main as geofuse  # noqa: E402
from app.export.orthophoto import OrthoOptions, paint_clip  # noqa: E402
from app.register.solve import RegistrationSettings  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.simulate.session import SampleConfig, write_sample_session  # noqa: E402
from app.solve.accuracy import true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from bench.common import machine, table  # noqa: E402

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


# The parts of the command, by the function whose cumulative time is the part's (file suffix,
# function name), in the order they run; the registration's own calls below them.
PARTS = [
    ("registration (solve --source registered)", "app/register/solve.py", "registered_track"),
    ("  SIFT features (coarse step)", "", "detectAndCompute"),
    ("  ECC alignment (coarse step, flat views)", "", "findTransformECC"),
    ("  Lucas-Kanade tracking (fine step)", "", "calcOpticalFlowPyrLK"),
    ("  pose from points (PnP, RANSAC)", "", "solvePnPRansac"),
    ("painting (paint_clip)", "app/export/orthophoto.py", "paint_clip"),
    ("  the model from each frame's pose (GL)", "app/export/painting.py", "model_view"),
    ("  SurfaceMemory.paint", "app/export/memory.py", "paint"),
    ("writing the GeoTIFFs", "app/export/orthophoto.py", "write_orthophoto"),
    ("(both) rendering the model", "app/render/views.py", "render"),
    ("(both) decoding frames", "app/io/video.py", "frames_at"),
    ("(both) projecting points (Camera.project)", "app/camera/pinhole.py", "project"),
]


def _cumulative(stats: pstats.Stats, suffix: str, name: str) -> float:
    """Seconds of cumulative time of the functions named `name` in files ending with suffix;
    suffix "": a built-in (OpenCV) whose cProfile name holds `name`."""
    total = 0.0
    for (path, _line, func), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():
        ours = bool(suffix) and func == name and path.endswith(suffix)
        if ours or (not suffix and path == "~" and name in func):
            total += ct
    return total


def command(folder: Path, repeats: int) -> int:
    """The whole export command on the survey, timed and profiled (module docstring)."""
    manifest = folder / "session.toml"
    session = open_session(manifest)
    clip_s = float(session.video.pts_s[-1] - session.video.pts_s[0])
    walls, cpus, parts = [], [], []
    for k in range(repeats):
        out = folder / f"ortho-{k}.tif"
        profile = cProfile.Profile()
        wall, cpu = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()) as said:
            profile.enable()
            code = geofuse(["export", "ortho", str(manifest), "--source", "registered", "--out", str(out)])  # fmt: skip
            profile.disable()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
        if code != 0:
            raise SystemExit(f"export ortho failed ({code}):\n{said.getvalue()}")
        stats = pstats.Stats(profile)
        parts.append([_cumulative(stats, suffix, name) for _, suffix, name in PARTS])
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    print(time.strftime("%Y-%m-%d"), machine(), f"survey {clip_s:.1f} s, {repeats} run(s), medians")
    rows = [["the whole command", f"{wall:.1f}", f"{wall / clip_s:.2f}x", "100 %"]]
    for (label, _, _), seconds in zip(PARTS, np.median(np.array(parts), axis=0), strict=True):
        rows.append([label, f"{seconds:.1f}", f"{seconds / clip_s:.2f}x", f"{100 * seconds / wall:.0f} %"])  # fmt: skip
    print(table(["part", "wall s", "against the clip", "share"], rows))
    print(f"CPU time of the process: {cpu:.1f} s ({cpu / wall:.2f} of the wall time); goal 2x the clip")  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=40.0)
    p.add_argument("--sources", default="offline,registered")
    p.add_argument("--keep", type=Path, default=None)
    p.add_argument("--command", action="store_true", help="the whole export command's time")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--seed", type=int, default=SampleConfig().seed, help="the simulation's seed")
    args = p.parse_args(argv)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_ortho_"))
    manifest = folder / "session.toml"
    if not manifest.exists():
        write_sample_session(
            folder,
            SAMPLE_SCENE,
            replace(SampleConfig(), duration_s=args.seconds, flight="survey", seed=args.seed),
        )
    if args.command:
        return command(folder, args.repeats)
    session = open_session(manifest)
    clip_s = float(session.video.pts_s[-1] - session.video.pts_s[0])
    # the true poses at the frames' true times: the session's clock is 80 ms late, as phones and
    # drones are, which at 10 m/s would move the reference 0.8 m along the track
    truth_track = true_track(session)
    t = time.perf_counter()
    reference = paint_clip(session, truth_track, OrthoOptions(gsd=0.2))
    rows = [["truth (reference)", "-", f"{time.perf_counter() - t:.1f} s", "0", "0", "1", "-", "-"]]
    grid = reference.grid
    for spelt in args.sources.split(","):
        source, _, every = spelt.partition(":")  # registered:1.0: keyframes every 1.0 s
        options = {"settings": RegistrationSettings(every_s=float(every))} if every else {}
        t = time.perf_counter()
        track = solve_track(session, source, **options)
        solved_s = time.perf_counter() - t
        t = time.perf_counter()
        memory = paint_clip(session, track, OrthoOptions(), grid=grid)
        seconds = time.perf_counter() - t
        shift, p95, corr, tiles, cells = compare(memory, reference)
        rows.append([spelt, f"{solved_s:.1f} s", f"{seconds:.1f} s", f"{shift:.2f}", f"{p95:.2f}", f"{corr:.3f}", tiles, f"{cells:,.0f}"])  # fmt: skip
    print(
        time.strftime("%Y-%m-%d"),
        f"survey {clip_s:.0f} s, {grid.shape[1]} x {grid.shape[0]} cells of {grid.gsd} m, "
        f"memory {reference.nbytes / 1e6:.0f} MB",
    )
    print(table(["poses", "solved in", "written in", "shift median (m)", "shift p95 (m)", "correlation", "tiles", "cells compared"], rows))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
