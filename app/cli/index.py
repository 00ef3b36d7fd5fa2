"""`geofuse index`: folders of clips indexed into a GeoParquet archive (app.archive); each clip
that failed is said with why (a warning), and a run that indexed nothing at all is an error
(exit status 2, the archive not written)."""

from __future__ import annotations

import argparse
import sys

from app.archive import index_archive
from app.core.errors import GeofuseError
from app.core.outputs import check_output
from app.world.overpass import is_overpass


def run(args: argparse.Namespace) -> int:
    out = check_output(args.out, "--out", (".parquet",))
    if any(is_overpass(b) for b in args.buildings or ()):
        raise GeofuseError(
            "--buildings overpass: is fetched as a clip opens (view, solve, export...): for index, "
            "pre-fetch it (geofuse cache CLIP --buildings overpass: --out AREA.mbtiles) and give "
            "--buildings AREA-buildings.osm"
        )
    for folder in args.folders:
        if not folder.exists():
            raise GeofuseError(f"{folder}: no such folder or file")

    def progress(done: int, failed: int, total: int, left_s: float) -> None:
        if sys.stderr.isatty():
            print(
                f"\rindex: {done}/{total} clips, {failed} failed, about {left_s:.0f} s left",
                end="",
                file=sys.stderr,
            )

    report = index_archive(
        list(args.folders),
        out,
        args.every_s,
        tuple(args.scene or ()) + tuple(args.buildings or ()),
        args.source,
        args.workers,
        args.scheduler,
        progress,
    )
    if sys.stderr.isatty():
        print(file=sys.stderr)
    for _, why in report.failures:
        print(f"warning: skipped {' '.join(why.split())}", file=sys.stderr)
    print(f"wrote {out}: {report.line()}")
    return 0
