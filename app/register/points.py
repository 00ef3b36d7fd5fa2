"""Control points by hand: pairs of a video pixel and the model point it shows (as in
photogrammetry tools), on one frame or several, solve the clip's boresight (the constant rotation
between the solved camera and the real one) and a constant position correction.

Model: the camera of frame k under the prior source is at C_k (ENU m) with camera -> ENU
rotation R_k; the corrected camera is at C_k + dp with rotation R_k B (B camera-side). A point X
(ENU m) is then seen at the pixel the clip's camera (lens included) projects X to from that
pose; (dp, B) minimise the pixel residuals (robust soft-L1 loss, scipy least_squares).

Points file (CSV with a header): frame (video frame index), x, y (pixels of the displayed frame,
from its top-left corner), latitude, longitude (degrees, WGS84), height (metres above the
ellipsoid).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from app.camera.trajectory import PositionTrack
from app.core.errors import DataFormatError, GeofuseError
from app.geodesy import rotations
from app.session.camera_track import CameraTrack

FloatArray = npt.NDArray[np.float64]
COLUMNS = ("frame", "x", "y", "latitude", "longitude", "height")
MIN_PAIRS = 4


@dataclass(frozen=True)
class ControlPoints:
    """frame (N,) video frame indices; pixel (N, 2) u, v of the displayed frame; geodetic (N, 3)
    latitude, longitude (deg), ellipsoidal height (m)."""

    frame: npt.NDArray[np.int64]
    pixel: FloatArray
    geodetic: FloatArray

    def __len__(self) -> int:
        return len(self.frame)


def control_path(source: Path) -> Path:
    """The control points kept beside a manifest or clip (never an input): `NAME.control.csv`."""
    return source.with_name(source.stem + ".control.csv")


def read_points(path: str | Path) -> ControlPoints:
    """A points file (see the module docstring); DataFormatError naming the line and field."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "control points file does not exist")
    rows = []
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise DataFormatError(
                path,
                f"missing columns {', '.join(missing)} (expected a header {','.join(COLUMNS)})",
                line=1,
            )
        for line, row in enumerate(reader, start=2):
            values = []
            for c in COLUMNS:
                try:
                    v = float(row[c])
                except (TypeError, ValueError):
                    raise DataFormatError(
                        path, f"{row[c]!r} is not a number", line=line, field=c
                    ) from None
                if not np.isfinite(v):
                    raise DataFormatError(
                        path, f"{row[c]!r} is not a finite number", line=line, field=c
                    )
                values.append(v)
            if values[0] < 0 or values[0] != int(values[0]):
                raise DataFormatError(
                    path,
                    f"{row['frame']!r} is not a frame index (a whole number from 0)",
                    line=line,
                    field="frame",
                )
            if not -90 <= values[3] <= 90 or not -180 <= values[4] <= 180:
                raise DataFormatError(
                    path,
                    "latitude must lie in [-90, 90] and longitude in [-180, 180] degrees",
                    line=line,
                )
            rows.append(values)
    if len(rows) < MIN_PAIRS:
        raise DataFormatError(path, f"{len(rows)} control points; need at least {MIN_PAIRS} pairs")
    a = np.array(rows)
    return ControlPoints(a[:, 0].astype(np.int64), a[:, 1:3], a[:, 3:6])


def write_points(path: str | Path, points: ControlPoints) -> Path:
    """Write control points as read_points reads them (the viewer keeps clicked pairs so)."""
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for k, (u, v), (lat, lon, h) in zip(
            points.frame, points.pixel, points.geodetic, strict=True
        ):
            w.writerow([int(k), f"{u:.2f}", f"{v:.2f}", f"{lat:.9f}", f"{lon:.9f}", f"{h:.3f}"])
    return path


