"""The browser map (issue 53, app.share.web): a real server on the loopback fed by the sharing
hub (a flat ground and known cameras, as tests/test_share_hub.py), opened in a headless Chromium
(Debian's chromium and chromium-driver, through selenium); the footprint, the aircraft, the point
of interest and the track read back from the page equal the SharedFrame's (exactly: JSON prints
floats so that they read back the same); every request without the token is refused 403; a
browser and a plain event-stream client both follow the frames and the marks; a `live` run feeds
it; imagery comes through the server with its key kept out of the browser; `geofuse serve`
plays a clip into it until Ctrl-C; and the viewer's Share toggle under Xvfb serves the frame
shown. Where Chromium is absent (a developer's machine) the browser tests are skipped, as the
Xvfb tests are without Xvfb; CI installs both, so there they run."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.footage.clips import open_any
from app.geodesy.enu import LocalFrame
from app.live.run import LiveOptions, run_live
from app.scene import shapes
from app.scene.mesh import MeshData
from app.session.camera_track import camera_track
from app.share.hub import Offer, Share
from app.share.web import MapServer, WebMapSink, parse_bind, read_events, web_sink_maker
from app.simulate.feed import Sender, free_udp_port, sending_clock, write_feed
from app.world.sources import parse_source
from tests.conftest import ROOT, _unavailable
from tests.waiting import wait_until

try:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
except ImportError:  # the test extra not installed: the browser tests say so
    webdriver = Service = None

FRAME = LocalFrame(47.0, 8.0, 400.0)
INTR = Intrinsics.from_fov(640, 480, 60.0)


class Recorder:
    """A sink keeping what it was handed (the SharedFrames the page is compared with)."""

    def __init__(self):
        self.name, self.frames, self.marks = "recorder", [], []

    def send_frame(self, frame):
        self.frames.append(frame)

    def send_marks(self, marks):
        self.marks.append(marks)

    def close(self):
        pass


class EventFollower:
    """A plain client of the map's event stream, in a thread: every (name, data) it read."""

    def __init__(self, url: str):
        self.events: list[tuple[str, dict]] = []
        self.error: BaseException | None = None
        threading.Thread(target=self._run, args=(url,), daemon=True).start()

    def _run(self, url):
        try:
            for event in read_events(url):
                self.events.append(event)
        except BaseException as exc:  # said by the test that waits on it
            self.error = exc

    def frames(self) -> list[dict]:
        return [d["frame"] for n, d in self.events if n == "frame" or (n == "state" and d["frame"])]


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _at(server: MapServer, path: str, token: str | None = None) -> str:
    base = f"http://127.0.0.1:{server.port}{path}"
    return base if token is None else f"{base}{'&' if '?' in path else '?'}token={token}"


def _camera(east: float, north: float, height: float, look=(0.3, 1.0, -1.0)) -> Camera:
    eye = np.array([east, north, height])
    return Camera.create(INTR, eye, look_at_quat(eye, eye + np.asarray(look)), 0.5, 5000.0)


def _polygons(geometry: dict) -> list:
    """A GeoJSON (Multi)Polygon as lists of rings of [lon, lat] without each ring's closing
    point (Leaflet draws a ring without it)."""
    polys = [geometry["coordinates"]] if geometry["type"] == "Polygon" else geometry["coordinates"]
    return [[[[p[0], p[1]] for p in ring[:-1]] for ring in poly] for poly in polys]


def _drawn(browser) -> list:
    """The footprint the page drew, as _polygons gives the shared one."""
    (layer,) = browser.execute_script("return geofuseMap.drawnFootprint()")
    return [layer] if not isinstance(layer[0][0][0], list) else layer


def _shown(browser, index: int) -> bool:
    return browser.execute_script("return geofuseMap.frame && geofuseMap.frame.index") == index


def _as_json(value):
    return json.loads(json.dumps(value))


