import numpy as np
import pytest

from app.core.constants import WGS84_A, WGS84_E2
from app.geodesy import enu as geo

ORIGIN = (34.80, 113.53, 110.0)


def closed_form_ecef(lat, lon, h):
    """Independent textbook formula, to check pyproj's answer."""
    phi, lam = np.radians(lat), np.radians(lon)
    n = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(phi) ** 2)
    return np.array(
        [
            (n + h) * np.cos(phi) * np.cos(lam),
            (n + h) * np.cos(phi) * np.sin(lam),
            (n * (1 - WGS84_E2) + h) * np.sin(phi),
        ]
    )


def test_published_ecef_points():
    # The semi-major axis on the equator at the prime meridian, the semi-minor axis at the pole
    # (WGS84: a = 6378137 m, b = 6356752.314245 m).
    np.testing.assert_allclose(
        geo.geodetic_to_ecef(0.0, 0.0, 0.0), [6378137.0, 0.0, 0.0], atol=1e-6
    )
    np.testing.assert_allclose(
        geo.geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, 6356752.314245], atol=1e-6
    )
    np.testing.assert_allclose(
        geo.geodetic_to_ecef(0.0, 90.0, 100.0), [0.0, 6378237.0, 0.0], atol=1e-6
    )
    np.testing.assert_allclose(geo.geodetic_to_ecef(*ORIGIN), closed_form_ecef(*ORIGIN), atol=1e-6)


def test_scalar_and_array_agree():
    lat = np.array([34.8, -33.9, 60.1])
    lon = np.array([113.53, 18.4, -150.0])
    h = np.array([110.0, 0.0, 2500.0])
    arr = geo.geodetic_to_ecef(lat, lon, h)
    assert arr.shape == (3, 3)
    for i in range(3):
        np.testing.assert_allclose(arr[i], geo.geodetic_to_ecef(lat[i], lon[i], h[i]), atol=1e-9)


def test_round_trips_below_a_millimetre():
    rng = np.random.default_rng(1)
    frame = geo.LocalFrame(*ORIGIN)
    enu = rng.uniform(-5000, 5000, (1000, 3))
    back = frame.ecef_to_enu(frame.enu_to_ecef(enu))
    assert np.abs(back - enu).max() < 1e-3
    llh = frame.enu_to_geodetic(enu)
    assert np.abs(frame.geodetic_to_enu(llh[:, 0], llh[:, 1], llh[:, 2]) - enu).max() < 1e-3
    pts = np.column_stack(
        [rng.uniform(-89, 89, 500), rng.uniform(-180, 180, 500), rng.uniform(-100, 9000, 500)]
    )
    ecef = geo.geodetic_to_ecef(pts[:, 0], pts[:, 1], pts[:, 2])
    assert np.abs(geo.geodetic_to_ecef(*geo.ecef_to_geodetic(ecef).T) - ecef).max() < 1e-3


def test_one_kilometre_north_drops_below_the_tangent_plane():
    frame = geo.LocalFrame(*ORIGIN)
    dlat = np.degrees(1000.0 / (geo.meridian_radius(ORIGIN[0]) + ORIGIN[2]))
    e, n, u = frame.geodetic_to_enu(ORIGIN[0] + dlat, ORIGIN[1], ORIGIN[2])
    assert abs(e) < 1e-6
    assert n == pytest.approx(1000.0, abs=0.01)
    assert u == pytest.approx(-0.0785, abs=0.005)  # ~ -d^2 / 2R


def test_enu_axes_point_east_north_up():
    frame = geo.LocalFrame(*ORIGIN)
    up = frame.geodetic_to_enu(ORIGIN[0], ORIGIN[1], ORIGIN[2] + 10.0)
    np.testing.assert_allclose(up, [0, 0, 10], atol=1e-6)
    east = frame.geodetic_to_enu(ORIGIN[0], ORIGIN[1] + 0.001, ORIGIN[2])
    assert east[0] > 90 and abs(east[1]) < 0.01


def test_radii_at_known_latitudes():
    # Equator: M = a(1-e^2), N = a. Pole: M = N = a / sqrt(1-e^2).
    assert geo.meridian_radius(0.0) == pytest.approx(6335439.327, abs=1e-3)
    assert geo.prime_vertical_radius(0.0) == pytest.approx(6378137.0, abs=1e-6)
    assert geo.meridian_radius(90.0) == pytest.approx(6399593.626, abs=1e-3)
    assert geo.prime_vertical_radius(90.0) == pytest.approx(6399593.626, abs=1e-3)
