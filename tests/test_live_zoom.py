"""A live feed that zooms (issue 50): each frame is drawn with the field of view of its own
moment (ST 0601 tags 16/17), linear between the sets that arrived, never the last one a feed
gave; a field of view the user gives stands instead. The stream is the simulator's orbit, its
field of view changed set by set here, sent over the loopback by the test itself."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.io.misb import local_set, parse, read_ber, read_oid
from app.live.pose import FRESH, LivePoses
from app.live.run import LiveOptions, run_live
from app.simulate.feed import (
    Orbit,
    Sender,
    free_udp_port,
    moving_texture,
    orbit_set,
    sending_clock,
)
from app.simulate.phone import write_video

ORBIT = Orbit()
SIZE = (320, 180)


def _vfov(hfov_deg: float) -> float:
    """The vertical field of view (deg) of a SIZE picture with square pixels."""
    return math.degrees(2 * math.atan(math.tan(math.radians(hfov_deg) / 2) * SIZE[1] / SIZE[0]))


def _set(t: float, hfov_deg: float) -> bytes:
    """The orbit's Local Set at t s with its lens at hfov_deg across."""
    return orbit_set(replace(ORBIT, hfov_deg=hfov_deg), t, _vfov(hfov_deg))


def _without_fov(t: float) -> bytes:
    """The orbit's Local Set at t s without tags 16 and 17 (a set that says no field of view)."""
    raw = _set(t, 50.0)
    length, i = read_ber(raw, 16)
    end, items = i + length, []
    while i < end:
        tag, i = read_oid(raw, i)
        n, i = read_ber(raw, i)
        items.append((tag, raw[i : i + n]))
        i += n
    return local_set([(tag, v) for tag, v in items if tag not in (1, 16, 17)])


def test_each_moment_has_its_own_field_of_view_forward_only():
    """Sets at 0 s (40 deg), 0.2 s (20 deg) and 0.4 s (none given: it keeps the one before it,
    ST 0601's report on change): at 0.05 s the camera is 40 + (20 - 40) x 0.25 = 35 deg
    across, at 0.1 s 30 deg, from 0.2 s on 20 deg, past the newest set too; a field of view the
    user gave (own_fov False) stands. The feed's pinhole: 50 deg."""
    poses = LivePoses(stale_after_s=0.1)
    frame = ORBIT.frame()
    intr = Intrinsics.from_fov(*SIZE, 50.0)
    for t, raw in ((0.0, _set(0.0, 40.0)), (0.2, _set(0.2, 20.0)), (0.4, _without_fov(0.4))):
        assert poses.add(t, parse(raw))
    step = 180.0 / 65535  # tag 16's integer step (deg)
    for t, want in ((0.0, 40.0), (0.05, 35.0), (0.1, 30.0), (0.3, 20.0), (0.5, 20.0)):
        camera = poses.at(t, frame, intr, 1000.0).camera
        assert camera.intrinsics.hfov_deg == pytest.approx(want, abs=step), t
        assert (camera.intrinsics.width, camera.intrinsics.height) == SIZE
    given = poses.at(0.05, frame, intr, 1000.0, own_fov=False).camera
    assert given.intrinsics.hfov_deg == pytest.approx(50.0)
    assert poses.hfov_deg == pytest.approx(20.0, abs=step)  # the last one a set gave


def test_a_zooming_feed_is_drawn_with_each_frames_own_field_of_view(tmp_path):
    """2 s of the orbit at 30 fps, a set per frame, the lens zooming from 40 to 22 deg across
    (9 deg a second): every frame drawn with a fresh pose has the field of view of its own
    time, 40 - 9 t deg (within the 2-byte tag's step), not the one the feed began with."""

    def hfov(t: float) -> float:
        return 40.0 - 9.0 * t

    times = np.arange(60) / 30.0
    packets = [(float(t), _set(float(t), hfov(float(t)))) for t in times]
    path = write_video(
        tmp_path / "zoom.ts", times, SIZE, 0, frame=moving_texture(SIZE), crf=28, klv=packets
    )
    port = free_udp_port()
    sender = Sender(path.read_bytes(), ("127.0.0.1", port))
    cameras = []
    run = run_live(
        f"udp://127.0.0.1:{port}",
        LiveOptions(silence_s=2.0, size=(160, 90)),
        clock=sending_clock(sender, port),
        on_drawn=lambda d, camera: cameras.append((d, camera)),
    )
    sender.stop()
    fresh = [(d, c) for d, c in cameras if d.pose == FRESH]
    assert len(fresh) >= 30 and len(fresh) >= 0.9 * len(cameras), run.summary()
    drawn = []
    for d, camera in fresh:
        t = d.pts_s + run.origin_s  # the frame's time on the sender's clock
        assert camera.intrinsics.hfov_deg == pytest.approx(hfov(t), abs=0.01), t
        drawn.append(camera.intrinsics.hfov_deg)
    assert max(drawn) - min(drawn) > 10.0  # a zoom, drawn as one
