"""Where is what the video shows: the point of the scene a pixel of a posed camera sees.

The ray through the pixel (through the camera's lens: `Camera.pixel_rays`) is followed to the
first surface of the scene, occlusion included, by the GPU position pass (app.render.probe) of a
narrow pinhole camera along that ray (RAY_GRID x RAY_GRID pixels spanning RAY_FOV_DEG): its
centre pixel is the point, its neighbours give the surface's normal, from which the grazing
angle comes. A ray that meets nothing within the camera's far plane is the sky.

The uncertainty is what the pose's error explains, in metres on the surface: the position's
(sigma_position_m) and the attitude's (sigma_attitude_deg, times the range, stretched by the
grazing angle: an error across a surface seen at incidence i moves the point 1 / sin(i) times
as far), added in quadrature. The pose's errors per source: app.solve.uncertainty.

Pixels are image coordinates of the displayed video (or still): x right, y down, (0, 0) the
top-left corner of the top-left pixel, pixel centres at half-integers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.camera.frame_time import frame_at
from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, image_size, look_at_quat
from app.core.constants import DEFAULT_NEAR_M
from app.core.errors import GeofuseError
from app.footage.clips import open_any
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.render.probe import SurfaceProbe
from app.scene.city.model import Feature
from app.scene.mesh import MeshData
from app.session.model import Session
from app.solve.track import solve_track
from app.solve.uncertainty import PoseSigmas, pose_sigmas

__all__ = [
    "Location",
    "Locator",
    "feature_tolerance",
    "image_size",
    "locate",
    "ray_camera",
    "video_pixel",
]

RAY_GRID = 3  # pixels a side of the camera along a ray: the centre, and neighbours for the normal
RAY_FOV_DEG = 0.02  # its field of view: 3 cm across at 100 m
LOCATE_FAR_M = 20_000.0  # a ray that meets nothing within this range is the sky
MIN_SIN_INCIDENCE = 0.1  # grazing views stretch the error at most 10 times
FEATURE_TOLERANCE_M = 0.05  # a located point this near a city surface is on it, plus
FEATURE_TOLERANCE_PER_M = 1e-3  # this much per metre of range


@dataclass(frozen=True)
class Location:
    """A pixel's point on the scene. pixel: (x, y) image px; enu: (3,) m in the session's local
    frame; lat, lon: WGS84 deg; height_m: above the ellipsoid; msl_m: above mean sea level
    (EGM2008); range_m: from the camera; incidence_deg: between the ray and the surface (90:
    head-on; None where the neighbours do not give a normal); uncertainty_m: what the pose's
    error explains on the surface (None without sigmas); feature: the city object the point
    lies on (its id, surface kind, attributes), None off city models."""

    pixel: tuple[float, float]
    enu: tuple[float, float, float]
    lat: float
    lon: float
    height_m: float
    msl_m: float
    range_m: float
    incidence_deg: float | None
    uncertainty_m: float | None
    feature: Feature | None = None

    def as_dict(self) -> dict[str, object]:
        """The fields for JSON, named with their units."""
        return {
            "pixel": list(self.pixel),
            "latitude": self.lat,
            "longitude": self.lon,
            "ellipsoid_height_m": self.height_m,
            "msl_height_m": self.msl_m,
            "enu_m": list(self.enu),
            "range_m": self.range_m,
            "incidence_deg": self.incidence_deg,
            "uncertainty_m": self.uncertainty_m,
            "object": None if self.feature is None else self.feature.as_dict(),
        }

    def line(self) -> str:
        """One line for people."""
        e, n, u = self.enu
        unc = "" if self.uncertainty_m is None else f", +-{self.uncertainty_m:.2f} m"
        on = "" if self.feature is None else f"; on {self.feature.line()}"
        return (
            f"pixel {self.pixel[0]:g},{self.pixel[1]:g}: {self.lat:.8f}, {self.lon:.8f}, "
            f"{self.height_m:.2f} m ellipsoidal ({self.msl_m:.2f} m above sea level); "
            f"ENU {e:.2f}, {n:.2f}, {u:.2f} m; range {self.range_m:.2f} m{unc}{on}"
        )


def video_pixel(camera: Camera, point_enu: npt.ArrayLike) -> tuple[float, float] | None:
    """The image pixel (x, y) at which `camera` (through its lens) sees the point (ENU m), or
    None when the point is behind it or outside its image."""
    uv, depth = camera.project(np.asarray(point_enu, np.float64).reshape(1, 3))
    w, h = image_size(camera)
    u, v = float(uv[0, 0]), float(uv[0, 1])
    return (u, v) if depth[0] > 0 and 0 <= u < w and 0 <= v < h else None


def ray_camera(camera: Camera, pixel: tuple[float, float], far: float = LOCATE_FAR_M) -> Camera:
    """A narrow pinhole (RAY_GRID px, RAY_FOV_DEG) at the camera, looking along the ray through
    `pixel` (through its lens). Raises ValueError for a pixel outside the image."""
    w, h = image_size(camera)
    x, y = pixel
    if not (0.0 <= x <= w and 0.0 <= y <= h) or not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"pixel {x:g},{y:g} lies outside the {w}x{h} image")
    ray = camera.pixel_rays([[x, y]])[0]
    if not np.all(np.isfinite(ray)):
        raise ValueError(f"pixel {x:g},{y:g} lies outside what the lens sees")
    eye = np.asarray(camera.position, np.float64)
    # an up vector away from the ray (look_at_quat needs one that is not parallel to it)
    up = (0.0, 0.0, 1.0) if abs(ray[2]) < 0.99 else (0.0, 1.0, 0.0)
    f = RAY_GRID / 2 / math.tan(math.radians(RAY_FOV_DEG) / 2)
    return Camera.create(
        Intrinsics(RAY_GRID, RAY_GRID, f, f, RAY_GRID / 2, RAY_GRID / 2),
        eye,
        look_at_quat(eye, eye + ray, up),
        near=max(camera.near, DEFAULT_NEAR_M) * 0.1,
        far=far,
    )


def location_of(
    points: np.ndarray,
    camera: Camera,
    pixel: tuple[float, float],
    frame: LocalFrame,
    sigmas: PoseSigmas | None,
    scene: MeshData | None = None,
) -> Location | None:
    """The Location from a ray camera's position map (RAY_GRID, RAY_GRID, 3) ENU m; None where
    its centre meets nothing. scene: the city objects of its feature tables are named."""
    c = RAY_GRID // 2
    p = np.asarray(points[c, c], np.float64)
    if not np.all(np.isfinite(p)):
        return None
    eye = np.asarray(camera.position, np.float64)
    ray = p - eye
    rng = float(np.linalg.norm(ray))
    normal = np.cross(points[c, c + 1] - points[c, c - 1], points[c - 1, c] - points[c + 1, c])
    incidence = None
    if np.all(np.isfinite(normal)) and np.linalg.norm(normal) > 0:
        cos = abs(float(np.dot(normal, ray))) / (np.linalg.norm(normal) * rng)
        incidence = float(np.degrees(np.arcsin(min(1.0, cos))))
    lat, lon, h = frame.enu_to_geodetic(p[None])[0]
    unc = None
    if sigmas is not None:
        stretch = 1.0 / max(
            math.sin(math.radians(incidence if incidence is not None else 90.0)),
            MIN_SIN_INCIDENCE,
        )
        across = rng * math.radians(sigmas.attitude_deg) * stretch
        unc = math.hypot(sigmas.position_m, across)
    return Location(
        (float(pixel[0]), float(pixel[1])),
        (float(p[0]), float(p[1]), float(p[2])),
        float(lat),
        float(lon),
        float(h),
        float(h - undulation(lat, lon)),
        rng,
        incidence,
        unc,
        None if scene is None else scene.feature_at(p, feature_tolerance(rng)),
    )


def feature_tolerance(range_m: float) -> float:
    """How far (m) a located point may lie from a city object's surface and still be on it:
    the position pass's depth precision grows with range."""
    return FEATURE_TOLERANCE_M + FEATURE_TOLERANCE_PER_M * range_m


