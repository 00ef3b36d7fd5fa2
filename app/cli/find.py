"""`geofuse find`: the clips of an archive that saw a place, and when (app.archive); --open
starts the viewer on the best of them."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import shapely
from shapely.geometry import shape

from app.archive import find, place_of
from app.core.errors import DataFormatError, GeofuseError
from app.ui.viewer import Options, Viewer


def _polygon(path: Path) -> shapely.Geometry:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        geometry = doc["features"][0]["geometry"] if "features" in doc else doc.get("geometry", doc)
        polygon = shape(geometry)
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError) as exc:
        raise DataFormatError(path, f"expected a GeoJSON Polygon ({exc})") from exc
    if polygon.geom_type not in ("Polygon", "MultiPolygon") or not polygon.is_valid:
        raise DataFormatError(path, f"expected a valid Polygon, got a {polygon.geom_type}")
    return polygon


def run(args: argparse.Namespace) -> int:
    if not args.archive.is_file():
        raise GeofuseError(
            f"{args.archive}: archive does not exist (make one with `geofuse index`)"
        )
    place = place_of(args.point, args.radius, _polygon(args.polygon) if args.polygon else None)
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
