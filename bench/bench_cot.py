"""Cursor on Target benchmark (issue 53): the delay from a frame offered to the sharing hub (as the
drawing loop offers each frame it drew) to its CoT events received, on the loopback, to a UDP
receiver, a TCP one and a TLS one that requires a client certificate (the test's authority,
tests/cot_listener.py), one transport a run.

A drone orbits the flat ground (app.simulate.feed.Orbit: 150 m out, 80 m up, its sensor on the
centre); its camera is offered 30 times a second with a 1280x720 picture (the hub casts the
newest at most 5 times a second, makes a thumbnail and hands the SharedFrame to the sink, which
sends the aircraft and its point of interest at most twice a second and the footprint once).
The delay of an event: from the offer of its frame (matched by the frame index the event
carries) to its arrival at the receiver, both on this process's monotonic clock; it includes
the hub's wait for its next turn (up to 200 ms at 5 Hz), its cast of the footprint on the scene
(an off-screen GL pass), the event's making, the sink's queue and the socket.

    python bench/bench_cot.py [--seconds 20] [--json out/bench_cot.json]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lxml import etree  # noqa: E402

from app.camera.intrinsics import Intrinsics  # noqa: E402
from app.camera.pinhole import Camera, look_at_quat  # noqa: E402
from app.core.messages import Messages  # noqa: E402
from app.scene.ground_plane import ground_plane  # noqa: E402
from app.share.cot import KIND_AIRCRAFT, KIND_FOOTPRINT, KIND_POI  # noqa: E402
from app.share.hub import Offer, Share  # noqa: E402
from app.share.tak import TakSink, cot_targets  # noqa: E402
from app.share.target import parse_target  # noqa: E402
from app.simulate.feed import Orbit  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402
from tests.cot_listener import P12_PASSWORD, Listener, make_pki  # noqa: E402

FPS = 30.0
SIZE = (1280, 720)
TYPES = {"a-f-A-M-F-Q": KIND_AIRCRAFT, "b-m-p-s-p-i": KIND_POI, "u-d-f": KIND_FOOTPRINT}


def _picture() -> np.ndarray:
    """A 1280x720 RGB frame with texture (a JPEG of it costs what a real one does)."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    base = np.stack([x % 256, y % 256, (x + y) % 256], axis=-1).astype(np.int16)
    return np.clip(base + rng.integers(-20, 20, base.shape), 0, 255).astype(np.uint8)


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q / 100.0 * (len(s) - 1))))]


def one_run(kind: str, seconds: float, pki_dir: Path) -> dict:
    """Offer the orbit for `seconds` to a hub sharing with one CoT receiver of `kind`."""
    orbit = Orbit()
    frame = orbit.frame()
    intr = Intrinsics.from_fov(*SIZE, orbit.hfov_deg)
    mesh = ground_plane(np.zeros(2), 0.0, 1000.0)
    pki = make_pki(pki_dir)
    listener = Listener(kind, pki.server_context() if kind == "tls" else None)
    target = parse_target(listener.url)
    messages = Messages()
    if kind == "tls":
        os.environ["GEOFUSE_COT_PASSWORD"] = P12_PASSWORD  # the test PKCS#12's
        ctx = cot_targets(
            [target], pki / "client.p12", None, pki / "ca.pem", settings=pki_dir / "none.toml"
        ).contexts[target]
    else:
        ctx = None
    sink = TakSink(target, messages, context=ctx)
    share = Share(mesh, frame, intr, [sink], messages).start()
    picture = _picture()
    offered: dict[int, float] = {}
    start = time.monotonic()
    k = 0
    try:
        while time.monotonic() - start < seconds:
            t = k / FPS
            eye = orbit.position(t)
            camera = Camera.create(intr, eye, look_at_quat(eye, np.zeros(3)), 0.5, 5000.0)
            offered[k] = time.monotonic()
            share.offer(
                Offer(camera, k, t, None, "orbit", "klv", None, picture if share.due() else None)
            )
            k += 1
            time.sleep(max(0.0, start + k / FPS - time.monotonic()))
        deadline = time.monotonic() + 3.0
        while not share.idle() and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        share.close()
        time.sleep(0.2)
        listener.close()
    delays: dict[str, list[float]] = {v: [] for v in TYPES.values()}
    for arrived, xml in listener.events:
        doc = etree.fromstring(xml)
        what = TYPES.get(doc.get("type"))
        tag = doc.find("detail/__geofuse")
        if what is None or tag is None:
            continue
        delays[what].append(1000.0 * (arrived - offered[int(tag.get("frame"))]))
    return {
        "transport": kind,
        "frames_offered": k,
        "frames_shared": share.shared,
        "seconds": seconds,
        "sent": dict(sink.sent),
        "not_sent": sink.dropped + sink.expired + sink.failed,
        "delay_ms": {
            what: {"n": len(d), "p50": statistics.median(d), "p95": pct(d, 95)}
            for what, d in delays.items()
            if d
        },
        "messages": messages.items,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("udp", "tcp", "tls"):
            results.append(one_run(kind, args.seconds, Path(tmp) / kind))
    print(
        f"\n{machine()}; {args.seconds:g} s a transport, frames offered at {FPS:g} Hz with a "
        f"{SIZE[0]}x{SIZE[1]} picture, the hub at 5 Hz, the aircraft and point of interest at "
        "2 Hz, the footprint at 1 Hz\n"
    )
    rows = []
    for r in results:
        d = r["delay_ms"]
        for what in (KIND_AIRCRAFT, KIND_POI, KIND_FOOTPRINT):
            if what in d:
                rate = d[what]["n"] / r["seconds"]
                rows.append([
                    r["transport"], what, d[what]["n"], f"{rate:.2f}",
                    f"{d[what]['p50']:.1f}", f"{d[what]['p95']:.1f}",
                ])  # fmt: skip
    print(
        table(
            ["transport", "event", "received", "per s", "offer -> received p50 ms", "p95 ms"], rows
        )
    )
    for r in results:
        if r["messages"] or r["not_sent"]:
            print(f"{r['transport']}: {r['not_sent']} not sent; {'; '.join(r['messages'])}")
    if any(not math.isfinite(v["p95"]) for r in results for v in r["delay_ms"].values()):
        return 1
    write_json(args.json, {"machine": machine(), "runs": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
