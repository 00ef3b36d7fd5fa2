"""`geofuse export`: footprints, an FMV CSV, KLV, the fused video, the true orthophoto or the
painted model of a session or clip (app.export.jobs, app.export.orthophoto, app.export.painted)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from app.cli.common import (
    open_further,
    open_with_source,
    print_messages,
    print_scene_report,
    solved,
)
from app.core.constants import ORTHO_KEYFRAMES_S
from app.core.errors import GeofuseError
from app.core.outputs import IMAGE_SUFFIXES, check_output
from app.core.progress import ProgressBar
from app.export import EXPORT_SUFFIXES
from app.export.jobs import ExportOptions, export_session, write_footprints
from app.export.orthophoto import OrthoOptions, paint_clip, write_orthophoto
from app.export.painted import (
    ModelOptions,
    atlas_part,
    paint_model,
    paint_model_paged,
    write_painted,
)
from app.export.painted_tiles import atlas_tiles, page_tiles, write_painted_tiles
from app.export.records import frame_records
from app.geodesy.crs import parse_crs
from app.io.area import read_area
from app.scene.layers import scene_credit
from app.session.config import ClipRef


def _area(path: Path | None) -> tuple[float, float, float, float] | None:
    """(lat_min, lon_min, lat_max, lon_max) degrees: the box of a GeoJSON file's polygons."""
    if path is None:
        return None
    lon0, lat0, lon1, lat1 = read_area(path, "--area").bounds
    return lat0, lon0, lat1, lon1


def keyframes_s(args: argparse.Namespace) -> float | None:
    """The `registered` source's seconds between keyframes for ortho and model: --keyframes-s,
    else ORTHO_KEYFRAMES_S for an orthophoto (a survey's poses hold the orthophoto within its
    goal at half the registration's time: docs/ACCURACY.md), else registration's default."""
    if args.keyframes_s is not None:
        return args.keyframes_s
    return ORTHO_KEYFRAMES_S if args.what == "ortho" else None


def _solved_further(args: argparse.Namespace, inputs: list[Path], suffixes) -> list:
    """(session, solved track) of the further inputs, each under --source where it offers it,
    else its own first."""
    out = []
    for path in inputs:
        session, source = open_with_source(path, args, suffixes, any_source=True)
        print_messages(session)
        out.append((session, solved(session, source, keyframes_s(args))))
    return out


def _ortho(args: argparse.Namespace, inputs: list[Path], suffixes, bar: ProgressBar) -> int:
    """`export ortho`: the true orthophoto of the clips (app.export.orthophoto)."""
    input_path = inputs[0]
    session, source = open_with_source(input_path, args, suffixes)
    print_messages(session)
    further = _solved_further(args, inputs[1:], suffixes)
    try:
        crs = None if args.crs is None else parse_crs(args.crs)
    except ValueError as exc:
        raise GeofuseError(f"--crs: {exc}") from exc
    options = OrthoOptions(args.gsd, crs, _area(args.area), args.rule, args.every_s)
    try:
        track = solved(session, source, keyframes_s(args))
        memory = paint_clip(session, track, options, bar, further=further)
    except ValueError as exc:
        raise GeofuseError(f"export ortho {input_path}: {exc}") from exc
    read = [*session.inputs, *(p for s, _ in further for p in s.inputs)]
    out, seen = write_orthophoto(memory, Path(args.out), read, scene_credit(session.layers))
    g = memory.grid
    covered = 100.0 * memory.seen.sum() / max(1, np.isfinite(memory.points[..., 2]).sum())
    print(
        f"wrote {out} ({g.shape[1]} x {g.shape[0]} cells of {g.gsd:g} m in {g.crs.name}, "
        f"{covered:.0f} % of the surface seen, {memory.frames} frames of {len(inputs)} clip(s), rule {memory.rule}) "
        f"and {seen} (seen at, quality)"
    )
    return 0


def _model(args: argparse.Namespace, inputs: list[Path], suffixes, bar: ProgressBar) -> int:
    """`export model`: the scene with the clips painted on it (app.export.painted)."""
    input_path = inputs[0]
    session, source = open_with_source(input_path, args, suffixes)
    print_messages(session)
    further = _solved_further(args, inputs[1:], suffixes)
    options = ModelOptions(args.rule, args.every_s, args.max_texels, args.finest_m, args.memory_mb)
    f = session.frame
    read = [*session.inputs, *(p for s, _ in further for p in s.inputs)]
    origin = (f.lat_deg, f.lon_deg, f.h_m)
    tiles = Path(args.out).suffix.lower() == ".json"  # a 3D Tiles tileset
    credit = scene_credit(session.layers)  # its asset.copyright: the world's providers
    try:
        if options.max_texels is not None:
            atlas, memory = paint_model(
                session, solved(session, source, keyframes_s(args)), options, bar, further
            )
        else:
            paged = paint_model_paged(
                session, solved(session, source, keyframes_s(args)), options, bar, further
            )
    except ValueError as exc:
        raise GeofuseError(f"export model {input_path}: {exc}") from exc
    if options.max_texels is not None:
        w, h = atlas.size
        said = (
            f"{len(atlas.triangles):,} triangles, a {w} x {h} atlas of {atlas.texel_m:.2f} m texels and coarser, "
            f"{100.0 * memory.seen.mean():.0f} % of the surface seen, {memory.frames} frames of {len(inputs)} clip(s), rule {memory.rule}"
        )
        parts = atlas_tiles(atlas, memory) if tiles else [atlas_part(atlas, memory)]
    else:
        said = (
            f"{len(paged.triangles):,} triangles in {len(paged.pages):,} pages of {paged.texel_m:.2f} m texels and coarser "
            f"(the video's ground sampling), {paged.frames} frames of {len(inputs)} clip(s), rule {paged.rule}"
        )
        parts = page_tiles(paged)
    try:
        if tiles:
            out, n = write_painted_tiles(parts, f, Path(args.out), read, credit)
            where = f"{n} tiles beside it"
        else:
            out = write_painted(parts, origin, Path(args.out), read, credit)
            where = f"local east-north-up from {f.lat_deg:.7f}, {f.lon_deg:.7f}, {f.h_m:.2f} m, glTF Y-up"
        if options.max_texels is None:
            seen, samples = paged.seen_count()
            said += f"; {100.0 * seen / max(1, samples):.0f} % of the surface seen; paging: {paged.stats.said()}"
    finally:
        if options.max_texels is None:
            paged.close()
    print(f"wrote {out} ({said}; {where})")
    return 0


def run(args: argparse.Namespace) -> int:
    inputs = list(args.input)
    if len(inputs) > 1 and args.what not in ("footprints", "video", "ortho", "model"):
        raise GeofuseError(
            f"export {args.what}: one input at a time (several inputs: footprints, each with its clip; video, all drawn; ortho and model, all painted)"
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
        return _ortho(args, inputs, suffixes, bar)
    if args.what == "model":
        return _model(args, inputs, suffixes, bar)
    if len(inputs) == 1 or args.what == "video":
        session, source = open_with_source(inputs[0], args, suffixes)
        print_messages(session)
        further = []
        refs = [ClipRef(p) for p in inputs[1:]] if args.what == "video" else []
        named = len(refs)
        refs += list(session.further) if args.what == "video" else []
        for k, ref in enumerate(refs):  # further clips drawn in the video
            key = f"clips[{k - named}].source"  # the manifest's [[clips]] table, from 0
            s, src = open_further(ref, args, suffixes, session.path, key)
            print_messages(s)
            further.append((s, solved(s, src), ref.offset_s, ref.priority))
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
