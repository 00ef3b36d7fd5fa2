"""`geofuse solve`: a session's or clip's per-frame camera track to CSV."""

from __future__ import annotations

import argparse
import sys

from app.cli.common import open_with_source, print_messages
from app.core.outputs import CSV_SUFFIXES, check_output
from app.solve.track import solve_to_csv


def run(args: argparse.Namespace) -> int:
    check_output(args.out, "--out", CSV_SUFFIXES, [args.manifest, args.srt])
    session, source = open_with_source(args.manifest, args, CSV_SUFFIXES)
    print_messages(session)
    rows = solve_to_csv(session, source, args.out, progress=sys.stderr)
    print_messages(session)
    print(f"wrote {args.out}: {rows} frames, attitude from {source}")
    return 0