class Locator:
    """Pixels to scene points for one scene, off-screen (its own EGL context: `release()`)."""

    def __init__(self, mesh: MeshData, frame: LocalFrame) -> None:
        self.frame = frame
        self.mesh = mesh
        self.probe = SurfaceProbe(mesh)

    def locate(
        self,
        camera: Camera,
        pixels: npt.ArrayLike,
        sigmas: PoseSigmas | None = None,
    ) -> list[Location | None]:
        """Each pixel's Location (None: the sky). Raises ValueError for a pixel outside the
        image."""
        out = []
        for x, y in np.atleast_2d(np.asarray(pixels, np.float64)):
            ray = ray_camera(camera, (x, y))
            out.append(
                location_of(self.probe.points(ray), ray, (x, y), self.frame, sigmas, self.mesh)
            )
        return out

    def release(self) -> None:
        self.probe.release()


def locate(
    source: Session | str | Path,
    time_s: float,
    pixels: npt.ArrayLike,
    attitude: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> list[Location | None]:
    """Where the pixels (N, 2) of the video frame shown at media time `time_s` (s from the first
    frame; app.camera.frame_time.frame_at) lie on the session's scene, under the pose source
    `attitude` (default: the session's first). `source`: a Session, or a manifest or clip path.
    For notebooks; `geofuse locate` prints the same. Raises GeofuseError for a bad source or
    time, ValueError for a pixel outside the image."""
    session = source if isinstance(source, Session) else open_any(source)
    name = attitude or session.sources[0]
    try:
        session.check_source(name)
    except ValueError as exc:
        raise GeofuseError(f"--source: {exc}") from exc
    pts = session.video.pts_s
    if not pts[0] - 0.5 <= time_s <= pts[-1] + 0.5:
        raise GeofuseError(
            f"--time {time_s:g}: the video runs from {pts[0]:.3f} to {pts[-1]:.3f} s"
        )
    track = solve_track(session, name, progress=progress).with_clip(DEFAULT_NEAR_M, LOCATE_FAR_M)
    camera = track.frame_camera(frame_at(pts, time_s))
    locator = Locator(session.scene(), session.frame)
    try:
        return locator.locate(camera, pixels, pose_sigmas(session, track, frame_at(pts, time_s)))
    finally:
        locator.release()
