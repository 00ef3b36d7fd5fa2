"""What valid plan-view footprints cost: the sample walk's frame records, and the footprints
built from them (app/export/footprint.py) against the plain GEOS union of every cell.

    python bench/bench_footprints.py [--every 1] [--repeat 3] [--check 200]

Records (the GPU position pass, 33 x 19 rays a frame) are made once; the footprints are built
`--repeat` times (the median reported). On every `--check`-th record the plain union of all
the grid's cells (each folded one made valid) is timed too, in the same run, with the relative
area by which the two differ."""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import shapely  # noqa: E402

from app.export.footprint import cell_rings, plan_footprint  # noqa: E402
from app.export.records import frame_records  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate.sample import SAMPLE_DIR  # noqa: E402
from bench.common import table  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--check", type=int, default=200)
    args = parser.parse_args(argv)

    session = open_session(SAMPLE_DIR / "session.toml")
    t0 = time.perf_counter()
    records = list(frame_records(session, session.sources[0], args.every))
    records_s = time.perf_counter() - t0
    runs = []
    for k in range(args.repeat):
        t0 = time.perf_counter()
        shapes = [plan_footprint(r.ground) for r in records]
        runs.append(time.perf_counter() - t0)
        print(f"run {k + 1}/{args.repeat}: {runs[-1]:.2f} s", file=sys.stderr)
    plain, built, differ = [], [], []
    for r, s in list(zip(records, shapes, strict=True))[:: args.check]:
        lon_lat = np.asarray(r.ground)[..., ::-1]
        t0 = time.perf_counter()
        u = shapely.union_all(shapely.make_valid(shapely.polygons(cell_rings(lon_lat))))
        plain.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        plan_footprint(r.ground)
        built.append(time.perf_counter() - t0)
        differ.append(u.symmetric_difference(s).area / u.area)
    n = len(records)
    valid = sum(s is not None and s.is_valid for s in shapes)
    multi = sum(s is not None and s.geom_type == "MultiPolygon" for s in shapes)
    print(
        table(
            ["what", "value"],
            [
                ["frames", str(n)],
                ["records (position pass), s", f"{records_s:.1f}"],
                ["footprints, s (median of runs)", f"{statistics.median(runs):.2f}"],
                ["footprint, ms a frame", f"{statistics.median(runs) / n * 1000:.2f}"],
                ["valid (GEOS), of frames", f"{valid} of {n}"],
                ["MultiPolygons", str(multi)],
                [
                    f"plain union / built, time ratio ({len(plain)} frames, same run)",
                    f"{statistics.median(plain) / statistics.median(built):.1f}x",
                ],
                ["area differing from the plain union, max", f"{max(differ):.1e}"],
            ],
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
