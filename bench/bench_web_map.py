"""Browser map benchmark (issue 53, app.share.web): how long after a frame is offered to the
sharing hub its update reaches the browsers, with 1, 5 and 20 of them connected; and the
viewer's frame time with sharing on and off in one run.

Delay: a hub (app.share.hub, its own GL context) over a flat ground is offered a posed camera
with a 640x480 picture every 0.25 s (under its 5 Hz limit: each is shared at once); the clock
starts at the offer and stops when the client has the update: in headless Chromium (Debian's
chromium, through selenium) when the page has drawn it (map.js notes Date.now() once the frame
is applied), in a plain event-stream client (app.share.web.read_events, a thread each) when the
event is parsed. With 1 client: Chromium alone; with 5 and 20: one Chromium and 4 or 19 plain
clients (as many Chromiums would measure the machine's two cores, not the map). Each delay is
also split at the moment the hub hands the frame to the map's sink: the cast (point of
interest, footprint, picture) before it, the server and the client after. The first WARMUP
offers of each configuration are left out.

Viewer: `geofuse view` on the bundled sample in a real window (a private Xvfb, llvmpipe), on the
wall clock at 1x once every source is solved (the registered one too): --segment seconds with
sharing off, on (`share on`, one plain event-stream client following it), off, on; each
segment's frame time is the viewer's own (median and p95 of its loop over its last 600 frames,
the `state` action), so a segment should hold more than 600 frames.

    geofuse bench map [--offers 40] [--segment 25] [--size 960x540]
                      [--no-viewer | --no-delays] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

try:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
except ImportError:  # the test extra not installed: plain clients only
    webdriver = Service = None

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.intrinsics import Intrinsics  # noqa: E402
from app.camera.pinhole import Camera, look_at_quat  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.scene import shapes  # noqa: E402
from app.scene.mesh import MeshData  # noqa: E402
from app.share.hub import Offer, Share  # noqa: E402
from app.share.web import MapServer, WebMapSink, read_events  # noqa: E402
from bench.bench_playback import Display  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402

FRAME = LocalFrame(47.0, 8.0, 400.0)
INTR = Intrinsics.from_fov(640, 480, 60.0)
OFFER_EVERY_S = 0.25
CLIENT_COUNTS = (1, 5, 20)
WARMUP = 3  # the first offers of each configuration left out (the worker's first casts)


def percentiles(ms: list[float]) -> tuple[float, float]:
    """(p50, p95) of a list of milliseconds."""
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 95))


class TimedSink(WebMapSink):
    """The map's sink, noting when the hub hands it each frame (wall clock, s, by index)."""

    def __init__(self, server: MapServer) -> None:
        super().__init__(server, owns=False)
        self.handed: dict[int, float] = {}

    def send_frame(self, frame) -> None:
        self.handed[frame.index] = time.time()
        super().send_frame(frame)


class Follower:
    """A plain event-stream client in a thread: when each frame's event arrived (wall s)."""

    def __init__(self, url: str) -> None:
        self.got: dict[int, float] = {}
        self.ready = threading.Event()
        threading.Thread(target=self._run, args=(url,), daemon=True).start()

    def _run(self, url: str) -> None:
        try:
            for name, data in read_events(url):
                now = time.time()
                self.ready.set()
                if name == "frame":
                    self.got[data["frame"]["index"]] = now
        except OSError:
            pass  # the server closed: the run is over


def chromium():
    """A headless Chromium driven by selenium, or None (said) where there is none."""
    chrome, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if chrome is None or driver is None or webdriver is None:
        print("no Chromium/chromedriver/selenium: plain clients only", file=sys.stderr)
        return None
    options = webdriver.ChromeOptions()
    options.binary_location = chrome
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1000,700"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(driver), options=options)


def delays(clients: int, offers: int, browser) -> dict:
    """One configuration: `clients` connected (one of them the browser, where there is one),
    `offers` frames offered; the delays in ms."""
    g = shapes.quad([-2000.0, -2000.0, 0.0], [4000.0, 0, 0], [0, 4000.0, 0]).primitive()
    server = MapServer().start()
    sink = TimedSink(server)
    share = Share(MeshData([g]), FRAME, INTR, [sink]).start()
    events = server.url.replace("/?token=", "/events?token=")
    plain = [Follower(events) for _ in range(clients - (browser is not None))]
    for f in plain:
        f.ready.wait(30)
    if browser is not None:
        browser.get(server.url)
        end = time.monotonic() + 30
        while not browser.execute_script("return window.geofuseMap && geofuseMap.connected"):
            if time.monotonic() > end:
                raise SystemExit("the browser did not connect to the map")
            time.sleep(0.05)
    rng = np.random.default_rng(1)
    picture = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    offered: dict[int, float] = {}
    try:
        for k in range(offers):
            t = k * OFFER_EVERY_S
            eye = np.array([40.0 * np.cos(t / 3), 40.0 * np.sin(t / 3), 120.0])
            look = np.array([0.3 * np.cos(t), 1.0, -1.0])
            camera = Camera.create(INTR, eye, look_at_quat(eye, eye + look), 0.5, 5000.0)
            if k >= WARMUP:
                offered[k] = time.time()
            share.offer(Offer(camera, k, t, 1.7e9 + t, "bench.ts", "klv", "used", picture))
            time.sleep(OFFER_EVERY_S)
        time.sleep(1.0)  # the last frame's way
        applied = browser.execute_script("return geofuseMap.applied") if browser is not None else []
    finally:
        share.close()
        server.close()
    out: dict[str, object] = {"clients": clients, "offers": offers, "shared": share.shared}
    cast = [1000 * (sink.handed[k] - offered[k]) for k in offered if k in sink.handed]
    out["cast_ms"] = percentiles(cast)
    if applied:
        b = {int(k): ms / 1000.0 for k, ms in applied}
        out["browser_ms"] = percentiles([1000 * (b[k] - offered[k]) for k in b if k in offered])
        out["browser_after_sink_ms"] = percentiles(
            [1000 * (b[k] - sink.handed[k]) for k in b if k in sink.handed]
        )
        out["browser_frames"] = len(b)
    if plain:
        got = [(k, t) for f in plain for k, t in f.got.items() if k in offered]
        out["plain_ms"] = percentiles([1000 * (t - offered[k]) for k, t in got])
        out["plain_after_sink_ms"] = percentiles(
            [1000 * (t - sink.handed[k]) for k, t in got if k in sink.handed]
        )
        out["plain_frames_each"] = statistics.median(len(f.got) for f in plain)
    return out


