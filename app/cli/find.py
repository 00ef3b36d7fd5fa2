"""`geofuse find`: the clips of an archive that saw a place, and when (app.archive); --open
starts the viewer on the best of them."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from app.archive import find, place_of
from app.core.errors import GeofuseError
from app.io.area import read_area
from app.ui.viewer import Options, Viewer


def run(args: argparse.Namespace) -> int:
    if not args.archive.is_file():
        raise GeofuseError(
            f"{args.archive}: archive does not exist (make one with `geofuse index`)"
        )
    place = place_of(
        args.point, args.radius, read_area(args.polygon, "--polygon") if args.polygon else None
    )
    hits = find(args.archive, place, args.start, args.end)
    if args.json:
        print(json.dumps([h.as_dict() for h in hits]))
    else:
        for h in hits:
            print(h.line())
        print(f"{len(hits)} spans in {len({h.clip for h in hits})} clips", file=sys.stderr)
    if args.open and hits:
        best = hits[0]
        with tempfile.TemporaryDirectory(prefix="geofuse-find-") as tmp:
            script = Path(tmp) / "open.txt"
            script.write_text(f"0 seek {best.frame_s}\n0 pause\n")
            return Viewer(Options(Path(best.clip), script=script)).run()
    return 0 if hits else 1
