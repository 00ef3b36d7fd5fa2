"""What every export says about a frame: the sensor's place and attitude, its field of view, and
where the image lands on the scene (frame centre, corners, footprint), from the session's camera
track (app.session.camera_track) and the model (or assumed ground) through the GPU position pass.

Frames: WGS84 latitude/longitude in degrees, ellipsoidal heights in metres; heading, pitch, roll
of the optical axis in degrees (DESIGN.md); times in seconds. A border ray that meets no surface
(above the horizon, or past the model's edge) is clipped at `max_range_m` along the ray, and the
record says so (`clipped`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from app.camera.pinhole import Camera
from app.core.constants import VIEW_FAR_M, VIEW_NEAR_M
from app.geodesy import rotations
from app.geodesy.geoid import undulation
from app.render.probe import SurfaceProbe, border_sampling
from app.session.camera_track import CameraTrack
from app.session.model import Session
from app.solve.track import solve_track

FOOTPRINT_MAX_RANGE_M = 2000.0  # border rays that meet nothing are clipped at this range
FOOTPRINT_SAMPLES = (33, 19)  # rays across the image, and down it (the border's samples)
LENS_PROBE_PX = 1024  # width of the position map looked up for cameras with a real lens


@dataclass(frozen=True)
class FrameRecord:
    """One exported frame. utc_s: Unix seconds (UTC) when the session has a clock
    (Session.utc_of), else None; sensor: (lat, lon, h) degrees and metres above the WGS84
    ellipsoid; hpr: heading, pitch, roll (deg); centre: (lat, lon, h) where the optical axis
    meets the scene, slant_m its distance (NaN when the axis meets nothing); corners: (4, 3)
    top-left, top-right, bottom-right, bottom-left image corners on the scene; footprint: (N, 3)
    the image border on the scene, clockwise in the image from the top-left corner (not closed);
    clipped: some border ray met no surface. undulation: (N + 2,) EGM2008 geoid heights above the
    ellipsoid (m) at the sensor, the centre and the footprint's points, for heights above mean
    sea level (the `*_msl` properties). ground: (rows, cols, 2) lat, lon of every ray of the
    sampling grid where it lands (or is clipped), from which the plan-view footprint is built
    (app.export.footprint)."""

    index: int
    media_s: float
    session_s: float
    utc_s: float | None
    sensor: tuple[float, float, float]
    hpr: tuple[float, float, float]
    hfov_deg: float
    vfov_deg: float
    centre: tuple[float, float, float]
    slant_m: float
    corners: np.ndarray
    footprint: np.ndarray
    clipped: bool
    undulation: np.ndarray
    ground: np.ndarray
    clip: str = ""  # the video file the frame is from (several clips in one export)
    gnss: str | None = None  # what its position stands on (app.camera.fixes); None: no GNSS

    @property
    def sensor_msl_m(self) -> float:
        """The sensor's height above mean sea level (EGM2008), m."""
        return self.sensor[2] - float(self.undulation[0])

    @property
    def centre_msl_m(self) -> float:
        """The frame centre's height above mean sea level (EGM2008), m; NaN where none."""
        return self.centre[2] - float(self.undulation[1])

    @property
    def footprint_msl(self) -> np.ndarray:
        """The footprint (N, 3) with heights above mean sea level (EGM2008)."""
        return np.column_stack([self.footprint[:, :2], self.footprint[:, 2] - self.undulation[2:]])


def border_indices(columns: int, rows: int) -> np.ndarray:
    """(N, 2) (row, column) of a grid's border, clockwise from the top-left corner, each once."""
    top = [(0, c) for c in range(columns)]
    right = [(r, columns - 1) for r in range(1, rows)]
    bottom = [(rows - 1, c) for c in range(columns - 2, -1, -1)]
    left = [(r, 0) for r in range(rows - 2, 0, -1)]
    return np.array(top + right + bottom + left)