@pytest.fixture(scope="module")
def browser():
    """One headless Chromium for the module (skipped where it is not installed, failed in CI)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if chromium is None or driver is None:
        _unavailable("Chromium is not installed (apt-get install chromium chromium-driver)")
    if webdriver is None:
        _unavailable("selenium is not installed (pip install -e '.[test]')")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1000,700",
    ):
        options.add_argument(arg)
    b = webdriver.Chrome(service=Service(driver), options=options)
    yield b
    b.quit()


@pytest.fixture(scope="module")
def ground():
    g = shapes.quad([-500.0, -500.0, 0.0], [1000.0, 0, 0], [0, 1000.0, 0]).primitive()
    g.colors[:] = (0.5, 0.5, 0.5, 1.0)
    return MeshData([g])


@pytest.fixture(scope="module")
def served(ground):
    """A map on the loopback fed by a hub over the flat ground; a recorder beside it."""
    server = MapServer().start()
    rec = Recorder()
    share = Share(ground, FRAME, INTR, [WebMapSink(server, owns=True), rec], max_hz=0).start()

    def offer(camera: Camera, index: int, media_s: float, picture=None):
        share.offer(Offer(camera, index, media_s, 1.7e9 + media_s, "a.ts", "klv", "used", picture))
        assert wait_until(lambda: rec.frames and rec.frames[-1].index == index)
        return rec.frames[-1]

    yield SimpleNamespace(server=server, share=share, rec=rec, offer=offer)
    share.close()


def test_the_page_draws_the_shared_footprint_exactly(served, browser):
    picture = np.zeros((480, 640, 3), np.uint8)
    picture[:, 320:] = 200
    f = served.offer(_camera(30.0, -20.0, 100.0), 7, 0.25, picture)
    browser.get(served.server.url)  # a new browser: the current state at once
    assert wait_until(lambda: _shown(browser, 7))
    assert browser.execute_script("return geofuseMap.frame") == _as_json(f.as_dict())
    assert f.footprint["type"] == "Polygon"
    assert _drawn(browser) == _polygons(_as_json(f.footprint))
    assert browser.execute_script("return geofuseMap.drawnAircraft()") == [
        f.sensor[1],
        f.sensor[0],
    ]
    assert browser.execute_script("return geofuseMap.drawnCentre()") == [f.centre[1], f.centre[0]]
    assert wait_until(
        lambda: (
            browser.execute_script("return document.getElementById('thumb').naturalWidth") == 320
        )
    )
    text = browser.find_element("id", "background").text
    assert "No imagery configured" in text and "--world NAME" in text


def test_without_the_token_every_request_is_refused(served):
    s = served.server
    paths = ("/", "/state", "/events", "/thumbnail.jpg", "/static/leaflet/leaflet.js", "/tiles/1/0/0", "/elsewhere")  # fmt: skip
    for path in paths:
        assert _get(_at(s, path))[0] == 403, path
        assert _get(_at(s, path, "not-the-token"))[0] == 403, path
    assert _get(_at(s, "/state", s.token))[0] == 200
    assert _get(_at(s, "/static/leaflet/leaflet.js", s.token))[0] == 200
    assert _get(_at(s, "/elsewhere", s.token))[0] == 404
    assert any("refused a request from 127.0.0.1" in m for m in s.messages.items)
    assert s.host == "127.0.0.1" and s.warning is None
    assert parse_bind("0.0.0.0:8080") == ("0.0.0.0", 8080) and parse_bind("[::1]:0") == ("::1", 0)
    assert "beyond this machine" in MapServer(("0.0.0.0", 0)).warning
    with pytest.raises(ValueError):
        parse_bind("8080")


def test_a_browser_and_a_plain_client_both_follow_the_frames_and_the_marks(served, browser):
    s = served.server
    browser.get(s.url)
    plain = EventFollower(_at(s, "/events", s.token))
    assert wait_until(lambda: plain.events or plain.error)
    assert plain.events[0][0] == "state" and plain.error is None  # the current state at once
    shared = []
    for k, east in enumerate((0.0, 15.0, 30.0), start=20):
        shared.append(served.offer(_camera(east, 40.0, 80.0 + k), k, 10.0 + k))
        assert wait_until(lambda k=k: _shown(browser, k))
        assert wait_until(lambda k=k: plain.frames() and plain.frames()[-1]["index"] == k)
        assert _drawn(browser) == _polygons(_as_json(shared[-1].footprint))
        assert plain.frames()[-1] == _as_json(shared[-1].as_dict())
    # the track: every position shared, in order (the frames before these were another clip's
    # time: 10 s on is no jump back, so the track goes on from them)
    track = browser.execute_script("return geofuseMap.drawnTrack()")
    assert track[-3:] == [[f.sensor[1], f.sensor[0]] for f in shared]
    marks = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [8.0004, 47.0003, 400.0]},
                "properties": {"label": "red car"},
            }
        ],
    }
    served.share.set_marks(marks)
    assert wait_until(lambda: browser.execute_script("return geofuseMap.drawnMarks().length"))
    assert browser.execute_script("return geofuseMap.drawnMarks()") == [
        {"label": "red car", "at": [8.0004, 47.0003]}
    ]
    assert wait_until(lambda: any(n == "marks" for n, _ in plain.events))
    assert [d for n, d in plain.events if n == "marks"][-1]["marks"] == marks
    assert s.clients >= 2


@pytest.fixture(scope="module")
def feed(tmp_path_factory) -> Path:
    """3 s of the orbit at 320x180, 30 fps, a KLV set per frame (as tests/test_live.py)."""
    return write_feed(tmp_path_factory.mktemp("web-map") / "feed.ts", 3.0, (320, 180))


def test_a_live_run_feeds_the_map(served, browser, feed, tmp_path):
    s = served.server
    browser.get(s.url)
    port = free_udp_port()
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port))
    rec = Recorder()
    options = LiveOptions(
        silence_s=2.0,
        size=(160, 90),
        record=tmp_path / "rec.ts",
        sinks=(web_sink_maker(s), lambda messages: rec),
    )
    url = f"udp://127.0.0.1:{port}"
    run = run_live(url, options, clock=sending_clock(sender, port))
    sender.stop()
    assert run.drawn and len(rec.frames) >= 3
    last = rec.frames[-1]
    assert wait_until(lambda: _shown(browser, last.index))
    assert browser.execute_script("return geofuseMap.frame") == _as_json(last.as_dict())
    assert last.clip == url and last.source == "klv"
    assert _drawn(browser) == _polygons(_as_json(last.footprint))
    # another clip: a new track, every position the run shared
    track = browser.execute_script("return geofuseMap.drawnTrack()")
    assert track == [[f.sensor[1], f.sensor[0]] for f in rec.frames]
    assert _get(_at(s, "/state", s.token))[0] == 200  # the run closed its sinks, not the map


KEY = "Zk3y-never-in-the-browser-0123"


class _Tiles(BaseHTTPRequestHandler):
    """An imagery server that wants its key: ?key=KEY, else 403; each tile a flat colour."""

    log: list = []

    def do_GET(self):
        type(self).log.append(self.path)
        if f"key={KEY}" not in self.path:
            self.send_error(403)
            return
        out = io.BytesIO()
        Image.new("RGB", (256, 256), (30, 140, 60)).save(out, "PNG")
        self.send_response(200)
        self.send_header("Content-Type", "image/png")
        self.end_headers()
        self.wfile.write(out.getvalue())

    def log_message(self, *args):
        pass


def test_imagery_comes_through_the_server_and_its_key_never_reaches_the_browser(
    browser, tmp_path, monkeypatch
):
    monkeypatch.setenv("GEOFUSE_TILE_CACHE", str(tmp_path / "tiles"))
    upstream = ThreadingHTTPServer(("127.0.0.1", 0), _Tiles)
    threading.Thread(target=upstream.serve_forever, daemon=True).start()
    template = f"http://127.0.0.1:{upstream.server_port}/{{z}}/{{x}}/{{y}}.png?key={{key}}"
    source = parse_source(template, "imagery", "(c) Test Imagery", key=KEY, max_zoom=5)
    server = MapServer(imagery=source).start()
    try:
        browser.get(server.url)
        loaded = "return document.querySelectorAll('img.leaflet-tile-loaded').length"
        assert wait_until(lambda: browser.execute_script(loaded) >= 4)
        assert _Tiles.log and all(f"key={KEY}" in p for p in _Tiles.log)
        tile = browser.execute_script("return document.querySelector('img.leaflet-tile').src")
        assert tile.startswith(f"http://127.0.0.1:{server.port}/tiles/")
        code, body = _get(_at(server, "/tiles/2/1/1", server.token))
        assert code == 200 and Image.open(io.BytesIO(body)).getpixel((128, 128)) == pytest.approx(
            (30, 140, 60), abs=3
        )
        assert _get(_at(server, "/tiles/6/0/0", server.token))[0] == 404  # past its max zoom
        seen = browser.execute_script(
            "return document.documentElement.outerHTML + JSON.stringify(geofuseMap.map)"
            " + performance.getEntries().map(e => e.name).join(' ')"
        )
        assert KEY not in seen and str(upstream.server_port) not in seen
        assert (
            "(c) Test Imagery"
            in browser.find_element("class name", "leaflet-control-attribution").text
        )
    finally:
        server.close()
        upstream.shutdown()


def test_serve_plays_a_clip_onto_the_map_until_ctrl_c(feed):
    proc = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", str(feed), "--bind", "127.0.0.1:0"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        before = []  # what was said before the URL (nothing, but for a stray warning)
        while not (line := proc.stdout.readline()).startswith("the browser map: ") and line:
            before.append(line)
        assert line.startswith("the browser map: http://127.0.0.1:"), before
        url = line.split(": ", 1)[1].strip()
        state = url.replace("/?token=", "/state?token=")

        def a_frame():
            code, body = _get(state)
            return code == 200 and json.loads(body)["frame"] is not None

        assert wait_until(a_frame)
        s = json.loads(_get(state)[1])
        assert s["frame"]["clip"] == "feed.ts" and s["frame"]["source"] == "telemetry"
        assert s["frame"]["footprint"]["type"] in ("Polygon", "MultiPolygon")
        assert _get(url.split("?")[0] + "state")[0] == 403
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert "stopped (Ctrl-C)" in out and "refused a request from 127.0.0.1" in out


@pytest.mark.gl
def test_the_viewer_share_toggle_serves_the_frame_shown(display, feed, tmp_path):
    """`share on` in a viewer script: the URL among the notes; a plain HTTP client fetches the
    state with the token and gets the frame shown, its pose the projector's and its footprint
    the one a hub casts for that camera here; `share off` stops it."""
    d = tmp_path
    script = d / "script.txt"
    script.write_text(
        f"""0.0 clock 0.0333333
