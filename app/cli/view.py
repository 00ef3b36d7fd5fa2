"""`geofuse view`: the interactive viewer (app.ui.viewer)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from app.cli.common import layers, start_area
from app.core.errors import GeofuseError
from app.live.feed import LiveOptions
from app.live.probe import mavlink_refusal, stream_refusal
from app.live.receiver import protocols_missing
from app.share.tak import cot_targets
from app.ui.live import is_stream
from app.ui.script import parse_script
from app.ui.viewer import Options, Viewer


def run(args: argparse.Namespace) -> int:
    if args.script is not None:
        parse_script(args.script)  # a bad script is refused before a window opens
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    inputs = list(args.manifest or [])
    streams = [x for x in inputs if is_stream(x)]
    if streams and len(inputs) > 1:
        raise GeofuseError(
            f"{streams[0]}: a stream opens alone (its recording, a clip, plays with others afterwards)"
        )
    stream = streams[0] if streams else None
    if stream is not None:
        # what cannot open (a protocol FFmpeg lacks, a port that is not a port) is said before
        # a window opens, as `geofuse live` says it
        refused = (
            protocols_missing(stream)
            or stream_refusal(stream)
            or (args.mavlink and mavlink_refusal(args.mavlink))
        )
        if refused:
            raise GeofuseError(refused)
    live = LiveOptions(
        delay_s=args.buffer_ms / 1000.0,
        origin=tuple(args.origin) if args.origin else None,
        search_radius_m=args.search_radius,
        mavlink=args.mavlink,
        hfov_deg=args.fov,
        register=args.register,
        gnss_accuracy_m=args.gnss_accuracy,
    )
    # Cursor on Target out: its certificate files checked before a window opens
    cot = cot_targets(args.cot, args.cot_cert, args.cot_key, args.cot_ca, args.cot_callsign)
    paths = [Path(x) for x in inputs if not is_stream(x)]
    return Viewer(
        Options(
            paths[0] if paths else None,
            args.size,
            args.script,
            args.screenshot,
            args.play,
            srt=args.srt,
            lens=args.lens,
            layers=layers(args, clip=not (paths and paths[0].suffix.lower() == ".toml")),
            more=tuple(paths[1:]),
            stream=stream,
            live=live,
            sinks=cot.makers(),
            start=start_area(args),
        )
    ).run()
