"""Pinhole intrinsics: an image's size and its camera matrix (pixels), and OpenGL's projection
matrix from them.

Image pixels: u to the right from the left edge, v down from the top edge, pixel centres at
half-integers. Camera frame: OpenGL's (x right, y up, looking down -z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.core.constants import DEFAULT_FAR_M, DEFAULT_NEAR_M, FOV_RANGE_DEG

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image width x height pixels; fx, fy, cx, cy in pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fov(
        cls, width: int, height: int, fov_deg: float, axis: str = "horizontal"
    ) -> Intrinsics:
        """Square pixels, principal point at the image centre, FOV (deg) across the given axis."""
        lo, hi = FOV_RANGE_DEG
        if not lo <= fov_deg <= hi:
            raise ValueError(f"field of view must be in [{lo:g}, {hi:g}] degrees, got {fov_deg}")
        span = width if axis == "horizontal" else height
        if axis not in ("horizontal", "vertical"):
            raise ValueError(f"axis must be 'horizontal' or 'vertical', got {axis!r}")
        f = 0.5 * span / np.tan(np.radians(fov_deg) / 2.0)
        return cls(width, height, float(f), float(f), width / 2.0, height / 2.0)

    @classmethod
    def from_focal_length(
        cls,
        width: int,
        height: int,
        focal_mm: float,
        sensor_width_mm: float,
        sensor_height_mm: float | None = None,
    ) -> Intrinsics:
        """From a focal length and the sensor size (mm) that the full image covers."""
        fx = focal_mm / sensor_width_mm * width
        fy = fx if sensor_height_mm is None else focal_mm / sensor_height_mm * height
        return cls(width, height, float(fx), float(fy), width / 2.0, height / 2.0)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view, degrees."""
        return float(np.degrees(2.0 * np.arctan(self.width / (2.0 * self.fx))))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view, degrees."""
        return float(np.degrees(2.0 * np.arctan(self.height / (2.0 * self.fy))))

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera sampled at another resolution (same field of view)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)


@dataclass(frozen=True)
class Zoom:
    """A field of view that changes over time (a zoom lens, as FMV metadata reports it): the
    horizontal field of view hfov_deg (N,) degrees at times t (N,) session seconds, increasing;
    linear between them, held before the first and after the last."""

    t: FloatArray
    hfov_deg: FloatArray

    def hfov_at(self, t: float) -> float:
        """Degrees at session time t."""
        return float(np.interp(t, self.t, self.hfov_deg))

    def intrinsics_at(self, base: Intrinsics, t: float) -> Intrinsics:
        """`base`'s image with the field of view at session time t (square pixels, centred)."""
        return Intrinsics.from_fov(base.width, base.height, self.hfov_at(t))


def projection_matrix(
    intr: Intrinsics, near: float = DEFAULT_NEAR_M, far: float = DEFAULT_FAR_M
) -> FloatArray:
    """OpenGL clip-from-camera 4x4 matrix (column vectors) for the pinhole intrinsics.

    A camera point (x, y, z), z < 0, lands at pixel u = fx x/(-z) + cx, v = cy - fy y/(-z);
    NDC depth is -1 at `near` and +1 at `far` (metres).
    """
    if not 0.0 < near < far:
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    w, h = intr.width, intr.height
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * intr.fx / w
    p[1, 1] = 2.0 * intr.fy / h
    p[0, 2] = 1.0 - 2.0 * intr.cx / w
    p[1, 2] = 2.0 * intr.cy / h - 1.0
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return p
