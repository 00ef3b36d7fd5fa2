import numpy as np
import pytest

from app.camera.trajectory import PositionTrack, device_to_camera, geodetic_rates
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame, meridian_radius, prime_vertical_radius

ORIGIN = (34.80, 113.53, 110.0)


def test_hermite_passes_through_the_fixes_with_their_velocities():
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.5, 2.0, 8))
    frame = LocalFrame(*ORIGIN)
    enu = np.cumsum(rng.normal(0, 3, (8, 3)), axis=0)
    vel = rng.normal(0, 1.5, (8, 3))
    llh = frame.enu_to_geodetic(enu)
    track = PositionTrack.from_fixes(t, llh[:, 0], llh[:, 1], llh[:, 2], vel)
    at_fixes = track.geodetic_at(t)
    np.testing.assert_allclose(frame.geodetic_to_enu(*at_fixes.T), enu, atol=1e-6)
    # Velocity at each fix by a central difference of the interpolant, in ENU m/s.
    h = 1e-4
    inner = t[1:-1]
    v = (
        frame.geodetic_to_enu(*track.geodetic_at(inner + h).T)
        - frame.geodetic_to_enu(*track.geodetic_at(inner - h).T)
    ) / (2 * h)
    np.testing.assert_allclose(v, vel[1:-1], atol=2e-3)


def test_eq4_rates_by_hand():
    lat, h = 34.8, 110.0
    rates = geodetic_rates(np.array([lat]), np.array([h]), np.array([[2.0, 3.0, 0.5]]))[0]
    assert rates[0] == pytest.approx(3.0 / (meridian_radius(lat) + h))
    assert rates[1] == pytest.approx(
        2.0 / ((prime_vertical_radius(lat) + h) * np.cos(np.radians(lat)))
    )
    assert rates[2] == pytest.approx(0.5)


def test_velocity_estimated_when_the_log_has_none():
    frame = LocalFrame(*ORIGIN)
    t = np.array([0.0, 1.0, 2.5, 3.0, 5.0])
    enu = np.column_stack([1.4 * t, -0.5 * t, 0.1 * t])  # straight line, constant velocity
    llh = frame.enu_to_geodetic(enu)
    track = PositionTrack.from_fixes(t, llh[:, 0], llh[:, 1], llh[:, 2])
    np.testing.assert_allclose(track.vel_enu, np.tile([1.4, -0.5, 0.1], (5, 1)), atol=1e-3)
    mid = frame.geodetic_to_enu(*track.geodetic_at([1.75]).T)[0]
    np.testing.assert_allclose(mid, [1.4 * 1.75, -0.5 * 1.75, 0.1 * 1.75], atol=1e-3)


def test_a_step_kept_between_fixes_is_not_curved_either_side():
    """Fixes a second apart flying east at 10 m/s, 200 m north from t = 10 s on (a spoofed step
    the readers keep: it holds). Its interval is a straight line, and the seconds either side
    follow their own fixes (10 m/s east, no north). Before, the central difference across the
    step gave those fixes 100 m/s north, and the curves either side bulged 14 m (7 %) off."""
    frame = LocalFrame(*ORIGIN)
    t = np.arange(0.0, 20.0)
    enu = np.column_stack([10.0 * t, np.where(t >= 10.0, 200.0, 0.0), np.zeros(len(t))])
    llh = frame.enu_to_geodetic(enu)
    track = PositionTrack.from_fixes(t, llh[:, 0], llh[:, 1], llh[:, 2])
    np.testing.assert_allclose(track.vel_enu[[9, 10]], [[10.0, 0.0, 0.0]] * 2, atol=1e-3)
    tq = np.arange(8.0, 12.0, 0.05)
    got = frame.geodetic_to_enu(*track.geodetic_at(tq).T)
    want = np.where(tq < 9.0, 0.0, np.where(tq >= 10.0, 200.0, 200.0 * (tq - 9.0)))
    np.testing.assert_allclose(got[:, 1], want, atol=1e-3)
    np.testing.assert_allclose(got[:, 0], 10.0 * tq, atol=1e-3)
    # the breaks found while estimating the velocities are those found afresh from the fixes
    given = PositionTrack.from_fixes(t, llh[:, 0], llh[:, 1], llh[:, 2], track.vel_enu)
    np.testing.assert_allclose(given.geodetic_at(tq), track.geodetic_at(tq), atol=1e-9)


def test_slerp_crosses_the_heading_wrap():
    q = rotations.camera_quat_from_hpr(np.array([179.0, -179.0]), 0.0, 0.0)
    mid = rotations.slerp([0.0, 1.0], q, [0.5])
    assert rotations.wrap_degrees(rotations.hpr_from_camera_quat(mid)[0, 0]) == pytest.approx(
        -180.0, abs=1e-6
    )


@pytest.mark.parametrize(
    "rotation, right_in_device",
    [(90, [1, 0, 0]), (0, [0, -1, 0]), (180, [0, 1, 0]), (270, [-1, 0, 0])],
)
def test_device_to_camera_follows_the_display_rotation(rotation, right_in_device):
    q = device_to_camera(rotation)
    np.testing.assert_allclose(rotations.rotate(q, [1, 0, 0]), right_in_device, atol=1e-12)
    np.testing.assert_allclose(
        rotations.rotate(q, [0, 0, -1]), [0, 0, -1], atol=1e-12
    )  # same optical axis
    with pytest.raises(ValueError):
        device_to_camera(45)
