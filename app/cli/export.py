"""`geofuse export`: footprints, an FMV CSV, KLV, the fused video, the true orthophoto or the
painted model of a session or clip (app.export.jobs, app.export.orthophoto, app.export.painted)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import shapely.geometry

from app.cli.common import open_with_source, print_messages, print_scene_report, solved
from app.core.errors import DataFormatError, GeofuseError
from app.core.outputs import IMAGE_SUFFIXES, check_output
from app.core.progress import ProgressBar
from app.export import EXPORT_SUFFIXES
from app.export.jobs import ExportOptions, export_session, write_footprints
from app.export.orthophoto import OrthoOptions, paint_clip, write_orthophoto
from app.export.painted import ModelOptions, paint_model, write_painted
from app.export.records import frame_records
from app.geodesy.crs import parse_crs


def _area(path: Path | None) -> tuple[float, float, float, float] | None:
    """(lat_min, lon_min, lat_max, lon_max) of a GeoJSON file's geometries (WGS84)."""
    if path is None:
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        features = doc.get("features", [doc]) if isinstance(doc, dict) else []
        geometries = [f.get("geometry", f) for f in features]
        bounds = np.array([shapely.geometry.shape(g).bounds for g in geometries if g])
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError, ValueError) as exc:
        raise DataFormatError(path, f"not a GeoJSON area ({exc})", field="--area") from exc
    if not len(bounds):
        raise DataFormatError(path, "no geometry (expected a polygon in WGS84)", field="--area")
    return (
        float(bounds[:, 1].min()),
        float(bounds[:, 0].min()),
        float(bounds[:, 3].max()),
        float(bounds[:, 2].max()),
    )


def _ortho(args: argparse.Namespace, input_path: Path, suffixes, bar: ProgressBar) -> int:
    """`export ortho`: the clip's true orthophoto (app.export.orthophoto)."""
    session, source = open_with_source(input_path, args, suffixes)
    print_messages(session)
    try:
        crs = None if args.crs is None else parse_crs(args.crs)
    except ValueError as exc:
        raise GeofuseError(f"--crs: {exc}") from exc
    options = OrthoOptions(args.gsd, crs, _area(args.area), args.rule, args.every_s)
    try:
        memory = paint_clip(session, solved(session, source), options, bar)
    except ValueError as exc:
        raise GeofuseError(f"export ortho {input_path}: {exc}") from exc
    out, seen = write_orthophoto(memory, Path(args.out), list(session.inputs))
    g = memory.grid
    covered = 100.0 * memory.seen.sum() / max(1, np.isfinite(memory.points[..., 2]).sum())
    print(
        f"wrote {out} ({g.shape[1]} x {g.shape[0]} cells of {g.gsd:g} m in {g.crs.name}, "
        f"{covered:.0f} % of the surface seen, {memory.frames} frames, rule {memory.rule}) "
        f"and {seen} (seen at, quality)"
    )
    return 0


def _model(args: argparse.Namespace, input_path: Path, suffixes, bar: ProgressBar) -> int:
    """`export model`: the scene with the clip painted on it (app.export.painted)."""
    session, source = open_with_source(input_path, args, suffixes)
    print_messages(session)
    options = ModelOptions(args.rule, args.every_s, args.max_texels)
    try:
        atlas, memory = paint_model(session, solved(session, source), options, bar)
    except ValueError as exc:
        raise GeofuseError(f"export model {input_path}: {exc}") from exc
    f = session.frame
    out = write_painted(
        atlas, memory, (f.lat_deg, f.lon_deg, f.h_m), Path(args.out), list(session.inputs)
    )
    w, h = atlas.size
    print(
        f"wrote {out} ({len(atlas.triangles):,} triangles, a {w} x {h} atlas of {atlas.texel_m:.2f} m texels, "
        f"{100.0 * memory.seen.mean():.0f} % of the surface seen, {memory.frames} frames, rule {memory.rule}; "
        f"local east-north-up from {f.lat_deg:.7f}, {f.lon_deg:.7f}, {f.h_m:.2f} m, glTF Y-up)"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    inputs = list(args.input)
    if len(inputs) > 1 and args.what not in ("footprints", "video"):
        raise GeofuseError(
            f"export {args.what}: one input at a time (several inputs: footprints, each with its clip, or video, all drawn)"
        )
    suffixes = EXPORT_SUFFIXES[args.what]
    check_output(args.out, "--out", suffixes, [*inputs, args.srt])
    if args.preview is not None:
        check_output(args.preview, "--preview", IMAGE_SUFFIXES, [*inputs, args.srt, args.out])
    options = ExportOptions(
        every=args.every,
        size=args.size,
        view=args.view,
        start_s=args.start,
        end_s=args.end,
        preview=args.preview,
        name=Path(inputs[0]).stem,
    )
    bar = ProgressBar(f"export {args.what}", sys.stderr)
    if args.what == "ortho":
        return _ortho(args, inputs[0], suffixes, bar)
    if args.what == "model":
        return _model(args, inputs[0], suffixes, bar)
    if len(inputs) == 1 or args.what == "video":
        session, source = open_with_source(inputs[0], args, suffixes)
        print_messages(session)
        further = []
        refs = [(p, 0.0, 0.0) for p in inputs[1:]] if args.what == "video" else []
        refs += (
            [(r.path, r.offset_s, r.priority) for r in session.further]
            if args.what == "video"
            else []
        )
        for path, offset, priority in refs:  # further clips drawn in the video
            s, src = open_with_source(path, args, suffixes, any_source=True)
            print_messages(s)
            further.append((s, solved(s, src), offset, priority))
        line = export_session(
            args.what,
            session,
            source,
            solved(session, source),
            Path(args.out),
            options,
            bar,
            tuple(further),
        )
        print_messages(session)
        print_scene_report(session.scene())
        print(line)
        return 0
    records, read, first = [], [], None
    for path in inputs:  # several clips: each its own session, source and scene
        session, source = open_with_source(path, args, suffixes)
        print_messages(session)
        track = solved(session, source)
        records += list(frame_records(session, source, args.every, progress=bar, track=track))
        print_messages(session)
        print_scene_report(session.scene())
        read += list(session.inputs)
        first = first or session
    print(write_footprints(records, Path(args.out), options, read, first))
    return 0
