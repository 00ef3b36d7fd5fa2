"""Attitude benchmark: accuracy on the BROAD trials (the dataset's own metric, the layout of the
paper's Table 2) with vqf and imufusion run side by side, and solve time for 6,624 / 66,240 /
662,400 samples (the paper's Table 3).

    python bench/bench_attitude.py [--broad ../shared/data/broad] [--skip-timing]

BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7), 2021, doi:10.3390/data6070072, CC BY 4.0. 6D (IMU) scores
remove one constant heading offset first (the dataset's README); 9D scores remove nothing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import machine, table  # noqa: E402

Estimator = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, float], np.ndarray]


def ours(method: str) -> Estimator:
    from app.attitude.filters import estimate

    return lambda t, gyr, acc, mag, rate: estimate(t, gyr, acc, mag, method=method)


def vqf_online(t, gyr, acc, mag, rate):
    from vqf import VQF

    out = VQF(1.0 / rate).updateBatch(
        np.ascontiguousarray(gyr),
        np.ascontiguousarray(acc),
        None if mag is None else np.ascontiguousarray(mag),
    )
    return out["quat6D"] if mag is None else out["quat9D"]


def vqf_offline(t, gyr, acc, mag, rate):
    from vqf import offlineVQF

    out = offlineVQF(
        np.ascontiguousarray(gyr),
        np.ascontiguousarray(acc),
        None if mag is None else np.ascontiguousarray(mag),
        1.0 / rate,
    )
    return out["quat6D"] if mag is None else out["quat9D"]


def imufusion_ahrs(t, gyr, acc, mag, rate):
    import imufusion

    ahrs = imufusion.Ahrs()
    settings = imufusion.AhrsSettings()
    # Keyword arguments to AhrsSettings are ignored by imufusion 1.3 (it stays NWU): set properties.
    settings.sample_rate = rate
    settings.convention = imufusion.CONVENTION_ENU
    ahrs.set_settings(settings)
    gyr_dps = np.degrees(gyr)
    acc_g = acc / 9.80665
    q = np.empty((len(t), 4))
    for i in range(len(t)):
        if mag is None:
            ahrs.update_no_magnetometer(gyr_dps[i], acc_g[i])
        else:
            ahrs.update(gyr_dps[i], acc_g[i], mag[i])
        q[i] = ahrs.get_quaternion()
    return q


FILTERS: dict[str, Estimator] = {
    "geofuse GD": ours("gd"),
    "geofuse CF": ours("cf"),
    "geofuse offline": ours("offline"),
    "vqf (online)": vqf_online,
    "vqf offline": vqf_offline,
    "imufusion": imufusion_ahrs,
}


def accuracy(broad: Path) -> str:
    from app.attitude.metrics import broad_rms
    from app.io.broad import list_trials, load_trial

    trials = [load_trial(p) for p in list_trials(broad)]
    if not trials:
        raise SystemExit(f"no BROAD trials in {broad}")
    names = [t.name for t in trials]
    undisturbed = [i for i, n in enumerate(names) if "undisturbed" in n]
    disturbed = [i for i, n in enumerate(names) if "undisturbed" not in n]
    rows = []
    for label, fn in FILTERS.items():
        for mode in ("9D", "6D"):
            res = []
            for tr in trials:
                rate = 1.0 / np.median(np.diff(tr.t))
                q = fn(tr.t, tr.gyr, tr.acc, tr.mag if mode == "9D" else None, rate)
                res.append(broad_rms(q, tr.q_ref, tr.movement, remove_heading=mode == "6D"))
            tot = np.array([r.total for r in res])
            head = np.array([r.heading for r in res])
            incl = np.array([r.inclination for r in res])
            rows.append(
                [
                    f"{label} {mode}",
                    f"{tot[undisturbed].mean():.2f}",
                    f"{tot[disturbed].mean():.2f}",
                    f"{head[undisturbed].mean():.2f}",
                    f"{incl[undisturbed].mean():.2f}",
                    " ".join(f"{x:.2f}" for x in tot),
                ]
            )
    header = [
        "filter",
        "total undisturbed",
        "total disturbed",
        "heading undisturbed",
        "inclination undisturbed",
        "total per trial (" + ", ".join(n[:2] for n in names) + ")",
    ]
    return table(header, rows)


def _synthetic(n: int, rate: float = 100.0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(0)
    t = np.arange(n) / rate
    gyr = 0.5 * np.column_stack(
        [np.sin(0.3 * t), np.cos(0.2 * t), np.sin(0.1 * t)]
    ) + 0.01 * rng.standard_normal((n, 3))
    acc = np.column_stack(
        [0.3 * np.sin(t), 0.2 * np.cos(t), np.full(n, 9.81)]
    ) + 0.05 * rng.standard_normal((n, 3))
    mag = np.column_stack(
        [np.full(n, 20.0), np.zeros(n), np.full(n, -40.0)]
    ) + 0.5 * rng.standard_normal((n, 3))
    return t, gyr, acc, mag


def timing() -> str:
    sizes = (6_624, 66_240, 662_400)
    rows = []
    entries = [
        (f"geofuse {m.upper()} {'AHRS' if mag else 'IMU'}", ours(m), mag)
        for m in ("gd", "cf", "offline")
        for mag in (True, False)
    ]
    entries += [
        ("vqf (batch C++) AHRS", vqf_online, True),
        ("vqf offline AHRS", vqf_offline, True),
        ("imufusion (Python loop) AHRS", imufusion_ahrs, True),
    ]
    data = {n: _synthetic(n) for n in sizes}
    ours("gd")(*data[sizes[0]][:3], data[sizes[0]][3], 100.0)  # compile / load the cache first
    for label, fn, use_mag in entries:
        cells = []
        for n in sizes:
            t, gyr, acc, mag = data[n]
            samples = []
            for _ in range(3 if n < 600_000 else 1 if "imufusion" in label else 3):
                t0 = time.perf_counter()
                fn(t, gyr, acc, mag if use_mag else None, 100.0)
                samples.append(time.perf_counter() - t0)
            cells.append(f"{1000 * float(np.median(samples)):.1f} ms")
        rows.append([label, *cells])
    header = ["filter", *[f"{n:,} samples" for n in sizes]]
    out = table(header, rows)
    code = (
        "import time; t0 = time.perf_counter(); import numpy as np; from app.attitude.filters import estimate; "
        "n = 6624; t = np.arange(n) / 100.0; g = np.zeros((n, 3)); a = np.tile([0, 0, 9.81], (n, 1)); "
        "m = np.tile([20.0, 0, -40], (n, 1)); estimate(t, g, a, m); print(time.perf_counter() - t0)"
    )

    def fresh(cache_dir: str | None) -> float:
        env = dict(os.environ)
        if cache_dir is not None:
            env["NUMBA_CACHE_DIR"] = cache_dir
        return float(
            subprocess.run(
                [sys.executable, "-c", code],
                capture_output=True,
                text=True,
                check=True,
                cwd=ROOT,
                env=env,
            ).stdout
        )

    warm = [fresh(None) for _ in range(3)]
    cold = []
    for _ in range(3):
        with tempfile.TemporaryDirectory() as empty:
            cold.append(fresh(empty))
    out += (
        "\n\nFresh process, import + first 6,624-sample GD AHRS solve, median of 3: "
        f"{np.median(cold):.2f} s with an empty numba cache (compilation), {np.median(warm):.2f} s with the cache on disk"
    )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broad", type=Path, default=ROOT.parent / "shared" / "data" / "broad")
    parser.add_argument("--skip-timing", action="store_true")
    args = parser.parse_args(argv)
    print(f"# attitude benchmark\n\n{machine()}\n")
    print("## BROAD accuracy (RMSE, degrees; dataset metric)\n")
    print(accuracy(args.broad))
    if not args.skip_timing:
        print("\n## Solve time (median of 3; synthetic 100 Hz data; after compilation)\n")
        print(timing())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
