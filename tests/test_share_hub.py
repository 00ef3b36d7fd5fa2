"""The sharing hub (app.share.hub): a drawn frame's camera becomes a SharedFrame whose point of
interest and footprint are where the frustum says on a flat ground, the sinks get the newest
frame at most max_hz times a second (an injected clock), and a failing sink is said once and
never stops the others."""

from __future__ import annotations

import math
from io import BytesIO

import numpy as np
import pytest
import shapely
from PIL import Image

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.geodesy.enu import METRES_PER_DEGREE, LocalFrame
from app.scene import shapes
from app.scene.mesh import MeshData
from app.share.frames import thumbnail_jpeg
from app.share.hub import Offer, Share
from tests.waiting import wait_until

FRAME = LocalFrame(47.0, 8.0, 400.0)
INTR = Intrinsics.from_fov(640, 480, 60.0)


class Recorder:
    def __init__(self, name="recorder", fail=False):
        self.name, self.fail = name, fail
        self.frames, self.marks, self.closed = [], [], False

    def send_frame(self, frame):
        if self.fail:
            raise ConnectionRefusedError("nobody listens")
        self.frames.append(frame)

    def send_marks(self, marks):
        self.marks.append(marks)

    def close(self):
        self.closed = True


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture(scope="module")
def ground():
    g = shapes.quad([-500.0, -500.0, 0.0], [1000.0, 0, 0], [0, 1000.0, 0]).primitive()
    g.colors[:] = (0.5, 0.5, 0.5, 1.0)
    return MeshData([g])


def _down(east, north, height):
    eye = np.array([east, north, height])
    return Camera.create(INTR, eye, look_at_quat(eye, eye - [0, 0, 1.0]), 0.5, 5000.0)


def test_the_centre_and_footprint_lie_where_the_frustum_says(ground):
    sink, clock = Recorder(), Clock()
    share = Share(ground, FRAME, INTR, [sink], clock=clock).start()
    try:
        rgb = np.zeros((480, 640, 3), np.uint8)
        rgb[:, 320:] = 255
        share.offer(Offer(_down(30.0, -20.0, 100.0), 7, 0.25, 1.7e9, "a.ts", "klv", "used", rgb))
        assert wait_until(lambda: sink.frames)
    finally:
        share.close()
    (f,) = sink.frames
    assert sink.closed
    # straight down from (30, -20, 100): the centre at (30, -20, 0) on the ground
    lat, lon, h = FRAME.enu_to_geodetic([30.0, -20.0, 0.0])
    assert f.centre[0] == pytest.approx(lat, abs=0.05 / METRES_PER_DEGREE)
    assert f.centre[1] == pytest.approx(lon, abs=0.05 / METRES_PER_DEGREE)
    assert f.centre[2] == pytest.approx(h, abs=0.05)
    assert f.slant_m == pytest.approx(100.0, abs=0.05)
    assert f.hpr[1] == pytest.approx(-90.0, abs=1e-6)
    # the footprint: 2 * 100 tan(30 deg) across by 2 * 100 tan(vfov / 2) down, about the centre
    poly = shapely.geometry.shape(f.footprint)
    lat0 = math.radians(lat)
    across = 200.0 * math.tan(math.radians(30.0))
    down = 200.0 * math.tan(math.radians(INTR.vfov_deg / 2))
    area_m2 = poly.area * METRES_PER_DEGREE**2 * math.cos(lat0)
    assert area_m2 == pytest.approx(across * down, rel=0.01)
    c = poly.centroid
    assert (c.x, c.y) == pytest.approx((lon, lat), abs=0.1 / METRES_PER_DEGREE)
    assert (f.index, f.media_s, f.utc_s, f.clip, f.source, f.gnss) == (
        7,
        0.25,
        1.7e9,
        "a.ts",
        "klv",
        "used",
    )
    assert f.thumbnail[:2] == b"\xff\xd8" and f.as_dict()["thumbnail"] is True


def test_the_newest_frame_at_most_max_hz_and_a_failing_sink_said_once(ground):
    good, bad, clock = Recorder("good"), Recorder("TAK 127.0.0.1:9", fail=True), Clock()
    share = Share(ground, FRAME, INTR, [bad, good], max_hz=2.0, clock=clock).start()
    try:
        share.offer(Offer(_down(0.0, 0.0, 50.0), 0, 0.0))
        assert wait_until(lambda: len(good.frames) == 1 and share.idle())
        for k in range(1, 6):  # the clock holds: the rate limit keeps them; the newest waits
            share.offer(Offer(_down(float(k), 0.0, 50.0), k, k / 30))
        # held while the clock stands (a broken limit would show within the 0.3 s)
        assert not wait_until(lambda: len(good.frames) > 1, 0.3)
        clock.t = 0.5  # half a second on: one more, the newest
        assert wait_until(lambda: len(good.frames) == 2)
        assert good.frames[-1].index == 5
        share.set_marks({"type": "FeatureCollection", "features": []})
        assert wait_until(lambda: good.marks)
    finally:
        share.close()
    said = [m for m in share.messages.items if "TAK 127.0.0.1:9" in m]
    assert len(said) == 1 and "nobody listens" in said[0]
    assert share.shared == 2 and share.offered == 6


def test_a_thumbnail_is_never_scaled_up():
    small = Image.open(BytesIO(thumbnail_jpeg(np.zeros((90, 160, 3), np.uint8))))
    big = Image.open(BytesIO(thumbnail_jpeg(np.zeros((1080, 1920, 3), np.uint8))))
    assert small.size == (160, 90) and big.size == (320, 180)
