"""Control points by hand: pairs of a video pixel and the model point it shows (as in
photogrammetry tools), on one frame or several, solve the clip's boresight (the constant rotation
between the solved camera and the real one) and a constant position correction.

Model: the camera of frame k under the prior source is at C_k (ENU m) with camera -> ENU
rotation R_k; the corrected camera is at C_k + dp with rotation R_k B (B camera-side). A point X
(ENU m) is then seen at the pixel the clip's camera (lens included) projects X to from that
pose; (dp, B) minimise the pixel residuals (robust soft-L1 loss, scipy least_squares).

Points file (UTF-8 CSV with a header): frame (video frame index), x, y (pixels of the displayed
frame, from its top-left corner), latitude, longitude (degrees, WGS84), height (metres above the
ellipsoid, within HEIGHT_RANGE_M). A pair repeated is dropped (said); fewer than MIN_PAIRS
distinct pairs, a pixel outside the video's image or model points that all lie behind their
frame's camera are refused, naming the file and line.
"""

from __future__ import annotations

import codecs
import csv
import io
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from app.camera.pinhole import Camera, image_size
from app.camera.trajectory import PositionTrack
from app.core.errors import DataFormatError, GeofuseError
from app.geodesy import rotations
from app.session.camera_track import CameraTrack

FloatArray = npt.NDArray[np.float64]
COLUMNS = ("frame", "x", "y", "latitude", "longitude", "height")
MIN_PAIRS = 4
# Ellipsoidal heights a point on a model may have (m): below the Dead Sea shore with the geoid's
# lowest undulation, above Everest with margin; 1e30 m is a typing error, not a place.
HEIGHT_RANGE_M = (-1000.0, 10000.0)
MAX_FRAME = 2**31 - 1  # a frame index above this is no video's (it would overflow int32 indices)
PIXEL_MARGIN_PX = 1.0  # how far outside the image (px) a pixel may lie, for rounding at its edge


@dataclass(frozen=True)
class ControlPoints:
    """frame (N,) video frame indices; pixel (N, 2) u, v of the displayed frame; geodetic (N, 3)
    latitude, longitude (deg), ellipsoidal height (m)."""

    frame: npt.NDArray[np.int64]
    pixel: FloatArray
    geodetic: FloatArray
    path: Path | None = None  # the file read (None: picked in the viewer)
    lines: tuple[int, ...] = ()  # each pair's line in that file
    notes: tuple[str, ...] = ()  # what reading them said (pairs repeated and dropped)

    def __len__(self) -> int:
        return len(self.frame)

    def where(self, i: int) -> str:
        """Pair i (from 0) for people: its line in the file, else its number from 1."""
        return f"line {self.lines[i]}" if self.lines else f"pair {i + 1}"

    def refuse(self, i: int, message: str, field: str | None = None) -> GeofuseError:
        """The error refusing pair i: DataFormatError naming the file, line and field when the
        pairs were read from one, else naming the pair."""
        if self.path is not None and self.lines:
            return DataFormatError(self.path, message, line=self.lines[i], field=field)
        return GeofuseError(f"control {self.where(i)}: {message}")

    def refuse_all(self, message: str) -> GeofuseError:
        """The error refusing the pairs as a whole (naming the file where they were read)."""
        if self.path is not None:
            return DataFormatError(self.path, message)
        return GeofuseError(f"control points: {message}")

    def subset(self, keep: npt.NDArray[np.int64], note: str | None = None) -> ControlPoints:
        """The pairs at indices `keep`, with `note` added to their notes."""
        return replace(
            self,
            frame=self.frame[keep],
            pixel=self.pixel[keep],
            geodetic=self.geodetic[keep],
            lines=tuple(self.lines[i] for i in keep) if self.lines else (),
            notes=self.notes + ((note,) if note else ()),
        )

    def distinct(self) -> ControlPoints:
        """The pairs without repeats (the same frame, pixel and model point again: one pair
        weighed several times), the first of each kept and the others said in the notes."""
        rows = np.column_stack([self.frame, self.pixel, self.geodetic])
        _, first = np.unique(rows, axis=0, return_index=True)
        keep = np.sort(first)
        if len(keep) == len(self):
            return self
        dropped = sorted(set(range(len(self))) - set(keep.tolist()))
        where = ", ".join(self.where(i) for i in dropped)
        source = f"{self.path}: " if self.path is not None else "control points: "
        return self.subset(
            keep,
            f"{source}{len(dropped)} pairs repeat an earlier one ({where}): dropped, "
            f"{len(keep)} distinct pairs left",
        )


