"""How fast city models open, and in how much memory: a district of 100,000 LoD2 buildings (30 m
apart, 9.5 km across) as a CityJSON document, a CityJSON Sequence and CityGML 2.0, read around a
track at one corner (500 m margin). Each read runs in a process of its own (its peak resident
memory against what it held before reading: Linux VmHWM after clear_refs), three times; the
medians are reported.

    python bench/bench_city.py [--count N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyproj

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.geodesy.enu import LocalFrame  # noqa: E402
from app.geodesy.geoid import undulation  # noqa: E402
from app.simulate.city import (  # noqa: E402
    Building,
    district,
    write_citygml,
    write_cityjson,
    write_cityjsonseq,
)
from bench.common import table  # noqa: E402

CRS = "EPSG:32632+3855"
SITE = (480_000.0, 5_550_000.0)
READ = """
import json, sys, time
import numpy as np
from app.geodesy.enu import LocalFrame
from app.scene.city.read import read_city
frame, track = LocalFrame(*json.loads(sys.argv[2])), np.array(json.loads(sys.argv[3]))
read_city(sys.argv[4], frame)
def status(key):
    return int(open("/proc/self/status").read().split(key + ":")[1].split()[0])
before = status("VmRSS")
try:
    open("/proc/self/clear_refs", "w").write("5")
except OSError:
    pass
t = time.perf_counter()
city = read_city(sys.argv[1], frame, track, margin_m=500.0)
print(json.dumps([time.perf_counter() - t, (status("VmHWM") - before) * 1024, city.objects_read]))
"""


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--count", type=int, default=100_000)
    p.add_argument("--keep", type=Path, default=None)
    args = p.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_city_"))
    folder.mkdir(parents=True, exist_ok=True)
    to_ll = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(*SITE)
    frame = LocalFrame(lat, lon, 100.0 + float(undulation(lat, lon)))
    tlon, tlat = to_ll.transform(SITE[0] + 100, SITE[1] + 100)
    small = write_cityjson(
        folder / "small.city.json",
        [Building.box("a", (*SITE, SITE[0] + 9, SITE[1] + 9), 0.0, 9.0)],
        CRS,
    )
    writers = {
        "CityJSON document": (write_cityjson, "district.city.json"),
        "CityJSON Sequence": (write_cityjsonseq, "district.city.jsonl"),
        "CityGML 2.0": (write_citygml, "district.gml"),
    }
    rows = []
    for name, (write, file) in writers.items():
        path = folder / file
        if not path.exists():
            write(path, district(args.count, SITE), CRS)
        runs = []
        for _ in range(3):
            out = subprocess.run(
                [sys.executable, "-c", READ, str(path), json.dumps([lat, lon, frame.h_m]), json.dumps([[tlat, tlon]]), str(small)],
                capture_output=True, text=True, check=True, cwd=ROOT,
            )  # fmt: skip
            runs.append(json.loads(out.stdout))
        seconds, grown, read = np.median(np.array(runs), axis=0)
        rows.append(
            [name, f"{path.stat().st_size / 1e6:.0f} MB", f"{seconds:.2f} s", f"{grown / 1e6:.0f} MB", int(read)]
        )  # fmt: skip
    print(time.strftime("%Y-%m-%d"), f"{args.count:,} buildings, track at one corner, 500 m margin")
    print(
        table(["format", "file", "read (median of 3)", "peak memory added", "buildings read"], rows)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
