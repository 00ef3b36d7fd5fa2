"""`geofuse export`: footprints, an FMV CSV, KLV or the fused video of a session or clip
(app.export.jobs)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli.common import open_with_source, print_messages, print_scene_report, solved
from app.core.errors import GeofuseError
from app.core.outputs import IMAGE_SUFFIXES, check_output
from app.core.progress import ProgressBar
from app.export import EXPORT_SUFFIXES
from app.export.jobs import ExportOptions, export_session, write_footprints
from app.export.records import frame_records


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
