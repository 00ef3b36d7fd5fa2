"""A live stream in the real viewer window under Xvfb: `geofuse view udp://...` receives a drone's
downlink the test sends over the loopback, drapes it with each frame's own KLV pose, records it in
rolling segments, scrubs back through what arrived and returns to the live edge. The screenshot is
checked against the frustum: a texel of the frame shown lands where the projector's ray through it
meets the ground."""

from __future__ import annotations

import json
import threading
import time

import av
import numpy as np
import pytest
from PIL import Image

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.footage.clips import open_clip
from app.geodesy.enu import LocalFrame
from app.io.video import decode_at, probe
from app.simulate.feed import Orbit, Sender, free_udp_port, port_held, write_feed
from tests.conftest import run_viewer, state_camera

pytestmark = pytest.mark.gl

ORBIT = Orbit()
SIZE = (320, 180)


@pytest.fixture(scope="module")
def live_window(display, tmp_path_factory):
    d = tmp_path_factory.mktemp("live-viewer")
    feed = write_feed(d / "feed.ts", 10.0, SIZE)
    port = free_udp_port()
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port))

    def send_once_listening():  # the viewer takes seconds to start; the feed waits for it
        end = time.monotonic() + 120.0
        while not port_held(port) and time.monotonic() < end:
            time.sleep(0.05)
        sender.start()

    threading.Thread(target=send_once_listening, daemon=True).start()
    script = d / "script.txt"
    script.write_text(
        f"""0.0 clock 0.05
0.0 wait live 45
0.0 panels off
0.0 lines off
0.0 alpha 1.0
0.1 screenshot {d / "live.png"}
0.1 state {d / "live.json"}
0.2 live back 1.0
0.2 state {d / "review0.json"}
0.25 wait arrived 10
0.6 state {d / "review.json"}
0.7 live edge
1.5 state {d / "edge.json"}
1.6 quit
"""
    )
    result = run_viewer(
        display, f"udp://127.0.0.1:{port}", "--script", str(script), "--size", "640x360", cwd=d
    )
    sender.stop()
    assert result.returncode == 0, result.stderr[-3000:]
    return d, probe(feed).origin_s


def test_the_stream_is_shown_frame_by_frame_with_each_frames_own_pose(live_window):
    d, first_pts_s = live_window
    s = json.loads((d / "live.json").read_text())
    live = s["live"]
    assert s["errors"] == [], s["errors"]
    assert live["drawn"] >= 45 and live["received"] >= live["drawn"]
    assert live["review_s"] is None and live["shown_s"] is not None
    # latency from arrival to the screen, measured on the window's swap
    p50, p95 = live["latency_ms"]
    assert 0.0 < p50 <= p95
    # The projector is the orbit at the shown frame's own time (the KLV's positions are mm-exact;
    # a frame off would be 0.5 m along the circle).
    frame = LocalFrame(*live["frame"])
    t = live["shown_s"] + live["origin_s"] - first_pts_s  # the orbit's time
    want = frame.geodetic_to_enu(*ORBIT.frame().enu_to_geodetic(ORBIT.position(t)[None]).T)[0]
    got = np.asarray(live["projector"]["position"])
    assert np.linalg.norm(got[:2] - want[:2]) < 0.1, (got, want)


def test_a_texel_of_the_frame_shown_lands_where_the_frustum_says(live_window):
    d, _ = live_window
    s = json.loads((d / "live.json").read_text())
    live = s["live"]
    shot = np.asarray(Image.open(d / "live.png").convert("RGB"), int)
    # the frame shown, decoded from the recording the viewer made
    segment = d / live["segments"][0]
    with av.open(str(segment)) as c:
        stream = c.streams.video[0]
        f = decode_at(c, stream, live["shown_s"] + live["origin_s"], 0.002)
        video = f.to_ndarray(format="rgb24").astype(int)
    frame = LocalFrame(*live["frame"])
    p = live["projector"]
    projector = Camera.create(
        Intrinsics.from_fov(*SIZE, ORBIT.hfov_deg), p["position"], p["orientation"]
    )
    wc = s["window_camera"]
    window = state_camera(wc)
    ground = frame.geodetic_to_enu(
        np.array([ORBIT.lat_deg]), np.array([ORBIT.lon_deg]), np.array([ORBIT.ground_h_m])
    )[0][2]
    # texels inside the 8-pixel blocks (uniform 5x5 neighbourhoods), over the middle of the frame
    texels = []
    for v in range(40, 140, 3):
        for u in range(60, 260, 3):
            patch = video[v - 2 : v + 3, u - 2 : u + 3]
            if np.ptp(patch.reshape(-1, 3), axis=0).max() < 16:
                texels.append((u, v))
    assert len(texels) > 30
    uv = np.array(texels, float) + 0.5
    rays = projector.pixel_rays(uv)
    o = np.asarray(projector.position)
    hits = o + rays * ((ground - o[2]) / rays[:, 2])[:, None]
    px, depth = window.project(hits)
    inside = (depth > 0) & (px[:, 0] >= 2) & (px[:, 0] < 638) & (px[:, 1] >= 2) & (px[:, 1] < 358)
    assert inside.sum() > 20
    screen = np.array([shot[int(y), int(x)] for x, y in px[inside]])
    colour = np.array([video[v, u] for u, v in np.array(texels)[inside]])
    diff = np.abs(screen - colour).max(axis=1)
    shuffled = np.abs(screen - np.roll(colour, 7, axis=0)).max(axis=1)
    assert np.median(diff) < 20 and np.mean(diff < 40) > 0.85, diff
    assert np.median(shuffled) > 50  # the check tells colours apart


def test_scrubbing_back_shows_the_recorded_moment_and_live_returns_to_the_edge(live_window):
    d, _ = live_window
    before = json.loads((d / "review0.json").read_text())["live"]  # as the review began
    review = json.loads((d / "review.json").read_text())["live"]  # 10 frames arrived later
    edge = json.loads((d / "edge.json").read_text())["live"]
    lo, hi = before["recorded_s"]  # when `live back 1.0` ran
    assert review["review_s"] == pytest.approx(hi - 1.0, abs=0.2)  # a second behind the newest
    assert review["review_s"] - 0.02 <= review["shown_s"] <= review["review_s"] + 1 / 30 + 1e-6
    assert before["shown_s"] == review["shown_s"]  # the reviewed frame stays up
    # frames kept arriving (and being recorded) while the viewer looked back, none of them counted
    # as dropped or drawn for it
    assert (
        review["received"] > before["received"]
        and review["recorded_s"][1] > before["recorded_s"][1]
    )
    assert review["dropped"] == before["dropped"] and review["drawn"] == before["drawn"]
    assert edge["review_s"] is None and edge["shown_s"] > review["shown_s"] + 0.5
    assert edge["drawn"] > review["drawn"]


def test_the_recording_is_a_clip(live_window):
    d, _ = live_window
    edge = json.loads((d / "edge.json").read_text())["live"]
    clip = open_clip(d / edge["segments"][0])
    assert "telemetry" in clip.recorded
    assert len(clip.video.pts_s) >= edge["drawn"]
