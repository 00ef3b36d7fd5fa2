import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics, projection_matrix
from app.camera.pinhole import Camera, depth_map_size, look_at_quat
from app.geodesy import rotations


def test_projection_matrix_by_hand():
    intr = Intrinsics(640, 480, 500.0, 400.0, 300.0, 250.0)
    p = projection_matrix(intr, near=1.0, far=101.0)
    expected = np.array(
        [
            [1000 / 640, 0, 1 - 600 / 640, 0],
            [0, 800 / 480, 500 / 480 - 1, 0],
            [0, 0, -102 / 100, -202 / 100],
            [0, 0, -1, 0],
        ]
    )
    np.testing.assert_allclose(p, expected, atol=1e-12)


def test_near_and_far_map_to_ndc_limits():
    p = projection_matrix(Intrinsics.from_fov(100, 100, 90), near=2.0, far=50.0)
    for z, ndc in ((-2.0, -1.0), (-50.0, 1.0)):
        clip = p @ [0, 0, z, 1]
        assert clip[2] / clip[3] == pytest.approx(ndc)


def test_fov_focal_round_trip():
    intr = Intrinsics.from_fov(640, 480, 90.0)
    assert intr.fx == pytest.approx(320.0)
    assert intr.hfov_deg == pytest.approx(90.0)
    assert intr.vfov_deg == pytest.approx(2 * np.degrees(np.arctan(240 / 320)))
    v = Intrinsics.from_fov(640, 480, 60.0, axis="vertical")
    assert v.vfov_deg == pytest.approx(60.0)
    f = Intrinsics.from_focal_length(4000, 3000, 4.25, 5.6)
    assert f.fx == pytest.approx(4.25 / 5.6 * 4000)
    with pytest.raises(ValueError):
        Intrinsics.from_fov(640, 480, 180.0)


def test_pixel_of_a_known_point_matches_the_matrices():
    # Camera 10 m up looking north; a point 20 m north, 5 m east, 2 m up lands at
    # u = cx + fx * 5/20, v = cy - fy * (-8)/20 (8 m below the optical axis).
    intr = Intrinsics(640, 480, 400.0, 400.0, 320.0, 240.0)
    cam = Camera.create(
        intr, [0, 0, 10], rotations.camera_quat_from_hpr(0, 0, 0), near=1.0, far=100.0
    )
    uv, depth = cam.project([[5.0, 20.0, 2.0]])
    assert uv[0] == pytest.approx([320 + 100, 240 + 160])
    assert depth[0] == pytest.approx(20.0)
    clip = cam.view_projection @ [5.0, 20.0, 2.0, 1.0]
    ndc = clip[:3] / clip[3]
    assert (ndc[0] + 1) / 2 * 640 == pytest.approx(420)
    assert (1 - ndc[1]) / 2 * 480 == pytest.approx(400)
    ray = cam.pixel_rays(uv)[0]
    np.testing.assert_allclose(ray, np.array([5, 20, -8]) / np.linalg.norm([5, 20, -8]), atol=1e-12)


def test_look_at_and_frustum():
    q = look_at_quat([0, 0, 0], [10, 0, 0])
    np.testing.assert_allclose(rotations.rotate(q, [0, 0, -1]), [1, 0, 0], atol=1e-12)
    cam = Camera.create(
        Intrinsics.from_fov(200, 100, 90),
        [0, 0, 0],
        rotations.camera_quat_from_hpr(0, 0, 0),
        near=1,
        far=10,
    )
    corners = cam.frustum_corners()
    np.testing.assert_allclose(corners[0], [-1, 1, 0.5], atol=1e-12)  # near top-left
    np.testing.assert_allclose(corners[6], [10, 10, -5], atol=1e-12)  # far bottom-right


def test_depth_map_size_follows_video_aspect():
    assert depth_map_size(1920, 1080, 2048) == (2048, 1152)
    assert depth_map_size(1080, 1920, 2048) == (1152, 2048)
