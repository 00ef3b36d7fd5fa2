"""`geofuse register`: control points picked by hand give the clip's boresight and position
correction (app.register.points)."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli.common import print_messages
from app.core.errors import GeofuseError
from app.core.outputs import check_output
from app.footage.clips import open_any
from app.register.points import control_path, read_points, solve_control, write_points
from app.register.solve import default_prior
from app.solve.track import solve_track


def run(args: argparse.Namespace) -> int:
    points = read_points(args.points)
    session = open_any(args.input, lens=args.lens)
    print_messages(session)
    source = args.source or default_prior(session)
    try:
        session.check_source(source)
    except ValueError as exc:
        raise GeofuseError(f"--source: {exc}") from exc
    solution = solve_control(solve_track(session, source), points)
    for note in solution.notes:
        session.messages.add(note)
    print_messages(session)
    print(f"{args.input}: {len(points)} control points against {source}")
    print(solution.report())
    if args.write:
        out = check_output(
            control_path(Path(args.input)),
            "--write",
            (".csv",),
            list(session.inputs) + [args.points],
        )
        write_points(out, points)
        print(f"wrote {out}: the registered source starts from this correction")
    return 0
