"""`geofuse sync`: the video's time offset (and drift) against the sensors (app.sync), written
beside the input with --write."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli.common import print_messages
from app.core.constants import SYNC_MIN_CONFIDENCE
from app.core.outputs import check_output, write_atomically
from app.core.progress import ProgressBar
from app.footage.clips import open_for_sync
from app.sync import settings_path, settings_text, sync_session, timed_by


def run(args: argparse.Namespace) -> int:
    session, base = open_for_sync(args.input, args.lens)
    print_messages(session)
    result = sync_session(session, ProgressBar("optical flow", sys.stderr))
    print(
        f"{args.input}: the video's times need {1000 * result.offset_s:+.1f} ms (confidence {result.confidence:.3f}; coarse {1000 * result.coarse_s:+.0f} ms), timed by {timed_by(session)}"
    )
    for line in result.report(float(session.frame_times[0])):
        print(line)
    if args.write and result.confidence < SYNC_MIN_CONFIDENCE and not args.force:
        print(
            f"not written: confidence {result.confidence:.3f} is below {SYNC_MIN_CONFIDENCE} (the video's rotation hardly "
            "follows the reference: stabilised video, too little turning, or the wrong clip); --force keeps it anyway",
            file=sys.stderr,
        )
        return 1
    if args.write:
        out = check_output(
            settings_path(Path(args.input)), "--write", (".toml",), list(session.inputs)
        )
        write_atomically(
            out, "--write", lambda f: f.write(settings_text(result, base + result.offset_s))
        )
        print(f'wrote {out}: a manifest with video.time_offset_s = "auto" reads it')
    return 0
