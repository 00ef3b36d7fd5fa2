"""Accuracy of a session with ground truth: attitude RMS per filter (the paper's Table 2 layout)
and the projection error in metres on the model, split by cause, with the paper's pipeline as a
baseline row.

    python bench/bench_accuracy.py [MANIFEST] [--every 10] [--grid 64x36]

MANIFEST defaults to the bundled sample session (assets/sample/session.toml).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import table  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "manifest", nargs="?", type=Path, default=ROOT / "assets" / "sample" / "session.toml"
    )
    parser.add_argument("--every", type=int, default=10, help="analyse every Nth frame")
    parser.add_argument("--grid", default="64x36", help="pixel grid per frame, WxH")
    args = parser.parse_args(argv)
    grid = tuple(int(v) for v in args.grid.split("x"))

    from app.core.progress import ProgressBar
    from app.session import open_session
    from app.solve.accuracy import evaluate

    t0 = time.perf_counter()
    session = open_session(args.manifest)
    sources = [s for s in session.sources if s != "truth"]
    reports = evaluate(
        session, sources, args.every, grid, progress=ProgressBar("accuracy", sys.stderr)
    )
    n = (len(session.frame_times) + args.every - 1) // args.every
    print(
        f"# accuracy: {args.manifest}\n\n{n} frames (every {args.every}th), a {grid[0]}x{grid[1]} pixel grid each; "
        f"declination {session.declination_deg:.2f} deg; {time.perf_counter() - t0:.0f} s\n"
    )
    print("## Attitude RMS of the optical axis (degrees), at the true frame times\n")
    print(
        table(
            ["source", "heading", "pitch", "roll", "total angle"],
            [[r.name, *(f"{v:.2f}" for v in r.attitude)] for r in reports],
        )
    )
    print("\n## Projection error on the model (metres): median / 95th percentile\n")
    rows = []
    for r in reports:
        cells = [r.name]
        for stats in (r.total, r.by_cause["attitude"], r.by_cause["position"], r.by_cause["time"]):
            cells.append(f"{stats.centre_median:.2f} / {stats.centre_p95:.2f}")
            cells.append(f"{stats.edge_median:.2f} / {stats.edge_p95:.2f}")
        rows.append(cells)
    header = ["source"] + [
        f"{what} {where}"
        for what in ("all", "attitude only", "position only", "time only")
        for where in ("centre", "edges")
    ]
    print(table(header, rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