def landing_points(
    camera: Camera, grid_points: np.ndarray, max_range_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """(points (H, W, 3) ENU, hit mask): the probe's points, with rays that met nothing (or met
    it beyond max_range_m) replaced by the point at max_range_m along the pixel's ray."""
    h, w = grid_points.shape[:2]
    v, u = np.mgrid[0:h, 0:w] + 0.5  # pixel centres of the grid camera itself
    rays = camera.pixel_rays(np.column_stack([u.ravel(), v.ravel()])).reshape(h, w, 3)
    far = np.asarray(camera.position) + rays * max_range_m
    dist = np.linalg.norm(grid_points - np.asarray(camera.position), axis=2)
    hit = np.isfinite(dist) & (dist <= max_range_m)
    return np.where(hit[..., None], grid_points, far), hit


class FootprintCaster:
    """Frame records from posed cameras: the border-sampling grid (FOOTPRINT_SAMPLES) rendered
    through the position pass of one scene."""

    def __init__(
        self, mesh, frame, intrinsics, max_range_m: float = FOOTPRINT_MAX_RANGE_M, lens=None
    ) -> None:
        self.frame, self.intrinsics, self.max_range_m = frame, intrinsics, max_range_m
        fov = (
            lens if lens is not None else intrinsics
        )  # a lens's own fields of view, not its enclosing pinhole's
        self.hfov_deg, self.vfov_deg = fov.hfov_deg, fov.vfov_deg
        self.grid = border_sampling(intrinsics, *FOOTPRINT_SAMPLES)
        self.border = border_indices(*FOOTPRINT_SAMPLES)
        g = self.grid
        self.corners = [(0, 0), (0, g.width - 1), (g.height - 1, g.width - 1), (g.height - 1, 0)]
        self.centre = ((g.height - 1) // 2, (g.width - 1) // 2)
        self.probe = SurfaceProbe(mesh)

    def grid_points(self, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(points (rows, cols, 3), hit mask) at the border-sampling grid of the real image."""
        far = max(VIEW_FAR_M, 2.0 * self.max_range_m)
        if cam.lens is None:  # a pinhole: the grid camera's own pixels are the rays, exactly
            grid = (  # a zooming camera's own field of view, the same grid of samples
                self.grid
                if cam.intrinsics == self.intrinsics
                else border_sampling(cam.intrinsics, *FOOTPRINT_SAMPLES)
            )
            small = Camera.create(grid, cam.position, cam.orientation, VIEW_NEAR_M, far)
            return landing_points(small, self.probe.points(small), self.max_range_m)
        # A real lens: rays through the image's own border (the lens's inverse), looked up in a
        # fine position map of the pinhole that encloses the image.
        g = self.grid
        v, u = np.mgrid[0 : g.height, 0 : g.width]
        uv = np.column_stack(
            [
                u.ravel() * cam.lens.width / (g.width - 1),
                v.ravel() * cam.lens.height / (g.height - 1),
            ]
        )
        rays = cam.pixel_rays(uv)
        fine = Camera.create(
            cam.intrinsics.scaled(
                LENS_PROBE_PX,
                max(2, round(LENS_PROBE_PX * cam.intrinsics.height / cam.intrinsics.width)),
            ),
            cam.position,
            cam.orientation,
            VIEW_NEAR_M,
            far,
        )
        points = self.probe.points(fine)
        px, _ = fine.project(np.asarray(cam.position) + rays)
        col = np.clip(px[:, 0].astype(int), 0, fine.intrinsics.width - 1)
        row = np.clip(px[:, 1].astype(int), 0, fine.intrinsics.height - 1)
        seen = points[row, col]
        dist = np.linalg.norm(seen - np.asarray(cam.position), axis=1)
        hit = np.isfinite(dist) & (dist <= self.max_range_m)
        out = np.where(hit[:, None], seen, np.asarray(cam.position) + rays * self.max_range_m)
        return out.reshape(g.height, g.width, 3), hit.reshape(g.height, g.width)

    def record(
        self,
        cam: Camera,
        index: int = 0,
        media_s: float = 0.0,
        session_s: float = 0.0,
        utc_s: float | None = None,
        clip: str = "",
    ) -> FrameRecord:
        pts, hit = self.grid_points(cam)
        cr, cc = self.centre
        b = self.border
        gh, gw = pts.shape[:2]
        geo = self.frame.enu_to_geodetic(np.vstack([[cam.position], pts.reshape(-1, 3)]))
        grid = geo[1:].reshape(gh, gw, 3)
        corners = np.array([grid[r, c] for r, c in self.corners])
        border = grid[b[:, 0], b[:, 1]]
        n = undulation(
            np.concatenate([geo[:1, 0], grid[cr, cc, :1], border[:, 0]]),
            np.concatenate([geo[:1, 1], grid[cr, cc, 1:2], border[:, 1]]),
        )
        centre_hit = bool(hit[cr, cc])
        own = cam.lens is None and cam.intrinsics != self.intrinsics  # a zoom's frame
        hfov, vfov = (
            (cam.intrinsics.hfov_deg, cam.intrinsics.vfov_deg)
            if own
            else (self.hfov_deg, self.vfov_deg)
        )
        return FrameRecord(
            index=index, media_s=media_s, session_s=session_s, utc_s=utc_s,
            sensor=tuple(map(float, geo[0])), hpr=tuple(map(float, rotations.hpr_from_camera_quat(cam.orientation))),
            hfov_deg=hfov, vfov_deg=vfov,
            centre=tuple(map(float, grid[cr, cc])) if centre_hit else (np.nan, np.nan, np.nan),
            slant_m=float(np.linalg.norm(pts[cr, cc] - np.asarray(cam.position))) if centre_hit else np.nan,
            corners=corners, footprint=border, clipped=not bool(hit[b[:, 0], b[:, 1]].all()),
            undulation=n, ground=grid[..., :2].copy(), clip=clip,
        )  # fmt: skip

    def release(self) -> None:
        self.probe.release()


def frame_records(
    session: Session,
    source: str,
    every: int = 1,
    max_range_m: float = FOOTPRINT_MAX_RANGE_M,
    progress: Callable[[float], None] | None = None,
    track: CameraTrack | None = None,
) -> Iterator[FrameRecord]:
    """A record for every `every`-th video frame under one source (see the module docstring)."""
    track = track or solve_track(session, source)
    caster = FootprintCaster(
        session.scene(), session.frame, session.intrinsics, max_range_m, session.lens
    )
    frames = range(0, track.frame_count, max(1, every))
    clip = Path(session.video.path).name
    try:
        for n, k in enumerate(frames):
            media = float(track.clock.media_s[k])
            t = float(track.clock.session_time(media))
            record = caster.record(track.frame_camera(k), k, media, t, session.utc_of(t), clip)
            if track.fixes is not None:  # used, rejected or missing (issue 52)
                record = replace(record, gnss=str(track.fixes.at([t])[0]))
            yield record
            if progress is not None:
                progress((n + 1) / len(frames))
    finally:
        caster.release()