0.0 wait solved
0.0 seek 1.5
0.0 pause
0.2 share on
0.3 state {d / "on.json"}
0.3 share wait
0.4 state {d / "served.json"}
0.5 share off
0.6 state {d / "off.json"}
0.7 quit
"""
    )
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(d / "config"))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "app",
            "view",
            str(feed),
            "--script",
            str(script),
            "--size",
            "640x360",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_until(lambda: (d / "on.json").exists() or proc.poll() is not None, 240)
        on = json.loads((d / "on.json").read_text())
        (note,) = [n for n in on["info"] if "the browser map is at" in n]
        url = note.split(" at ", 1)[1]
        assert url.startswith("http://127.0.0.1:")
        assert _get(url.split("?")[0] + "state")[0] == 403
        state_url = url.replace("/?token=", "/state?token=")

        def the_frame_shown():
            got = json.loads(_get(state_url)[1])["frame"]
            return got if got is not None and got["index"] == on["frame"] else None

        assert wait_until(lambda: the_frame_shown() is not None)
        frame = the_frame_shown()
        _, err = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err[-3000:]
    off = json.loads((d / "off.json").read_text())
    assert on["errors"] == [] and off["errors"] == [], off["errors"]
    assert any("stopped" in n for n in off["info"])
    with pytest.raises(OSError):  # nothing listens there any more
        socket.create_connection(tuple(parse_bind(url.split("/")[2])), timeout=5).close()
    # the pose the viewer drew the frame with, and the footprint a hub casts for it here
    session = open_any(feed)
    assert frame["source"] == on["source"] == "telemetry"
    camera = camera_track(session, on["source"]).frame_camera(on["frame"])
    sensor = session.frame.geodetic_to_enu(*frame["sensor"])
    assert np.allclose(sensor, on["projector"]["position"], atol=1e-3)
    assert np.allclose(sensor, camera.position, atol=1e-3)
    rec = Recorder()
    share = Share(session.scene(), session.frame, session.intrinsics, [rec], lens=session.lens)
    share.start().offer(Offer(camera, on["frame"], 0.0))
    try:
        assert wait_until(lambda: rec.frames)
    finally:
        share.close()
    ours, theirs = _polygons(_as_json(rec.frames[0].footprint)), _polygons(frame["footprint"])
    assert len(ours) == len(theirs) and all(
        len(a) == len(b) for a, b in zip(ours, theirs, strict=True)
    )
    assert np.allclose(
        np.concatenate([np.asarray(r, float).reshape(-1, 2) for p in theirs for r in p]),
        np.concatenate([np.asarray(r, float).reshape(-1, 2) for p in ours for r in p]),
        atol=1e-7,  # degrees: about 1 cm
    )
