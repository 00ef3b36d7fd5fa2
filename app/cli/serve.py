"""`geofuse serve INPUT`: the browser map (app.share.web) of a clip played in real time from its
solved track (app.share.replay), or of a live feed received and drawn off screen (app.live.run),
through the sharing hub (app.share.hub); no window. Prints the map's URL with its access token,
then runs until Ctrl-C, --for, or the end of --once."""

from __future__ import annotations

import argparse
import math
import signal
import sys
from pathlib import Path

from app.cli.common import layers, open_with_source, print_messages, solved
from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.live.probe import mavlink_refusal, stream_refusal
from app.live.receiver import protocols_missing
from app.live.run import LiveOptions, run_live
from app.share.hub import Share
from app.share.replay import replay, session_marks
from app.share.web import MapServer, WebMapSink, parse_bind, web_sink_maker
from app.world.settings import choose_world

STREAM_DRAWING = (320, 180)  # a stream's off-screen drawing: nobody sees it, the map needs none


def run(args: argparse.Namespace) -> int:
    stream = "://" in args.input
    if stream:
        refused = (
            protocols_missing(args.input)
            or stream_refusal(args.input)
            or (args.mavlink and mavlink_refusal(args.mavlink))
        )
        if refused:
            raise GeofuseError(refused)
    elif not Path(args.input).exists():
        raise GeofuseError(
            f"{args.input}: no such file (expected a manifest, a clip or a stream URL)"
        )
    # Ctrl-C is how serve stops: taken even where the shell started it with SIGINT ignored (a
    # background job of a script), which Python would otherwise keep
    signal.signal(signal.SIGINT, signal.default_int_handler)
    server = _server(args)
    said = Printer(server.messages)
    print(f"the browser map: {server.url}", flush=True)
    if server.warning:
        print(f"warning: {server.warning}", file=sys.stderr, flush=True)
    try:
        if stream:
            _stream(args, server, said)
        else:
            _clip(args, server, said)
    except KeyboardInterrupt:
        print("stopped (Ctrl-C)", flush=True)
    finally:
        server.close()
        said()
    return 0


class Printer:
    """Prints to stderr what `messages` said since the last call (the map's refusals, tile
    faults), each with its level."""

    def __init__(self, messages: Messages) -> None:
        self.messages, self.done = messages, 0

    def __call__(self) -> None:
        new = self.messages.since(self.done)
        self.done += len(new)
        for m in new:
            print(m, file=sys.stderr, flush=True)


def _server(args: argparse.Namespace) -> MapServer:
    """The map's server, listening: its imagery the world --world/--imagery (or the settings'
    default) names, whatever the scene."""
    try:
        bind = parse_bind(args.bind)
    except ValueError as exc:
        raise GeofuseError(f"--bind: {exc}") from exc
    world = choose_world(args.world, args.imagery, args.terrain)
    try:
        server = MapServer(
            bind,
            args.token,
            None if world is None else world.imagery,
            "" if world is None else world.attribution,
        )
    except ValueError as exc:
        raise GeofuseError(f"--token: {exc}") from exc
    try:
        return server.start()
    except OSError as exc:
        raise GeofuseError(
            f"--bind {args.bind}: cannot listen there: {exc.strerror or exc}"
        ) from exc


def _stream(args: argparse.Namespace, server: MapServer, said: Printer) -> None:
    """The live feed drawn off screen with the map's sink, through silences, until --for or
    Ctrl-C."""
    options = LiveOptions(
        seconds=args.seconds,
        delay_s=args.buffer_ms / 1000.0,
        size=STREAM_DRAWING,
        layers=layers(args),
        origin=tuple(args.origin) if args.origin else None,
        search_radius_m=args.search_radius,
        mavlink=args.mavlink,
        hfov_deg=args.fov,
        register=args.register,
        gnss_accuracy_m=args.gnss_accuracy,
        silence_s=math.inf,  # a link that drops comes back: keep serving
        sinks=(web_sink_maker(server),),
    )
    print(f"receiving {args.input} (jitter buffer {args.buffer_ms:g} ms)", flush=True)
    result = run_live(args.input, options, on_drawn=lambda d, camera: said())
    for m in result.messages.since(0):
        print(m, file=sys.stderr)
    print(result.summary())


def _clip(args: argparse.Namespace, server: MapServer, said: Printer) -> None:
    """The clip played in real time from its solved track, with the marks kept beside it."""
    path = Path(args.input)
    manifest = path.suffix.lower() == ".toml"
    # a manifest names its own scene: --world and --imagery are the map's imagery alone
    opened = (
        argparse.Namespace(**{**vars(args), "world": "none", "imagery": None, "terrain": None})
        if manifest
        else args
    )
    session, source = open_with_source(path, opened, ())
    print_messages(session)
    track = solved(session, source)
    share = Share(
        session.scene(),
        session.frame,
        session.intrinsics,
        [WebMapSink(server)],
        session.messages,
        lens=session.lens,
    ).start()
    try:
        marks = session_marks(session)
        if marks is not None:
            share.set_marks(marks)
            print(f"marks: {len(marks['features'])} from beside {path.name}", flush=True)
        print(
            f"playing {path.name} in real time ({source}, {len(track.clock.media_s)} frames"
            + (", once)" if args.once else ", again and again; Ctrl-C stops)"),
            flush=True,
        )
        done = replay(session, track, share, args.once, args.seconds, tick=said)
    finally:
        share.close()
    print_messages(session)
    print(
        f"{path.name}: {done.offered} frames offered in {done.passes} pass"
        f"{'' if done.passes == 1 else 'es'}, {share.shared} shared on the map; {done.ended}"
    )
