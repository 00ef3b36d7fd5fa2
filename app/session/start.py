"""Where a clip without any GNSS fix begins, roughly (issue 52's cold start): an area the
user names (`--near LAT,LON --radius M`, or a GeoJSON polygon `--start-area FILE`) and the platform's
height above the ground where it knows it (`--height M`). Registration searches the scene over
the area for the first pose (app.register.coldstart); nothing else reads it.

Geodetic coordinates are WGS84 degrees; `enu_area` gives the area in a session's local ENU frame
(metres), as a shapely polygon of (east, north).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from app.geodesy.enu import LocalFrame
from app.io.streams import GnssTrack

HEIGHT_OVER_S = (
    5.0  # a height the telemetry gives: its median over the clip's first seconds (searched)
)
MIN_HEIGHT_M = 5.0  # a platform lower than this above the ground sees too little scene to search
CIRCLE_SEGMENTS = 64  # a circle's polygon: this many segments a quarter (shapely's buffer)


TAKEOFF, ELLIPSOID = "take-off", "ellipsoid"  # what PlatformHeights are above


@dataclass(frozen=True)
class PlatformHeights:
    """The heights a clip's telemetry gives where it has no position (a cold start's, where the
    user gives none): t (N,) session s; h (N,) m; above: TAKEOFF (a barometer's above the
    take-off point, taken for the height above the ground) or ELLIPSOID (ellipsoidal: the
    scene's ground under the area is taken off); said: where they come from, for messages."""

    t: np.ndarray
    h: np.ndarray
    above: str
    said: str


@dataclass(frozen=True)
class StartArea:
    """centre: (lat, lon) degrees (a polygon's: its centroid's); radius_m: a circle's radius
    (m), None for a polygon; polygon: (longitude, latitude) degrees, None for a circle;
    height_m: the platform's height above the ground (m), None where not given; said: how the
    user named it, for messages ("300 m around 34.79900, 113.53000")."""

    centre: tuple[float, float]
    radius_m: float | None = None
    polygon: BaseGeometry | None = None
    height_m: float | None = None

    def __post_init__(self) -> None:
        lat, lon = self.centre
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
            raise ValueError(f"the area's centre {lat:g}, {lon:g} is not latitude, longitude")
        if (self.radius_m is None) == (self.polygon is None):
            raise ValueError("an area is a circle (radius_m) or a polygon, one of the two")
        if self.radius_m is not None and not (np.isfinite(self.radius_m) and self.radius_m > 0):
            raise ValueError(f"the area's radius must be positive metres, got {self.radius_m}")
        if self.height_m is not None and not (np.isfinite(self.height_m) and self.height_m > 0):
            raise ValueError(
                f"the height above the ground must be positive metres, got {self.height_m}"
            )

    @classmethod
    def near(
        cls, lat: float, lon: float, radius_m: float, height_m: float | None = None
    ) -> StartArea:
        """A circle of radius_m metres around (lat, lon) degrees."""
        return cls((float(lat), float(lon)), radius_m=float(radius_m), height_m=height_m)

    @classmethod
    def within(cls, polygon: BaseGeometry, height_m: float | None = None) -> StartArea:
        """A polygon in (longitude, latitude) degrees (app.io.area.read_area)."""
        c = polygon.centroid
        return cls((float(c.y), float(c.x)), polygon=polygon, height_m=height_m)

    @property
    def said(self) -> str:
        lat, lon = self.centre
        if self.radius_m is not None:
            return f"{self.radius_m:g} m around {lat:.5f}, {lon:.5f}"
        return f"the polygon around {lat:.5f}, {lon:.5f}"

    def enu_area(self, frame: LocalFrame) -> BaseGeometry:
        """The area in `frame`'s ENU metres: a polygon of (east, north)."""
        lat, lon = self.centre
        if self.radius_m is not None:
            e, n, _ = frame.geodetic_to_enu(lat, lon, frame.h_m)
            return shapely.Point(float(e), float(n)).buffer(self.radius_m, CIRCLE_SEGMENTS)

        def to_enu(lonlat: np.ndarray) -> np.ndarray:
            enu = frame.geodetic_to_enu(lonlat[:, 1], lonlat[:, 0], np.full(len(lonlat), frame.h_m))
            return np.asarray(enu, np.float64).reshape(-1, 3)[:, :2]

        return shapely.transform(self.polygon, to_enu)

    def outline(self) -> tuple[np.ndarray, np.ndarray]:
        """(lat, lon) degrees of the area's outline, its centre first (what a scene or a world
        is gathered around where a clip has no track)."""
        frame = LocalFrame(*self.centre, 0.0)
        xy = shapely.get_coordinates(self.enu_area(frame))
        enu = np.vstack([[0.0, 0.0, 0.0], np.column_stack([xy, np.zeros(len(xy))])])
        geo = np.asarray(frame.enu_to_geodetic(enu), np.float64).reshape(-1, 3)
        return geo[:, 0], geo[:, 1]

    def outline_track(self, height_m: float, path: str = "") -> GnssTrack:
        """The outline (`outline`) as a track at height_m (m, as the clip's heights are: above
        take-off, or ellipsoidal), one point a second: what a clip without a position has its
        scene gathered around. path: the file it stands for (messages)."""
        lat, lon = self.outline()
        t = np.arange(len(lat), dtype=np.float64)
        return GnssTrack(t, lat, lon, np.full(len(lat), float(height_m)), path=path)

    def centre_enu(self, frame: LocalFrame) -> np.ndarray:
        """(2,) the centre's east, north (m) in `frame`."""
        e, n, _ = frame.geodetic_to_enu(*self.centre, frame.h_m)
        return np.array([float(e), float(n)])