def control_path(source: Path) -> Path:
    """The control points kept beside a manifest or clip (never an input): `NAME.control.csv`."""
    return source.with_name(source.stem + ".control.csv")


def _text(path: Path) -> str:
    """The file's text (UTF-8, a byte-order mark allowed); DataFormatError naming the line of
    the first byte that is not UTF-8, or an empty file."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(path, f"cannot read the control points ({exc.strerror})") from exc
    bom = len(codecs.BOM_UTF8) if raw.startswith(codecs.BOM_UTF8) else 0
    try:
        text = raw[bom:].decode("utf-8")
    except UnicodeDecodeError as exc:
        at = bom + exc.start  # the byte's offset in the file
        raise DataFormatError(
            path,
            f"byte 0x{raw[at]:02x} at offset {at} is not UTF-8 (expected a UTF-8 text CSV)",
            line=raw[:at].count(b"\n") + 1,
        ) from None
    if not text.strip():
        raise DataFormatError(
            path, f"the file is empty (expected a header {','.join(COLUMNS)} and pairs)", line=1
        )
    return text


def _row(path: Path, line: int, row: dict) -> list[float]:
    """One pair's numbers in COLUMNS order, each checked (see the module docstring)."""
    values = []
    for c in COLUMNS:
        text = row[c]
        if text is None:
            raise DataFormatError(
                path,
                f"missing (expected {len(COLUMNS)} fields as the header names)",
                line=line,
                field=c,
            )
        try:
            v = float(text)
        except ValueError:
            raise DataFormatError(path, f"{text!r} is not a number", line=line, field=c) from None
        if not np.isfinite(v):
            raise DataFormatError(path, f"{text!r} is not a finite number", line=line, field=c)
        values.append(v)
    frame, _, _, lat, lon, h = values
    if not 0 <= frame <= MAX_FRAME or frame != int(frame):
        raise DataFormatError(
            path,
            f"{row['frame']!r} is not a frame index (a whole number from 0 to {MAX_FRAME})",
            line=line,
            field="frame",
        )
    if not -90 <= lat <= 90 or not -180 <= lon <= 180:
        raise DataFormatError(
            path,
            "latitude must lie in [-90, 90] and longitude in [-180, 180] degrees",
            line=line,
            field="latitude" if not -90 <= lat <= 90 else "longitude",
        )
    low, high = HEIGHT_RANGE_M
    if not low <= h <= high:
        raise DataFormatError(
            path,
            f"{row['height']!r} m is no height of a point on Earth (expected metres above the "
            f"ellipsoid, {low:g} to {high:g})",
            line=line,
            field="height",
        )
    return values


