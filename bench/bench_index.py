"""The archive: clips indexed per minute with 1, 2 and all workers, and a query on 1 million
footprints.

    python bench/bench_index.py [--clips 8] [--seconds 20] [--every-s 1] [--footprints 1000000]

Clips: simulated DJI clips (a 96x54 H.264 video and the Air 2S subtitle a DJI aircraft writes,
one entry per frame), `--seconds` long and one second longer each, each indexed on a Dask LocalCluster of processes (a
fresh archive per run). Reported per worker count: clips per minute, scaling against one worker
(same run), the workers' peak memory, and the cost per clip-minute of video (worker seconds per
minute of video). The query: `--footprints` synthetic 50 m footprints over 100 x 100 km, written
as GeoParquet like an index (covering bounding boxes, row groups in spatial order), then
`geofuse find` at a point with a 30 m radius, the median of five.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import geopandas as gpd  # noqa: E402
import shapely  # noqa: E402

from app.archive import find, index_archive, place_of, read_clips  # noqa: E402
from app.geodesy.enu import METRES_PER_DEGREE  # noqa: E402
from app.simulate import drone  # noqa: E402
from app.simulate.phone import write_video  # noqa: E402
from bench.common import machine, table  # noqa: E402


def _clips(folder: Path, n: int, seconds: float) -> None:
    for k in range(n):
        d = folder / f"flight{k:02d}"
        d.mkdir(parents=True)
        length = seconds + k  # each flight its own length: no two files alike
        write_video(d / "DJI_0001.MP4", np.arange(int(length * 30)) / 30.0, (96, 54), 0)
        (d / "DJI_0001.SRT").write_text(drone.srt_text(length, 0.1 * k), encoding="utf-8")


def _query(folder: Path, n: int) -> tuple[float, int]:
    rng = np.random.default_rng(1)
    lat0, lon0 = 46.0, 14.5
    x = rng.uniform(0, 100_000, n)
    y = rng.uniform(0, 100_000, n)
    order = np.lexsort((np.floor(x / 5000), np.floor(y / 5000)))  # 5 km cells, row by row
    x, y = x[order], y[order]
    k = np.array([METRES_PER_DEGREE * np.cos(np.radians(lat0)), METRES_PER_DEGREE])
    lon, lat = lon0 + x / k[0], lat0 + y / k[1]
    half = 25.0 / k
    boxes = shapely.box(lon - half[0], lat - half[1], lon + half[0], lat + half[1])
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    frame = gpd.GeoDataFrame(
        {
            "clip": [f"clip{i // 600:05d}.MP4" for i in range(n)],
            "frame": np.arange(n) % 600,
            "clip_s": (np.arange(n) % 600).astype(float),
            "utc": [t0 + timedelta(seconds=float(i)) for i in range(n)],
            "sensor_lat": lat, "sensor_lon": lon, "sensor_h": np.full(n, 400.0),
            "heading_deg": np.zeros(n), "pitch_deg": np.full(n, -90.0), "roll_deg": np.zeros(n),
            "axis_e": np.zeros(n), "axis_n": np.zeros(n), "axis_u": -np.ones(n),
            "hfov_deg": np.full(n, 70.0), "centre_h": np.full(n, 300.0),
        },
        geometry=boxes,
        crs="EPSG:4326",
    )  # fmt: skip
    path = folder / "million.parquet"
    frame.to_parquet(path, index=False, write_covering_bbox=True, row_group_size=50_000)
    times, hits = [], 0
    for _ in range(5):
        i = int(rng.integers(n))
        place = place_of((float(lat[i]), float(lon[i])), 30.0)
        t = time.perf_counter()
        hits = len(find(path, place))
        times.append(time.perf_counter() - t)
    return statistics.median(times), hits


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--every-s", type=float, default=1.0)
    parser.add_argument("--footprints", type=int, default=1_000_000)
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="geofuse-bench-index-"))
    try:
        _clips(folder / "clips", args.clips, args.seconds)
        counts = sorted({1, 2, os.cpu_count() or 1})
        rows, base = [], None
        for workers in counts:
            out = folder / f"w{workers}.parquet"
            t = time.perf_counter()
            report = index_archive([folder / "clips"], out, args.every_s, workers=workers)
            wall = time.perf_counter() - t
            clips = read_clips(out)
            per_min = 60.0 * report.indexed / wall
            base = base or per_min
            cost = clips["seconds"].sum() / (clips["duration_s"].sum() / 60.0)
            rows.append(
                [
                    workers,
                    f"{report.indexed} of {report.found}",
                    f"{wall:.1f}",
                    f"{per_min:.1f}",
                    f"{per_min / base:.2f}x",
                    f"{clips['worker_peak_mb'].max():.0f}",
                    f"{cost:.1f}",
                ]
            )
            print(f"{workers} workers: {wall:.1f} s", file=sys.stderr)
        query_s, hits = _query(folder, args.footprints)
        print(f"machine: {machine()}")
        print(
            table(
                [
                    "workers",
                    "clips indexed",
                    "wall s (cluster start included)",
                    "clips a minute",
                    "scaling vs 1 worker",
                    "worker peak MiB",
                    "worker s per clip-minute",
                ],
                rows,
            )
        )
        print(
            f"\nquery on {args.footprints} footprints: {query_s * 1000:.0f} ms median of 5 ({hits} spans found at the last)"
        )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
