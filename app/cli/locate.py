"""`geofuse locate`: where pixels of a video frame (a session or clip at --time) or of a still
(--scene, --image, --pose, --fov/--lens) lie on the scene (app.locate.location)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

from app.camera.frame_time import frame_at
from app.cli.common import open_with_source, print_messages, print_scene_report, solved, still_scene
from app.core.constants import DEFAULT_NEAR_M
from app.core.errors import DataFormatError, GeofuseError
from app.locate.location import LOCATE_FAR_M, Location, Locator
from app.solve.uncertainty import pose_sigmas


def read_pixels(path: Path) -> list[tuple[float, float]]:
    """X,Y pixel coordinates from a CSV, a header line optional. Raises DataFormatError naming
    the line."""
    if not path.is_file():
        raise DataFormatError(path, "pixel file does not exist")
    out = []
    with path.open(newline="", encoding="utf-8-sig") as f:
        for n, row in enumerate(csv.reader(f), start=1):
            if not row or not "".join(row).strip():
                continue
            try:
                x, y = (float(v) for v in row[:2])
            except ValueError as exc:
                if n == 1:
                    continue  # a header
                raise DataFormatError(path, f"expected X,Y numbers, got {row!r}", line=n) from exc
            if not (np.isfinite(x) and np.isfinite(y)):
                raise DataFormatError(path, f"expected finite X,Y, got {row!r}", line=n)
            out.append((x, y))
    if not out:
        raise DataFormatError(path, "no X,Y pixel in the file")
    return out


def _pixels(args: argparse.Namespace) -> list[tuple[float, float]]:
    pixels = [tuple(p) for p in args.pixel or []]
    if args.pixels is not None:
        pixels += read_pixels(args.pixels)
    if not pixels:
        raise GeofuseError("locate: give --pixel X,Y (repeatable) or --pixels FILE.csv")
    return pixels


def run(args: argparse.Namespace) -> int:
    pixels = _pixels(args)
    if args.input is not None:
        if args.time is None:
            raise GeofuseError(
                "locate SESSION|CLIP needs --time T (seconds from the video's first frame)"
            )
        session, source = open_with_source(args.input, args, (".csv",))
        pts = session.video.pts_s
        if not pts[0] - 0.5 <= args.time <= pts[-1] + 0.5:
            raise GeofuseError(
                f"--time {args.time:g}: the video runs from {pts[0]:.3f} to {pts[-1]:.3f} s"
            )
        print_messages(session)
        track = solved(session, source).with_clip(DEFAULT_NEAR_M, LOCATE_FAR_M)
        index = frame_at(pts, args.time)
        camera, mesh, frame = track.frame_camera(index), session.scene(), session.frame
        sigmas = pose_sigmas(session, track, index)
        where = f"frame {index} at {pts[index]:.3f} s, attitude from {source}"
    else:
        scene = still_scene(args, "locate: give SESSION|CLIP --time T, or all of", LOCATE_FAR_M)
        camera, mesh, frame, sigmas = scene.camera, scene.loaded.mesh, scene.frame, None
        where = f"the still {args.image[0]}"
    locator = Locator(mesh, frame)
    try:
        found: list[Location | None | str] = []
        for p in pixels:
            try:
                found += locator.locate(camera, [p], sigmas)
            except ValueError as exc:
                found.append(str(exc))
    finally:
        locator.release()
    print_scene_report(mesh)
    failed = 0
    rows = []
    for p, f in zip(pixels, found, strict=True):
        if isinstance(f, Location):
            rows.append(f.as_dict())
            if not args.json:
                print(f.line())
            continue
        failed += 1
        reason = f if isinstance(f, str) else "meets nothing of the scene (the sky)"
        rows.append({"pixel": list(p), "error": reason})
        if not args.json:
            print(
                f"pixel {p[0]:g},{p[1]:g}: {reason}",
                file=sys.stderr if isinstance(f, str) else sys.stdout,
            )
    if args.json:
        print(json.dumps(rows, allow_nan=False))
    else:
        print(f"({where}; uncertainty: {sigmas.why})" if sigmas else f"({where})", file=sys.stderr)
    return 1 if failed else 0
