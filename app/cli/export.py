"""`geofuse export`: footprints, an FMV CSV, KLV or the fused video of a session or clip
(app.export.jobs)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli.common import open_with_source, print_messages, print_scene_report, solved
from app.export import EXPORT_SUFFIXES
from app.export.jobs import ExportOptions, export_session
from app.outputs import IMAGE_SUFFIXES, check_output
from app.progress import ProgressBar


def run(args: argparse.Namespace) -> int:
    suffixes = EXPORT_SUFFIXES[args.what]
    check_output(args.out, "--out", suffixes, [args.input, args.srt])
    if args.preview is not None:
        check_output(args.preview, "--preview", IMAGE_SUFFIXES, [args.input, args.srt, args.out])
    session, source = open_with_source(args.input, args, suffixes)
    print_messages(session)
    track = solved(session, source)
    options = ExportOptions(
        every=args.every,
        size=args.size,
        view=args.view,
        start_s=args.start,
        end_s=args.end,
        preview=args.preview,
        name=Path(args.input).stem,
    )
    line = export_session(
        args.what,
        session,
        source,
        track,
        Path(args.out),
        options,
        ProgressBar(f"export {args.what}", sys.stderr),
    )
    print_messages(session)
    print_scene_report(session.scene())
    print(line)
    return 0
