"""The camera's own motion seen in the video (app.register.flow_motion): a step per metre of
height from corners met with a level ground, checked on rays made by hand, the height that
scales it fitted to where the track was measured, and the corners tracked once for a solve's
carries."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geodesy import rotations
from app.io.video import frames_at, probe
from app.register import flow_motion
from app.register.flow_motion import FlowSteps, ground_step, height, stretch_velocities
from app.simulate.phone import write_video

OPENGL = np.array([1.0, -1.0, -1.0])  # OpenGL camera axes <-> OpenCV's (its own inverse)


def _bearings(points: np.ndarray, camera: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Unit bearings (OpenCV camera axes) from a camera at `camera` (ENU m) with attitude q
    (camera -> ENU, OpenGL axes) to `points` (N, 3)."""
    d = rotations.rotate(rotations.conjugate(q), points - camera) * OPENGL
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _ground(n: int = 60, seed: int = 0) -> np.ndarray:
    """Points of a level ground 35 m below the cameras, ahead and around (ENU m)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-40, 40, n), rng.uniform(10, 70, n), np.full(n, -35.0)])


@pytest.mark.parametrize(
    ("hpr1", "hpr2"),
    [((0.0, -90.0, 0.0), (0.0, -90.0, 0.0)), ((10.0, -40.0, 2.0), (16.0, -37.0, -1.0))],
)
def test_a_step_over_level_ground_is_the_cameras_move_per_metre_of_height(hpr1, hpr2):
    """Straight down, and looking 40 deg down while turning 6 deg between the frames: the
    camera moves 3.5 m east and 1.4 m north 35 m above the ground, so 0.1 and 0.04 per metre;
    corners in the sky (above the horizon) and near it (under 10 deg down) are left out."""
    q1, q2 = (rotations.camera_quat_from_hpr(*hpr) for hpr in (hpr1, hpr2))
    c1, c2 = np.zeros(3), np.array([3.5, 1.4, 0.0])
    ground = _ground()
    sky = np.column_stack([np.linspace(-30, 30, 20), np.full(20, 60.0), np.full(20, 30.0)])
    far = np.column_stack([np.linspace(-30, 30, 20), np.full(20, 400.0), np.full(20, -35.0)])
    points = np.vstack([ground, sky, far])
    b1, b2 = _bearings(points, c1, q1), _bearings(points, c2, q2)
    seen = (b1[:, 2] > 0) & (b2[:, 2] > 0)  # in front of both cameras
    step = ground_step(b1[seen], b2[seen], q1, q2)
    assert step == pytest.approx([0.1, 0.04], abs=1e-9)
    # a corner that is not on the ground (a roof 10 m up) is outvoted by the ground's
    roofs = ground[:15] + [0.0, 0.0, 10.0]
    mixed = np.vstack([ground, roofs])
    b1, b2 = _bearings(mixed, c1, q1), _bearings(mixed, c2, q2)
    assert ground_step(b1, b2, q1, q2) == pytest.approx([0.1, 0.04], abs=0.01)
    # the sky alone gives no step, nor the ground 400 m off (5 deg down)
    for alone in (sky, far):
        b1, b2 = _bearings(alone, c1, q1), _bearings(alone, c2, q2)
        seen = (b1[:, 2] > 0) & (b2[:, 2] > 0)
        assert ground_step(b1[seen], b2[seen], q1, q2) is None


def test_the_height_scales_the_steps_to_where_the_track_was_measured():
    """Steps of 0.3 m per metre of height, where the track moved 10.5 m each (35 m up): 35 m;
    only those known count; too few known, or a track that moved across the steps, none."""
    n = 12
    step = np.tile([0.3, 0.0], (n, 1)) + np.random.default_rng(1).normal(0, 0.01, (n, 2))
    steps = FlowSteps(np.arange(n) * 0.1, np.full(n, 0.1), step)
    moved = 35.0 * step
    known = np.ones(n, bool)
    assert height(steps, moved, known) == pytest.approx(35.0)
    moved[:4] = [100.0, 0.0]  # where the track was not measured: not counted
    known[:4] = False
    assert height(steps, moved, known) == pytest.approx(35.0)
    known[:8] = False  # 4 known: too few
    assert height(steps, moved, known) is None
    across = np.column_stack([np.zeros(n), np.full(n, 10.5)])  # the track went north
    assert height(steps, across, np.ones(n, bool)) is None


def test_a_stretch_is_scaled_from_both_sides_or_left_to_the_carry():
    """Steps every 0.1 s over 0-9 s, the track measured over 0-3 s and 6-9 s, moving 10 m/s
    east: the stretch 3-6 s gets one velocity per 0.5 s, the height running from the one fitted
    before (35 m) to the one after (40 m: the steps there a little shorter); measured on one side
    only (the clip's end), or the two heights 1.5 times apart, it is left to the carry."""
    t = np.arange(0.05, 9.0, 0.1)
    rate = np.where(t[:, None] < 4.5, [10.0 / 35.0, 0.0], [10.0 / 40.0, 0.0])
    steps = FlowSteps(t, np.full(len(t), 0.1), rate * 0.1)
    moved = np.tile([1.0, 0.0], (len(t), 1))
    known = (t < 3.0) | (t > 6.0)
    got = stretch_velocities(steps, [(moved, known)], 3.0, 6.0)
    assert got is not None
    flow, h_a, h_b = got
    assert (h_a, h_b) == pytest.approx((35.0, 40.0))
    assert len(flow.t) == 6 and np.all(np.diff(flow.t) > 0)
    # the height runs linearly across: 35 -> 40 m over 3 s, on steps of 10/35 then 10/40
    h = 35.0 + (flow.t - 3.0) / 3.0 * 5.0
    want = h * np.where(flow.t < 4.5, 10.0 / 35.0, 10.0 / 40.0)
    assert flow.v[:, 0] == pytest.approx(want, rel=0.02) and np.all(flow.v[:, 1:] == 0.0)
    assert stretch_velocities(steps, [(moved, t < 3.0)], 3.0, 6.0) is None
    far = moved * np.where(t > 6.0, 1.6, 1.0)[:, None]  # 64 m after, 35 m before
    assert stretch_velocities(steps, [(far, known)], 3.0, 6.0) is None
    # a second kind of measurement (the fixes) fits a side the first (the keyframes) does not
    assert stretch_velocities(steps, [(moved, t < 3.0), (moved, known)], 3.0, 6.0) is not None


def test_the_corners_are_tracked_once_for_a_solves_carries(tmp_path, monkeypatch):
    """A textured ground slides 3 px a frame under a camera looking straight down (60 deg
    across 160 px: f = 80 / tan 30 deg = 138.6 px): each step is 3 / 138.6 = 0.0217 per metre
    of height, across the image. Asked again with the same `Seen` (a solve's next carry), under
    the camera turned 90 deg about the vertical (another attitude correction), nothing is
    decoded again and the steps turn with it."""
    rng = np.random.default_rng(1)
    noise = rng.uniform(0, 255, (40, 80)).astype(np.float32)
    texture = cv2.resize(noise, (320, 120), interpolation=cv2.INTER_CUBIC)
    texture = texture.clip(0, 255).astype(np.uint8)

    def frame(k: int) -> np.ndarray:
        grey = texture[:, 120 - 3 * k : 280 - 3 * k]
        return np.repeat(grey[:, :, None], 3, axis=2)

    times = np.arange(12) / 30.0
    video = probe(write_video(tmp_path / "ground.mp4", times, (160, 120), 0, frame=frame, crf=10))
    f = 80.0 / np.tan(np.radians(30.0))

    def bearings(px: np.ndarray) -> np.ndarray:
        d = np.column_stack([(px[:, 0] - 80.0) / f, (px[:, 1] - 60.0) / f, np.ones(len(px))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def looking(heading: float):
        q = rotations.camera_quat_from_hpr(heading, -90.0, 0.0)
        return lambda t: np.repeat(np.asarray(q)[None], len(t), axis=0)

    decoded = []

    def counted(*args, **kwargs):
        decoded.append(args[1])
        return frames_at(*args, **kwargs)

    monkeypatch.setattr(flow_motion, "frames_at", counted)
    seen = flow_motion.Seen()
    first = flow_motion.flow_steps(video, times, range(12), looking(0.0), bearings, 160, seen)
    assert len(decoded) == 1 and len(first.t) == 11
    np.testing.assert_allclose(np.linalg.norm(first.step, axis=1), 3.0 / f, rtol=0.05)
    turned = flow_motion.flow_steps(video, times, range(12), looking(90.0), bearings, 160, seen)
    assert len(decoded) == 1  # the corners of the first call
    np.testing.assert_allclose(turned.t, first.t)
    # turned 90 deg about the vertical: each step turns with the camera (east <-> north)
    np.testing.assert_allclose(np.abs(turned.step), np.abs(first.step[:, ::-1]), atol=1e-9)
    flow_motion.flow_steps(video, times, range(0, 12, 2), looking(0.0), bearings, 160, seen)
    assert len(decoded) == 2  # other pairs: decoded again
