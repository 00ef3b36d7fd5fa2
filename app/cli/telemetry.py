"""`geofuse telemetry`: what a camera file records (app.footage.telemetry), without solving anything."""

from __future__ import annotations

import argparse

from app.core.outputs import CSV_SUFFIXES, check_output
from app.footage.telemetry import describe, inspect, write_csv


def run(args: argparse.Namespace) -> int:
    if args.csv is not None:
        check_output(args.csv, "--csv", CSV_SUFFIXES, [args.file])
    tel = inspect(args.file)
    print(describe(tel))
    if args.csv is not None:
        print(f"wrote {args.csv}: {write_csv(tel, args.csv)} positions")
    return 0
