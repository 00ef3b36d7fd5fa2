"""`geofuse live URL`: a live feed received, recorded, drawn off screen (app.live.run) and sent on
with geofuse's poses as KLV (`--restream`, app.live.restream), one summary line at the end."""

from __future__ import annotations

import argparse
import sys

from app.cli.common import layers
from app.core.errors import GeofuseError
from app.core.outputs import check_output
from app.live.probe import mavlink_refusal, stream_refusal
from app.live.restream import restream_refusal
from app.live.run import LiveOptions, run_live
from app.share.tak import cot_targets


def run(args: argparse.Namespace) -> int:
    if "://" not in args.url:
        raise GeofuseError(
            f"{args.url}: expected a stream URL (udp://HOST:PORT, rtp://, rtsp://, srt://); a recorded file opens with view, solve or export"
        )
    # a port that is not a port never opens: said now, not retried until --for ends
    refused = (
        stream_refusal(args.url)
        or (args.mavlink and mavlink_refusal(args.mavlink))
        or (args.restream and restream_refusal(args.restream))
    )
    if refused:
        raise GeofuseError(refused)
    record = check_output(args.record, "--record", (".ts",), []) if args.record else None
    # Cursor on Target out: its certificate files checked now, before anything is received
    cot = cot_targets(args.cot, args.cot_cert, args.cot_key, args.cot_ca, args.cot_callsign)
    options = LiveOptions(
        seconds=args.seconds,
        record=record,
        delay_s=args.buffer_ms / 1000.0,
        size=tuple(args.size),
        layers=layers(args),
        origin=tuple(args.origin) if args.origin else None,
        search_radius_m=args.search_radius,
        mavlink=args.mavlink,
        hfov_deg=args.fov,
        register=args.register,
        gnss_accuracy_m=args.gnss_accuracy,
        restream=args.restream,
        sinks=cot.makers(),
    )
    beside = f", MAVLink from {args.mavlink}" if args.mavlink else ""
    beside += f", restreamed to {args.restream}" if args.restream else ""
    beside += "".join(f", CoT to {t}" for t in args.cot)
    print(f"receiving {args.url} (jitter buffer {args.buffer_ms:g} ms){beside}", flush=True)
    result = run_live(args.url, options)
    for m in result.messages.since(0):
        print(m, file=sys.stderr)
    print("; ".join([result.summary(), *cot.lines()]))  # the events sent to each CoT target
    if record is not None:
        print(f"recorded {record}")
    return 0 if result.drawn else 1
