import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.geodesy import rotations


def optical_axis(q):
    return rotations.rotate(q, [0.0, 0.0, -1.0])


def test_level_camera_looking_north():
    r = rotations.camera_matrix_from_hpr(0.0, 0.0, 0.0)
    np.testing.assert_allclose(r @ [0, 0, -1], [0, 1, 0], atol=1e-12)  # optical axis north
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, 1], atol=1e-12)  # image up = world up
    np.testing.assert_allclose(r @ [1, 0, 0], [1, 0, 0], atol=1e-12)  # image right = east


@pytest.mark.parametrize(
    "hpr, axis",
    [
        ((90.0, 0.0, 0.0), [1, 0, 0]),
        ((180.0, 0.0, 0.0), [0, -1, 0]),
        ((270.0, 0.0, 0.0), [-1, 0, 0]),
        ((0.0, 30.0, 0.0), [0, np.cos(np.radians(30)), 0.5]),
        ((45.0, -90.0, 0.0), [0, 0, -1]),
    ],
)
def test_heading_and_pitch_move_the_optical_axis(hpr, axis):
    q = rotations.camera_quat_from_hpr(*hpr)
    np.testing.assert_allclose(optical_axis(q), axis, atol=1e-12)


def test_positive_roll_lowers_the_image_right_side():
    q = rotations.camera_quat_from_hpr(0.0, 0.0, 10.0)
    right = rotations.rotate(q, [1.0, 0.0, 0.0])
    assert right[2] == pytest.approx(-np.sin(np.radians(10.0)))
    np.testing.assert_allclose(optical_axis(q), [0, 1, 0], atol=1e-12)


def test_hpr_round_trip_and_wrap():
    rng = np.random.default_rng(3)
    hpr = np.column_stack(
        [rng.uniform(0, 360, 500), rng.uniform(-85, 85, 500), rng.uniform(-179, 179, 500)]
    )
    back = rotations.hpr_from_camera_quat(rotations.camera_quat_from_hpr(*hpr.T))
    np.testing.assert_allclose(rotations.wrap_degrees(back - hpr), 0.0, atol=1e-8)
    assert rotations.wrap_degrees(181.0) == pytest.approx(-179.0)


def test_multiply_matches_scipy():
    rng = np.random.default_rng(5)
    a = Rotation.random(50, random_state=rng)
    b = Rotation.random(50, random_state=rng)
    ours = rotations.multiply(rotations.from_scipy(a), rotations.from_scipy(b))
    ref = rotations.from_scipy(a * b)
    np.testing.assert_allclose(rotations.canonical(ours), ref, atol=1e-12)
    v = rng.normal(size=(50, 3))
    np.testing.assert_allclose(rotations.rotate(rotations.from_scipy(a), v), a.apply(v), atol=1e-12)


def test_angle_between():
    q1 = rotations.camera_quat_from_hpr(10.0, 0.0, 0.0)
    q2 = rotations.camera_quat_from_hpr(13.0, 0.0, 0.0)
    assert np.degrees(rotations.angle_between(q1, q2)) == pytest.approx(3.0)


def test_circular_mean_across_the_wrap():
    assert rotations.circular_mean(np.radians([179.0, -179.0])) == pytest.approx(np.pi)
    assert rotations.circular_mean(np.radians([10.0, 30.0])) == pytest.approx(np.radians(20.0))
