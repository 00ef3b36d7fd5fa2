"""`geofuse simulate scene|session|city|photo|feed`: the sample data (app.simulate)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from app.core.errors import GeofuseError
from app.core.imageio import write_rgb
from app.geodesy.enu import LocalFrame
from app.scene import load_scene
from app.simulate import drone
from app.simulate.autopilot import MavlinkSender
from app.simulate.city import site_buildings, write_citygml, write_cityjson, write_cityjsonseq
from app.simulate.feed import Sender, write_feed
from app.simulate.photo import make_photo, photo_camera
from app.simulate.sample import SAMPLE_ORIGIN, SAMPLE_PHOTO_POSE, SAMPLE_SCENE
from app.simulate.session import SampleConfig, write_sample_session
from app.simulate.stadium import write_site

MAVLINK_LEAD_S = 0.3  # the simulated telemetry leaves this much ahead of its video


def scene(args: argparse.Namespace) -> int:
    out = write_site(args.out, seed=args.seed)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return 0


def city(args: argparse.Namespace) -> int:
    out = Path(args.out)
    buildings, relief, crs = site_buildings(LocalFrame(*SAMPLE_ORIGIN))
    name = out.name.lower()
    if name.endswith(".city.json"):
        write_cityjson(out, buildings, crs, relief=relief)
        ground = " and its ground (a TINRelief)"
    elif name.endswith(".city.jsonl"):
        write_cityjsonseq(out, buildings, crs)
        ground = ""
    elif name.endswith(".gml"):
        write_citygml(out, buildings, crs)
        ground = ""
    else:
        raise GeofuseError(f"--out {out}: expected a .city.json, .city.jsonl or .gml file")
    print(f"wrote {out}: {len(buildings)} LoD2 buildings{ground} in {crs} (no texture)")
    return 0


def photo(args: argparse.Namespace) -> int:
    frame = LocalFrame(*SAMPLE_ORIGIN)
    mesh = load_scene(args.scene, frame)
    out = write_rgb(args.out, make_photo(mesh, photo_camera(SAMPLE_PHOTO_POSE, frame)))
    print(f"wrote {out}")
    return 0


def session(args: argparse.Namespace) -> int:
    site = args.scene or SAMPLE_SCENE
    if not Path(site).is_file():
        raise GeofuseError(
            f"{site}: scene file does not exist (make one with `geofuse simulate scene`)"
        )
    manifest = write_sample_session(
        args.out,
        site,
        SampleConfig(
            seed=args.seed,
            duration_s=args.duration,
            world=not args.model_world,
            flight=args.flight,
            city=args.city,
        ),
    )
    total = sum(p.stat().st_size for p in Path(args.out).iterdir() if p.is_file())
    print(f"wrote {manifest} ({total / 1e6:.1f} MB in {args.out})")
    return 0


def _address(text: str, option: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise GeofuseError(f"{option} {text}: expected HOST:PORT")
    return host, int(port)


def feed(args: argparse.Namespace) -> int:
    mavlink_to = _address(args.mavlink, "--mavlink") if args.mavlink else None
    if args.no_fix and mavlink_to is None:
        raise GeofuseError("--no-fix goes with --mavlink (a KLV feed's positions are its own)")
    if mavlink_to is not None:
        if args.klv_hz is not None:
            raise GeofuseError("--klv-hz: an autopilot's feed (--mavlink) carries no KLV")
        out = drone.write_video(args.out, args.seconds, tuple(args.size))
    else:
        out = write_feed(args.out, args.seconds, tuple(args.size), klv_hz=args.klv_hz)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {args.seconds:g} s)", flush=True)
    if args.send is None:
        return 0
    host, port = _address(args.send, "--send")
    sender = Sender(out.read_bytes(), (host, port), loss=args.loss)
    telemetry = None
    if mavlink_to is not None:
        telemetry = MavlinkSender(
            mavlink_to, args.seconds, time.monotonic(), MAVLINK_LEAD_S,
            fixed=not args.no_fix, home=args.no_fix,
        )  # fmt: skip
        telemetry.start()
    sender.start()
    beside = f", MAVLink to {args.mavlink}" if telemetry is not None else ""
    print(f"sending to udp://{host}:{port} in real time{beside}", flush=True)
    try:
        sender.join()
        if telemetry is not None:
            telemetry.join()
    except KeyboardInterrupt:
        sender.stop()
    finally:
        if telemetry is not None:
            telemetry.stop()
    more = f", {telemetry.sent} MAVLink messages" if telemetry is not None else ""
    print(f"sent {sender.datagrams} datagrams, {sender.dropped} dropped on purpose{more}")
    return 0