@dataclass(frozen=True)
class ControlSolution:
    """boresight: camera-side quaternion B (corrected camera -> ENU = R_k B); offset_m (3,) ENU
    position correction; residual_px (N,) and residual_m (N,) per pair after the fit (metres:
    the point's distance from the corrected ray through its pixel); before_px (N,) before it."""

    boresight: FloatArray
    offset_m: FloatArray
    residual_px: FloatArray
    residual_m: FloatArray
    before_px: FloatArray

    @property
    def boresight_deg(self) -> float:
        return float(
            np.degrees(rotations.angle_between(self.boresight, np.array([1.0, 0.0, 0.0, 0.0])))
        )

    def report(self) -> str:
        """Lines for people: the solution and each pair's residual."""
        hpr = rotations.to_scipy(self.boresight).as_euler("ZXY", degrees=True)
        lines = [
            f"boresight {self.boresight_deg:.3f} deg (about the camera's z, x, y axes: {hpr[0]:+.3f}, {hpr[1]:+.3f}, {hpr[2]:+.3f} deg)",
            f"position correction E {self.offset_m[0]:+.2f} m, N {self.offset_m[1]:+.2f} m, U {self.offset_m[2]:+.2f} m",
            f"residuals: median {np.median(self.residual_px):.2f} px / {np.median(self.residual_m):.2f} m (before: median {np.median(self.before_px):.1f} px)",
        ]
        lines += [
            f"  pair {i + 1}: {p:.2f} px, {m:.2f} m"
            for i, (p, m) in enumerate(zip(self.residual_px, self.residual_m, strict=True))
        ]
        return "\n".join(lines)


def _cameras(track: CameraTrack, frames: npt.NDArray[np.int64]):
    bad = frames[(frames < 0) | (frames >= track.frame_count)]
    if len(bad):
        raise GeofuseError(
            f"control point frame {int(bad[0])} is outside the video (0..{track.frame_count - 1})"
        )
    return [track.frame_camera(int(k)) for k in frames]


def solve_control(track: CameraTrack, points: ControlPoints) -> ControlSolution:
    """The boresight and position correction that best explain the pairs under `track`."""
    if len(points) < MIN_PAIRS:
        raise GeofuseError(f"{len(points)} control points; need at least {MIN_PAIRS} pairs")
    cams = _cameras(track, points.frame)
    x = track.poses.frame.geodetic_to_enu(
        points.geodetic[:, 0], points.geodetic[:, 1], points.geodetic[:, 2]
    )

    def moved(params: FloatArray, i: int):
        b = rotations.from_rotvec(params[:3])
        c = cams[i]
        return replace(
            c,
            position=tuple(np.asarray(c.position) + params[3:]),
            orientation=tuple(rotations.multiply(np.asarray(c.orientation), b)),
        )

    def residuals(params: FloatArray) -> FloatArray:
        out = []
        for i in range(len(points)):
            uv, depth = moved(params, i).project(x[i : i + 1])
            d = uv[0] - points.pixel[i] if depth[0] > 0 else np.array([1e4, 1e4])
            out.append(d)
        return np.concatenate(out)

    before = np.linalg.norm(residuals(np.zeros(6)).reshape(-1, 2), axis=1)
    fit = least_squares(
        residuals,
        np.zeros(6),
        loss="soft_l1",
        f_scale=2.0,
        x_scale=np.array([0.01] * 3 + [1.0] * 3),
    )
    res_px = np.linalg.norm(fit.fun.reshape(-1, 2), axis=1)
    res_m = np.empty(len(points))
    for i in range(len(points)):
        cam = moved(fit.x, i)
        ray = cam.pixel_rays(points.pixel[i : i + 1])[0]
        v = x[i] - np.asarray(cam.position)
        res_m[i] = float(np.linalg.norm(v - ray * (v @ ray)))
    return ControlSolution(
        rotations.from_rotvec(fit.x[:3]), fit.x[3:].copy(), res_px, res_m, before
    )


def corrected_track(track: CameraTrack, solution: ControlSolution) -> CameraTrack:
    """The track with the boresight turned into its camera mount and its positions moved."""
    p = track.poses
    enu = (
        p.frame.geodetic_to_enu(p.positions.lat, p.positions.lon, p.positions.h) + solution.offset_m
    )
    geo = p.frame.enu_to_geodetic(enu)
    positions = PositionTrack.from_fixes(
        p.positions.t, geo[:, 0], geo[:, 1], geo[:, 2], p.positions.vel_enu
    )
    mount = rotations.canonical(rotations.multiply(p.q_dev_to_cam, solution.boresight))
    return replace(track, poses=replace(p, positions=positions, q_dev_to_cam=mount))