def read_points(path: str | Path) -> ControlPoints:
    """A points file (see the module docstring), repeated pairs dropped (said in `notes`);
    DataFormatError naming the line and field."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "control points file does not exist")
    reader = csv.DictReader(io.StringIO(_text(path), newline=""))
    rows, lines = [], []
    try:
        missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise DataFormatError(
                path,
                f"missing columns {', '.join(missing)} (expected a header {','.join(COLUMNS)})",
                line=1,
            )
        for row in reader:
            rows.append(_row(path, reader.line_num, row))
            lines.append(reader.line_num)
    except csv.Error as exc:
        # the record being read when it failed: the line after the last one read whole
        raise DataFormatError(path, f"not CSV: {exc}", line=reader.line_num + 1) from None
    if not rows:
        raise DataFormatError(path, f"0 control points; need at least {MIN_PAIRS} pairs")
    a = np.array(rows)
    points = ControlPoints(
        a[:, 0].astype(np.int64), a[:, 1:3], a[:, 3:6], path, tuple(lines)
    ).distinct()
    _check_count(points, len(rows))
    return points


def _check_count(points: ControlPoints, given: int) -> None:
    """Refuses fewer than MIN_PAIRS distinct pairs (of `given` before repeats were dropped)."""
    if len(points) < MIN_PAIRS:
        repeats = f" ({given - len(points)} repeated pairs dropped)" if given > len(points) else ""
        raise points.refuse_all(
            f"{len(points)} distinct control points{repeats}; need at least {MIN_PAIRS} pairs"
        )


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
    notes: tuple[str, ...] = ()  # warnings for people: pairs dropped, points behind the camera

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


def _cameras(track: CameraTrack, points: ControlPoints) -> list[Camera]:
    """Each pair's frame camera under `track`; refuses a frame outside the video or a pixel
    outside its image (more than PIXEL_MARGIN_PX), naming the pair."""
    cams = []
    for i, k in enumerate(points.frame):
        if not 0 <= k < track.frame_count:
            raise points.refuse(
                i,
                f"frame {int(k)} is outside the video (expected 0..{track.frame_count - 1})",
                "frame",
            )
        cam = track.frame_camera(int(k))
        w, h = image_size(cam)
        for axis, size in (("x", w), ("y", h)):
            value = points.pixel[i, "xy".index(axis)]
            if not -PIXEL_MARGIN_PX <= value <= size + PIXEL_MARGIN_PX:
                raise points.refuse(
                    i,
                    f"pixel {axis} = {value:g} lies outside the video's {w} x {h} image "
                    f"(expected 0 to {size} px from its top-left corner)",
                    axis,
                )
        cams.append(cam)
    return cams


def _in_front(points: ControlPoints, cams: list[Camera], x: FloatArray) -> list[str]:
    """Refuses pairs whose model points all lie behind their frame's camera; the warnings
    naming those that do where some others do not."""
    depth = np.array([cam.project(x[i : i + 1])[1][0] for i, cam in enumerate(cams)])
    behind = np.flatnonzero(~(depth > 0))
    if len(behind) == len(points):
        raise points.refuse_all(
            f"all {len(points)} model points lie behind the camera of their frame (expected "
            "points the video sees: are latitude and longitude swapped, or the heights wrong?)"
        )
    if not len(behind):
        return []
    source = f"{points.path}: " if points.path is not None else "control points: "
    where = ", ".join(points.where(int(i)) for i in behind)
    return [
        f"{source}the model point of {where} lies behind the camera of its frame: that pair "
        "cannot be fitted (check its latitude, longitude and height)"
    ]


def solve_control(track: CameraTrack, points: ControlPoints) -> ControlSolution:
    """The boresight and position correction that best explain the pairs under `track`.
    Repeated pairs are dropped and points behind the camera said (the solution's notes);
    GeofuseError (DataFormatError naming the line for pairs read from a file) for fewer than
    MIN_PAIRS distinct pairs, a frame outside the video, a pixel outside its image, or model
    points that all lie behind the camera."""
    given = len(points)
    points = points.distinct()
    _check_count(points, given)
    cams = _cameras(track, points)
    x = track.poses.frame.geodetic_to_enu(
        points.geodetic[:, 0], points.geodetic[:, 1], points.geodetic[:, 2]
    )
    notes = points.notes + tuple(_in_front(points, cams, x))

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
        rotations.from_rotvec(fit.x[:3]), fit.x[3:].copy(), res_px, res_m, before, notes
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
