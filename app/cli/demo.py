"""`geofuse demo` without a display: a still of the sample session as the viewer opens it (the
walk's video draped on the model at DEMO_TIME_S, seen from above the site)."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli import render
from app.cli.parser import build_parser, joined_negative_values
from app.simulate.sample import SAMPLE_DIR

DEMO_TIME_S = 20.0  # the demo still's moment of the sample walk (the hall's front in view)


def run(args: argparse.Namespace) -> int:
    argv = [
        "render",
        "--session", str(SAMPLE_DIR / "session.toml"),
        "--time", str(DEMO_TIME_S),
        "--view-from", "35,-160,40",
        "--look-at", "0,-20,8",
        "--alpha", "0.85",
        "--out", str(args.out),
    ]  # fmt: skip
    code = render.run(build_parser().parse_args(joined_negative_values(argv)))
    if code == 0:
        print(
            f"The demo still is at {Path(args.out).resolve()}; with a display, `geofuse view` opens the interactive viewer."
        )
    return code
