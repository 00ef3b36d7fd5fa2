"""WGS84 geodetic <-> ECEF <-> local East-North-Up, float64, vectorised over arrays.

Geodetic coordinates are (latitude deg, longitude deg, ellipsoidal height m) on WGS84
(EPSG:4979); ECEF is EPSG:4978 in metres; ENU is metres in the tangent frame at an origin
(x = East, y = North, z = Up). pyproj does the geodetic <-> ECEF part; ECEF <-> ENU is the
standard rotation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from pyproj import Transformer

from app.core.constants import WGS84_A, WGS84_E2

FloatArray = npt.NDArray[np.float64]


@lru_cache(maxsize=1)
def _to_ecef() -> Transformer:
    return Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@lru_cache(maxsize=1)
def _to_geodetic() -> Transformer:
    return Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def geodetic_to_ecef(
    lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
) -> FloatArray:
    """WGS84 latitude, longitude (degrees) and ellipsoidal height (m) -> ECEF (..., 3) metres."""
    lat, lon, h = np.broadcast_arrays(
        np.asarray(lat_deg, np.float64),
        np.asarray(lon_deg, np.float64),
        np.asarray(h_m, np.float64),
    )
    x, y, z = _to_ecef().transform(lon, lat, h)
    return np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=-1)


def ecef_to_geodetic(xyz: npt.ArrayLike) -> FloatArray:
    """ECEF (..., 3) metres -> (..., 3) of latitude deg, longitude deg, ellipsoidal height m."""
    p = np.asarray(xyz, np.float64)
    lon, lat, h = _to_geodetic().transform(p[..., 0], p[..., 1], p[..., 2])
    return np.stack([np.asarray(lat), np.asarray(lon), np.asarray(h)], axis=-1)


def ecef_to_enu_rotation(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> FloatArray:
    """Rotation R with v_enu = R @ v_ecef at the given latitude and longitude (degrees): 3x3,
    or (..., 3, 3) for arrays of positions (its rows: east, north, up in ECEF)."""
    lat, lon = (
        np.radians(np.asarray(lat_deg, np.float64)),
        np.radians(np.asarray(lon_deg, np.float64)),
    )
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    rows = ([-so, co, np.zeros_like(lat)], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl])
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


METRES_PER_DEGREE = (
    111_195.0  # of latitude, on a sphere of the Earth's mean radius (planar sketches)
)


def meridian_radius(lat_deg: npt.ArrayLike) -> FloatArray:
    """Meridian radius of curvature M = a(1-e^2)/(1-e^2 sin^2 phi)^(3/2), metres."""
    s = np.sin(np.radians(np.asarray(lat_deg, np.float64)))
    return WGS84_A * (1.0 - WGS84_E2) / (1.0 - WGS84_E2 * s * s) ** 1.5


def prime_vertical_radius(lat_deg: npt.ArrayLike) -> FloatArray:
    """Prime-vertical radius of curvature N = a/(1-e^2 sin^2 phi)^(1/2), metres."""
    s = np.sin(np.radians(np.asarray(lat_deg, np.float64)))
    return WGS84_A / np.sqrt(1.0 - WGS84_E2 * s * s)


@dataclass(frozen=True)
class LocalFrame:
    """The session's local ENU frame, tangent at an origin on the WGS84 ellipsoid.

    lat_deg, lon_deg: origin latitude and longitude, degrees; h_m: ellipsoidal height, metres.
    """

    lat_deg: float
    lon_deg: float
    h_m: float
    origin_ecef: FloatArray = field(init=False, repr=False, compare=False)
    rotation: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (-90.0 <= self.lat_deg <= 90.0) or not (-180.0 <= self.lon_deg <= 360.0):
            raise ValueError(f"origin out of range: lat={self.lat_deg}, lon={self.lon_deg}")
        object.__setattr__(
            self, "origin_ecef", geodetic_to_ecef(self.lat_deg, self.lon_deg, self.h_m)
        )
        object.__setattr__(self, "rotation", ecef_to_enu_rotation(self.lat_deg, self.lon_deg))

    def ecef_to_enu(self, xyz: npt.ArrayLike) -> FloatArray:
        """ECEF (..., 3) metres -> ENU (..., 3) metres relative to the origin."""
        return (np.asarray(xyz, np.float64) - self.origin_ecef) @ self.rotation.T

    def enu_to_ecef(self, enu: npt.ArrayLike) -> FloatArray:
        """ENU (..., 3) metres -> ECEF (..., 3) metres."""
        return np.asarray(enu, np.float64) @ self.rotation + self.origin_ecef

    def geodetic_to_enu(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
    ) -> FloatArray:
        """Latitude, longitude (deg), ellipsoidal height (m) -> ENU (..., 3) metres."""
        return self.ecef_to_enu(geodetic_to_ecef(lat_deg, lon_deg, h_m))

    def enu_to_geodetic(self, enu: npt.ArrayLike) -> FloatArray:
        """ENU (..., 3) metres -> (..., 3) latitude deg, longitude deg, ellipsoidal height m."""
        return ecef_to_geodetic(self.enu_to_ecef(enu))

    def rotation_to(self, other: LocalFrame) -> FloatArray:
        """3x3 R with v_other_enu = R @ v_self_enu (directions; tangent planes differ slightly)."""
        return other.rotation @ self.rotation.T
