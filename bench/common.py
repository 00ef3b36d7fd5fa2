"""Shared helpers for benchmarks: timing with medians, machine description, markdown tables."""

from __future__ import annotations

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