SEGMENTS = ("off", "on", "off", "on")  # sharing in each segment, alternated against drift


def viewer_on_off(display: str, segment_s: float, size: tuple[int, int], tmp: Path) -> dict:
    """The viewer on the sample, sharing off and on in turn (SEGMENTS; on: one plain client
    following the map); each segment's frame time from the viewer's own state at its end."""
    manifest = ROOT / "assets" / "sample" / "session.toml"
    lines = ["0 wait registered", "0 play"]
    for i, sharing in enumerate(SEGMENTS):
        t = i * segment_s
        if i == 0 or sharing != SEGMENTS[i - 1]:
            lines.append(f"{t + 0.1:.1f} share {sharing}")
        if sharing == "on":
            lines.append(f"{t + 0.2:.1f} state {tmp / f'url{i}.json'}")  # one state a frame
        lines.append(f"{t + segment_s:.1f} state {tmp / f'segment{i}.json'}")
    lines.append(f"{len(SEGMENTS) * segment_s + 0.2:.1f} quit")
    script = tmp / "share.txt"
    script.write_text("\n".join(lines) + "\n")
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp / "config"))
    cmd = [sys.executable, "-m", "app", "view", str(manifest), "--script", str(script)]
    proc = subprocess.Popen(
        [*cmd, "--size", f"{size[0]}x{size[1]}"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    followers = []
    for i, sharing in enumerate(SEGMENTS):  # a client follows each map the script starts
        url_file = tmp / f"url{i}.json"
        if sharing != "on":
            continue
        end = time.monotonic() + 1800
        while not url_file.is_file() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.1)
        if not url_file.is_file():
            break
        time.sleep(0.2)  # written whole
        info = json.loads(url_file.read_text())["info"]
        url = [n.split(" at ", 1)[1] for n in info if "the browser map is at" in n][-1]
        followers.append(Follower(url.replace("/?token=", "/events?token=")))
    _, err = proc.communicate(timeout=1800)
    last = tmp / f"segment{len(SEGMENTS) - 1}.json"
    if proc.returncode != 0 or not last.is_file():
        raise SystemExit(f"the viewer failed:\n{err[-3000:]}")
    out: dict[str, object] = {"segments": []}
    before = None
    for i, sharing in enumerate(SEGMENTS):
        st = json.loads((tmp / f"segment{i}.json").read_text())
        frames = None if before is None else st["frames_drawn"] - before
        before = st["frames_drawn"]
        out["segments"].append(
            {
                "sharing": sharing,
                "frame_ms": st["frame_ms"],
                "frame_p95_ms": st["frame_p95_ms"],
                "frames": frames,
            }  # fmt: skip
        )
    out["frames_followed"] = [len(f.got) for f in followers]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--offers", type=int, default=40)
    parser.add_argument("--segment", type=float, default=25.0)
    parser.add_argument("--size", default="960x540")
    parser.add_argument("--no-viewer", action="store_true")
    parser.add_argument("--no-delays", action="store_true", help="the viewer's frame time only")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    figures: dict[str, object] = {"machine": machine()}
    browser = None if args.no_delays else chromium()
    rows = []
    try:
        for n in () if args.no_delays else CLIENT_COUNTS:
            r = delays(n, args.offers, browser)
            figures[f"clients_{n}"] = r
            print(json.dumps(r), flush=True)
            cells = ("cast_ms", "browser_ms", "browser_after_sink_ms", "plain_ms", "plain_after_sink_ms")  # fmt: skip
            who = "1 Chromium" + (f" + {n - 1} plain" if n > 1 else "")
            rows.append(
                [who, r["shared"]]
                + ["-" if c not in r else "{:.1f} / {:.1f}".format(*r[c]) for c in cells]
            )
    finally:
        if browser is not None:
            browser.quit()
    if rows:
        print(f"\n{machine()}; a frame offered every {OFFER_EVERY_S} s, {args.offers} offers each; p50 / p95 ms\n")  # fmt: skip
        print(table(["clients", "frames shared", "offer -> sink (cast)", "offer -> Chromium drawn", "sink -> Chromium drawn", "offer -> plain client", "sink -> plain client"], rows))  # fmt: skip
    if not args.no_viewer:
        w, h = (int(v) for v in args.size.split("x"))
        with Display() as display, tempfile.TemporaryDirectory() as tmp:
            v = viewer_on_off(display, args.segment, (w, h), Path(tmp))
        figures["viewer"] = v
        print(f"\nthe viewer on the sample, {args.size}, {args.segment:g} s a segment; frames the plain client got in each 'on' segment: {v['frames_followed']}\n")  # fmt: skip
        print(table(["segment", "sharing", "frames drawn", "frame time median ms", "p95 ms"], [
            [i + 1, seg["sharing"], seg["frames"] or "-", f"{seg['frame_ms']:.1f}", f"{seg['frame_p95_ms']:.1f}"]
            for i, seg in enumerate(v["segments"])
        ]))  # fmt: skip
    write_json(args.json, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
