"""The tables of docs/PERFORMANCE.md's "GPU" section, from two runs of bench/bench_device.py:
the device's (bench/device.sh on a lent GPU) and this machine's at the same sizes (llvmpipe),
side by side. Steps missing from a run read "-".

    python bench/device_tables.py GPU.json LLVMPIPE.json > tables.md
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import table  # noqa: E402

PATHS = ("deferred", "forward")
GOAL = {"4": "1.5x", "8": "2x"}


def _figures(run: dict, step: str) -> dict | None:
    got = run["steps"].get(step) or {}
    return got.get("figures") if got.get("ok") else None


def _get(figures: dict | None, *keys: str | int, fmt: str = "{:.2f}") -> str:
    value: object = figures
    for k in keys:  # names into dicts, numbers into lists
        if isinstance(value, list) and isinstance(k, int) and k < len(value):
            value = value[k]
        elif isinstance(value, dict) and k in value:
            value = value[k]
        else:
            return "-"
    return fmt.format(value) if isinstance(value, int | float) else str(value)


def _name(run: dict) -> str:
    gpu = run["environment"].get("gpu")
    return gpu["name"] if gpu else run["environment"]["gl"]["renderer"].split(" (")[0]


def projectors(gpu: dict, cpu: dict, step: str) -> str:
    """Frame time and ratio against one projector, per path and count: llvmpipe | GPU; then
    the GPU's own time (timer query) on the device."""
    g, c = _figures(gpu, step), _figures(cpu, step)
    rows = []
    for path in PATHS:
        for n in ("1", "2", "4", "8"):
            p = ("paths", path)
            rows.append([path, n,
                         _get(c, *p, "frame_median_ms", n), _get(g, *p, "frame_median_ms", n),
                         _get(c, *p, "projector_ratios", n, fmt="{:.2f}x"),
                         _get(g, *p, "projector_ratios", n, fmt="{:.2f}x"), GOAL.get(n, ""),
                         _get(g, *p, "gpu_median_ms", n, fmt="{:.3f}"),
                         _get(g, *p, "gpu_ratios", n, fmt="{:.2f}x")])  # fmt: skip
    return table(["path", "projectors", f"{_name(cpu)} ms", f"{_name(gpu)} ms",
                  f"{_name(cpu)} against one", f"{_name(gpu)} against one", "goal",
                  "GPU busy ms (timer query)", "GPU busy against one"], rows)  # fmt: skip


def sections(gpu: dict, step: str) -> str:
    """Where a moving frame's time goes on the device, pass by pass (app.render.pass_timer)."""
    g = _figures(gpu, step) or {}
    rows = []
    for path in PATHS:
        for n, by_pass in ((g.get("paths") or {}).get(path, {}).get("sections") or {}).items():
            for name, t in by_pass.items():
                if name == "tiles":
                    continue  # nothing streams in the sample
                rows.append([path, n, name, f"{t['cpu_ms']:.3f}", f"{t['gpu_ms']:.3f}"])
    return table(["path", "projectors", "pass", "CPU ms (median)", "GPU ms (median)"], rows)


def on_off(gpu: dict, cpu: dict, steps: tuple[str, ...]) -> str:
    """The sample and the city with projection on and off, per path and view size."""
    rows = []
    for step in steps:
        g, c = _figures(gpu, step), _figures(cpu, step)
        size = step.split("_", 1)[1]
        for scene in ("sample_on_off", "city"):
            for path in PATHS:
                rows.append([f"{scene.split('_')[0]} {size}", path,
                             f"{_get(c, scene, path, 'on_ms')} / {_get(c, scene, path, 'off_ms')}",
                             _get(c, scene, path, "ratio", fmt="{:.2f}"),
                             f"{_get(g, scene, path, 'on_ms')} / {_get(g, scene, path, 'off_ms')}",
                             _get(g, scene, path, "ratio", fmt="{:.2f}")])  # fmt: skip
        rows.append([f"city {size}", "first full-detail frame (s)",
                     _get(c, "city", "first_full_frame_s"), "",
                     _get(g, "city", "first_full_frame_s"), ""])  # fmt: skip
    return table(["scene, view", "path", f"{_name(cpu)} on / off ms", "on / off",
                  f"{_name(gpu)} on / off ms", "on / off"], rows)  # fmt: skip


def others(gpu: dict, cpu: dict) -> str:
    """Terrain, live, registration and the paged memory: one row a figure."""
    rows = []

    def row(label: str, step: str, *keys: str | int, fmt: str = "{:.2f}") -> None:
        g, c = _figures(gpu, step), _figures(cpu, step)
        rows.append([label, _get(c, *keys, fmt=fmt), _get(g, *keys, fmt=fmt)])

    row("terrain 4001 x 4001: read + mesh + upload (s)", "terrain", "dem", "first_frame_s")
    row("terrain: frame, projection off (ms)", "terrain", "dem", "off_ms")
    row("terrain: frame, on, depth redrawn (ms)", "terrain", "dem", "on_ms")
    row("terrain: on / off", "terrain", "dem", "ratio")
    for feed in ("720p30", "1080p30"):
        key = f"{feed} loss 0%"
        row(f"live {feed}: arrival -> drawn p50 (ms)", "live", key, "median", "arrival_p50_ms")
        row(f"live {feed}: the same from 4 s on, p50 (ms)", "live", key, "median", "steady_p50_ms")
        row(f"live {feed}: the same from 4 s on, p95 (ms)", "live", key, "median", "steady_p95_ms")
        row(f"live {feed}: past the buffer p50 (ms)", "live", key, "median", "added_p50_ms")
        row(f"live {feed}: frames lost by geofuse", "live", key, "median", "lost_by_geofuse",
            fmt="{:.0f}")  # fmt: skip
    row("registration: keyframes per second", "registration", "keyframes_per_s")
    row("registration: wall time / clip length", "registration", "wall_per_clip")
    row("registration: render (s, all keyframes)", "registration", "stage_s", "render")
    row("registration: match (s, all keyframes)", "registration", "stage_s", "match")
    for i, label in enumerate(("room for all", "held to 64 MB")):
        row(f"paged memory, {label}: painted in (s)", "paged", "runs", i, "painted_s", fmt="{:.1f}")
    return table(["figure", _name(cpu), _name(gpu)], rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("gpu", type=Path, help="bench_device.py's JSON from the device")
    parser.add_argument("llvmpipe", type=Path, help="the same steps' JSON from this machine")
    args = parser.parse_args(argv)
    gpu, cpu = (json.loads(p.read_text()) for p in (args.gpu, args.llvmpipe))
    for size in ("1280x720", "1920x1080"):
        print(f"### Several projectors at once, {size}\n")
        print(projectors(gpu, cpu, f"render_{size}") + "\n")
        print(f"Where the time goes on the {_name(gpu)}, {size}:\n")
        print(sections(gpu, f"render_{size}") + "\n")
    print("### Projection on and off\n")
    print(on_off(gpu, cpu, ("render_1280x720", "render_1920x1080")) + "\n")
    print("### Terrain, live feeds, registration, paged memory\n")
    print(others(gpu, cpu))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
