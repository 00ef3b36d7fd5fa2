"""GNSS that begins late (issue 52): how the `registered` source poses the frames before a clip's
first fix (a receiver still acquiring, or jammed at take-off and then let go).

    python bench/bench_late_gnss.py [--flights orbit survey] [--seeds 1 2] [--duration 40]
        [--late 15 30] [--jobs 1] [--json out.json]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from the model, as bench/bench_gnss_lies.py does), then copies of it whose
fixes before --late seconds of clip time are removed (app.simulate.lies `outage`), each solved
with the `registered` source, and the clean session too, --jobs at a time. Figures per copy: the
camera position error (m, 3D, against the truth) over the frames before the first fix (median,
p90, the largest) and after it (median), the clean run's over the same frames, and how often
registration searched (app.register.solve: before any keyframe registered, over the disc the
platform flies from the first fix in time) and found.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.simulate.lies import Lie, falsify  # noqa: E402
from bench.bench_gnss_lies import _session, run  # noqa: E402
from bench.common import table, write_json  # noqa: E402


def _case(job: tuple[str, int, str, float | None]) -> tuple[str, int, float | None, dict]:
    """Solve one case (flight, seed, folder, the first fix's clip time s or None: clean)."""
    flight, seed, folder, late = job
    base = Path(folder)
    if late is None:
        return flight, seed, late, run(base / "clean" / "session.toml")
    manifest = falsify(base / "clean", base / f"late-{late:g}", Lie("outage", -1e6, until_s=late))
    return flight, seed, late, run(manifest)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--duration", type=float, default=40.0, help="seconds of video")
    parser.add_argument("--late", nargs="+", type=float, default=[15.0, 30.0], help="the first fix (clip s)")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1, help="sessions solved at a time")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="late-gnss-") as tmp:
        units = [(f, s, args.duration, str(Path(tmp) / f"{f}-{s}"), None) for s in args.seeds for f in args.flights]  # fmt: skip
        cases = [(f, s, d, late) for f, s, _, d, _ in units for late in (None, *args.late)]
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            list(pool.imap_unordered(_session, units))
            done = {(f, s, late): got for f, s, late, got in pool.imap_unordered(_case, cases)}
    rows, figures = [], []
    for flight, seed, _, _, _ in units:
        clean = done[(flight, seed, None)]
        for late in args.late:
            got = done[(flight, seed, late)]
            before, after = got["t"] < late, got["t"] >= late
            e = got["error"]
            found = sum(1 for _, _, ok in got["searched"] if ok)
            fig = {
                "flight": flight,
                "seed": seed,
                "first_fix_s": late,
                "before_median_m": float(np.median(e[before])),
                "before_p90_m": float(np.percentile(e[before], 90)),
                "before_max_m": float(e[before].max()),
                "clean_before_median_m": float(np.median(clean["error"][before])),
                "after_median_m": float(np.median(e[after])),
                "clean_after_median_m": float(np.median(clean["error"][after])),
                "searched": len(got["searched"]),
                "found": found,
                "radius_m": max((r for _, r, _ in got["searched"]), default=0.0),
            }
            figures.append(fig)
            rows.append([flight, seed, f"{late:g}", f"{fig['before_median_m']:.2f} / {fig['before_p90_m']:.2f} / {fig['before_max_m']:.1f}", f"{fig['clean_before_median_m']:.2f}", f"{fig['after_median_m']:.2f}", f"{fig['clean_after_median_m']:.2f}", f"{found} of {len(got['searched'])}, within {fig['radius_m']:.0f} m"])  # fmt: skip
    print(f"# GNSS that begins late: {args.duration:g} s sessions\n")
    print(table(["flight", "seed", "first fix (s)", "error before it: median / p90 / max (m)", "clean run's (m)", "error after it (m)", "clean run's (m)", "searched: found, widest disc"], rows))  # fmt: skip
    write_json(args.json, {"duration_s": args.duration, "runs": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
