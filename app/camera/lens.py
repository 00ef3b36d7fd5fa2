"""Real lenses: the Kannala-Brandt fisheye model (OpenCV `fisheye`, 4 coefficients), the
Brown-Conrady model (OpenCV standard: k1, k2, p1, p2, k3), and a horizontal stretch for digital
lens modes, read from lens profiles in the open gyroflow format.

Forward (camera ray -> distorted pixel) is what the projection shader does per fragment
(shaders/include/lens.glsl mirrors `distort`); the inverse (`undistort`, Newton iterations) serves
the CPU: pixel rays for frustum lines, picking and footprints.

Coordinates: normalised image coordinates (a, b) = (x / z, y / z) in OpenCV's camera frame (x
right, y down, z forward), i.e. a = x_gl / -z_gl, b = -y_gl / -z_gl for our OpenGL camera frame;
pixels (u, v) from the top-left corner, centres at half-integers, as app.camera.pinhole. A profile's
`input_horizontal_stretch` s means the video is the calibrated image stretched horizontally by s
about its centre (GoPro SuperView/HyperView): u_video = cx + s (u_model - cx).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.camera.intrinsics import Intrinsics
from app.core.errors import DataFormatError

FloatArray = npt.NDArray[np.float64]
KINDS = ("fisheye", "brown")
NEWTON_STEPS = 20


@dataclass(frozen=True)
class Lens:
    """A calibrated lens: its camera matrix at an image size (`k`, app.camera.intrinsics.Intrinsics: pixels),
    coefficients (fisheye: k1..k4; brown: k1, k2, p1, p2, k3), the horizontal stretch of the
    video, the sensor's readout time (s, None when unknown), and the profile's name."""

    kind: str
    k: Intrinsics
    coeffs: tuple[float, ...]
    stretch: float = 1.0
    readout_s: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"lens kind must be one of {KINDS}, got {self.kind!r}")
        wanted = 4 if self.kind == "fisheye" else 5
        if len(self.coeffs) != wanted or not all(np.isfinite(self.coeffs)):
            raise ValueError(
                f"a {self.kind} lens needs {wanted} finite coefficients, got {self.coeffs}"
            )
        if not self.stretch > 0:
            raise ValueError(f"the stretch must be positive, got {self.stretch}")

    @classmethod
    def create(
        cls,
        kind: str,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        coeffs,
        **rest,
    ) -> Lens:
        return cls(
            kind,
            Intrinsics(int(width), int(height), float(fx), float(fy), float(cx), float(cy)),
            tuple(float(c) for c in coeffs),
            **rest,
        )

    width = property(lambda self: self.k.width)
    height = property(lambda self: self.k.height)
    fx = property(lambda self: self.k.fx)
    fy = property(lambda self: self.k.fy)
    cx = property(lambda self: self.k.cx)
    cy = property(lambda self: self.k.cy)

    def scaled(self, width: int, height: int) -> Lens:
        """The same lens at another resolution of the same field of view."""
        return replace(self, k=self.k.scaled(width, height))

    def rotated(self, quarter_turns_cw: int) -> Lens:
        """The lens of the image turned clockwise by 90 deg steps (a video stored landscape and
        shown portrait): only the symmetric models turn exactly; the stretch must be 1."""
        q = quarter_turns_cw % 4
        if q == 0:
            return self
        if self.stretch != 1.0 or (self.kind == "brown" and any(self.coeffs[2:4])):
            raise ValueError("a stretched or decentred lens cannot be turned")
        k = self.k
        if q == 2:
            return replace(self, k=replace(k, cx=k.width - k.cx, cy=k.height - k.cy))
        cx, cy = (k.height - k.cy, k.cx) if q == 1 else (k.cy, k.width - k.cx)
        return replace(self, k=Intrinsics(k.height, k.width, k.fy, k.fx, cx, cy))

    # --- the model ------------------------------------------------------------------------------

    def _radial(self, a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self.kind == "fisheye":
            k1, k2, k3, k4 = self.coeffs
            r = np.hypot(a, b)
            theta = np.arctan(r)
            t2 = theta * theta
            theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
            return a * scale, b * scale
        k1, k2, p1, p2, k3 = self.coeffs
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        return a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a), b * radial + p1 * (
            r2 + 2 * b * b
        ) + 2 * p2 * a * b

    def distort(self, ab: npt.ArrayLike) -> FloatArray:
        """Normalised coordinates (N, 2) -> video pixels (N, 2) (u right, v down)."""
        ab = np.atleast_2d(np.asarray(ab, np.float64))
        x, y = self._radial(ab[:, 0], ab[:, 1])
        u = self.fx * x + self.cx
        return np.column_stack([self.cx + self.stretch * (u - self.cx), self.fy * y + self.cy])

    def undistort(self, uv: npt.ArrayLike) -> FloatArray:
        """Video pixels (N, 2) -> normalised coordinates (N, 2): Newton iterations on `distort`
        with a numerical Jacobian, from the pinhole guess."""
        uv = np.atleast_2d(np.asarray(uv, np.float64))
        target = uv.copy()
        ab = np.column_stack(
            [
                (self.cx + (uv[:, 0] - self.cx) / self.stretch - self.cx) / self.fx,
                (uv[:, 1] - self.cy) / self.fy,
            ]
        )
        h = 1e-7
        for _ in range(NEWTON_STEPS):
            f = self.distort(ab) - target
            ja = (self.distort(ab + [h, 0.0]) - self.distort(ab)) / h
            jb = (self.distort(ab + [0.0, h]) - self.distort(ab)) / h
            det = ja[:, 0] * jb[:, 1] - jb[:, 0] * ja[:, 1]
            det = np.where(np.abs(det) < 1e-18, 1e-18, det)
            da = (jb[:, 1] * f[:, 0] - jb[:, 0] * f[:, 1]) / det
            db = (-ja[:, 1] * f[:, 0] + ja[:, 0] * f[:, 1]) / det
            ab = ab - np.column_stack([da, db])
            if np.max(np.abs(f)) < 1e-9:
                break
        return ab

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view across the image's middle row, degrees."""
        a = self.undistort([[0.0, self.cy], [float(self.width), self.cy]])[:, 0]
        return float(np.degrees(np.arctan(-a[0]) + np.arctan(a[1])))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view down the image's middle column, degrees."""
        b = self.undistort([[self.cx, 0.0], [self.cx, float(self.height)]])[:, 1]
        return float(np.degrees(np.arctan(-b[0]) + np.arctan(b[1])))

    def border_extent(self, samples: int = 64) -> tuple[float, float, float, float]:
        """(a_min, a_max, b_min, b_max): the normalised extent of the whole image's border."""
        t = np.linspace(0.0, 1.0, samples)
        w, h = self.width, self.height
        border = np.vstack([np.column_stack([t * w, np.zeros(samples)]), np.column_stack([t * w, np.full(samples, h)]),
                            np.column_stack([np.zeros(samples), t * h]), np.column_stack([np.full(samples, w), t * h])])  # fmt: skip
        ab = self.undistort(border)
        return (
            float(ab[:, 0].min()),
            float(ab[:, 0].max()),
            float(ab[:, 1].min()),
            float(ab[:, 1].max()),
        )


