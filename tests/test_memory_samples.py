"""The scene memory's compiled pass for lensless cameras (app.export.memory._pinhole_visible)
keeps exactly the samples, frame pixels and qualities that the general numpy path (any lens,
through Camera.project and scipy's nearest-pixel lookups) keeps: random surfaces seen from random
poses, with hidden points, edge-on points, points behind the camera, a distance map and an
agreement map smaller than the frame, and a pose uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.export.memory import SurfaceMemory


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("with_agreement", [False, True])
def test_the_compiled_pass_keeps_what_the_general_path_keeps(seed, with_agreement):
    rng = np.random.default_rng(seed)
    n = 40_000
    points = rng.uniform([-60, -60, -5], [60, 60, 25], (n, 3))
    normals = rng.normal(size=(n, 3))
    normals[: n // 3] = [0, 0, 1]  # a third face up, the rest any way (some edge-on)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    memory = SurfaceMemory(points, normals)
    intr = Intrinsics.from_fov(960, 540, float(rng.uniform(40, 90)))
    eye = rng.uniform([-30, -30, 40], [30, 30, 80])
    target = rng.uniform([-20, -20, 0], [20, 20, 5])
    camera = Camera.create(intr, eye, look_at_quat(eye, target), 0.5, 2000.0)
    # a distance map smaller than the image (as painting renders it), some of it nearer than
    # the points (they are hidden), some empty (inf)
    dist = rng.uniform(20.0, 140.0, (135, 240))
    dist[rng.random(dist.shape) < 0.2] = np.inf
    agree = rng.uniform(0.2, 1.0, (135, 240)).astype(np.float32) if with_agreement else None
    idx = np.arange(n)
    frame_hw = (360, 640)  # decoded smaller than the camera's image
    sigmas = (0.4, 0.3)
    want = memory._samples(idx, frame_hw, camera, dist, agree, sigmas)
    got = memory._pinhole_samples(idx, frame_hw, camera, dist, agree, sigmas)
    assert len(want[0]) > 1000  # a pass that keeps something
    assert len(want[0]) < 0.9 * len(points[points[:, 2] < 100])  # and leaves some out
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-6)
    assert got[2].dtype == np.float32
