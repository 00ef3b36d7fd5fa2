"""Shared helpers for benchmarks: timing with medians, machine description, markdown tables."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable


def time_calls(fn: Callable[[], object], repeats: int, warmup: int = 3) -> list[float]:
    """Seconds per call of fn, `repeats` samples after `warmup` discarded calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def median_ms(samples: list[float]) -> float:
    return 1000.0 * statistics.median(samples)


def p95_ms(samples: list[float]) -> float:
    s = sorted(samples)
    return 1000.0 * s[min(len(s) - 1, int(round(0.95 * (len(s) - 1))))]


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"


def table(header: list[str], rows: list[list[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def interleaved(
    draw: Callable[[object], None], on: object, off: object, frames: int, warmup: int = 3
) -> tuple[list[float], list[float]]:
    """(on, off) seconds per call of draw(on) and draw(off), alternated frame by frame so that
    machine noise hits both alike."""
    for _ in range(warmup):
        draw(on)
        draw(off)
    t_on: list[float] = []
    t_off: list[float] = []
    for _ in range(frames):
        for settings, bucket in ((on, t_on), (off, t_off)):
            t0 = time.perf_counter()
            draw(settings)
            bucket.append(time.perf_counter() - t0)
    return t_on, t_off


def on_off_table(t_on: list[float], t_off: list[float], on_label: str = "on") -> str:
    """The markdown table of projection off and on frame times (median, p95, fps)."""
    return table(["projection", "median ms", "p95 ms", "fps (median)"], [
        ["off", f"{median_ms(t_off):.2f}", f"{p95_ms(t_off):.2f}", f"{1000 / median_ms(t_off):.1f}"],
        [on_label, f"{median_ms(t_on):.2f}", f"{p95_ms(t_on):.2f}", f"{1000 / median_ms(t_on):.1f}"],
    ])  # fmt: skip


def drawing_paths(renderer) -> dict[str, bool]:
    """The drawing paths a FusionRenderer can take, by name, each its `deferred` switch: the
    deferred decals (where the context has them) and the forward full-cost pass."""
    paths = {"deferred": True, "forward": False}
    if renderer.deferred_pass is None:
        paths.pop("deferred")
    return paths


def write_json(path, figures: dict) -> None:
    """Write a benchmark's figures to `path` (a pathlib.Path; nothing where it is None) as
    indented JSON, and say where."""
    if path is None:
        return
    path.write_text(json.dumps(figures, indent=2, default=float) + "\n", encoding="utf-8")
    print(f"\nwritten {path}")