def enclosing_intrinsics(lens: Lens, margin: float = 1.02) -> Intrinsics:
    """The pinhole whose image encloses the lens's whole (undistorted) image, at the lens's
    resolution: what the depth pass renders (its frustum sees everything the video covers)."""
    a0, a1, b0, b1 = lens.border_extent()
    ax, bx = max(-a0, a1) * margin, max(-b0, b1) * margin
    fx, fy = lens.width / (2 * ax), lens.height / (2 * bx)
    return Intrinsics(lens.width, lens.height, fx, fy, lens.width / 2, lens.height / 2)


def read_profile(path: str | Path) -> Lens:
    """A gyroflow lens profile (JSON): `calib_dimension`, `fisheye_params.camera_matrix` and
    `distortion_coeffs` (with `use_opencv_fisheye`), or `calib_params` (`use_opencv_standard`),
    `input_horizontal_stretch`, `frame_readout_time` (ms). Errors name the file and field."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "lens profile does not exist")
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(path, f"not a JSON lens profile ({exc})") from exc
    try:
        dim = d["calib_dimension"]
        fisheye = bool(d.get("use_opencv_fisheye", True)) or not d.get("use_opencv_standard")
        params = d["fisheye_params"] if fisheye else d["calib_params"]
        m = params["camera_matrix"]
        coeffs = tuple(float(c) for c in params["distortion_coeffs"])
        if not fisheye and len(coeffs) > 5:
            coeffs = coeffs[:5]
        readout = d.get("frame_readout_time")
        return Lens.create(
            "fisheye" if fisheye else "brown", dim["w"], dim["h"], m[0][0], m[1][1], m[0][2], m[1][2], coeffs,
            stretch=float(d.get("input_horizontal_stretch") or 1.0), readout_s=float(readout) / 1000.0 if readout else None, name=str(d.get("name", path.stem)),
        )  # fmt: skip
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise DataFormatError(
            path, f"not a usable lens profile ({type(exc).__name__}: {exc})", field="fisheye_params"
        ) from exc
