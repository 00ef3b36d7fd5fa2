"""`geofuse bench WHAT`: runs bench/bench_WHAT.py from a source checkout (results go to
docs/PERFORMANCE.md)."""

from __future__ import annotations

import argparse
import runpy

from app.cli.parser import BENCHMARKS
from app.core.errors import GeofuseError
from app.simulate.sample import ROOT


def run(args: argparse.Namespace) -> int:
    script = ROOT / "bench" / BENCHMARKS[args.what]
    if not script.is_file():
        raise GeofuseError(
            f"{script}: benchmark script not found (benchmarks run from a source checkout)"
        )
    return int(runpy.run_path(str(script))["main"](args.rest))
