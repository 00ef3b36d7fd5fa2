"""Pinhole cameras in numpy: intrinsics, pose, view and projection matrices.

Image pixels: u to the right from the left edge, v down from the top edge, pixel centres at
half-integers. Camera frame: OpenGL's (x right, y up, looking down -z). World: local ENU metres.
The window camera and the projector (the video's camera) both use this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from app.camera.intrinsics import Intrinsics, projection_matrix
from app.camera.lens import Lens
from app.core.constants import DEFAULT_FAR_M, DEFAULT_NEAR_M, EPS_DEGENERATE
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame

FloatArray = npt.NDArray[np.float64]


def _frozen(a: FloatArray) -> FloatArray:
    a.flags.writeable = False
    return a


def view_matrix(position_enu: npt.ArrayLike, q_cam_to_world: npt.ArrayLike) -> FloatArray:
    """Camera-from-world 4x4 matrix for a camera at position (ENU m) with orientation q ([w,x,y,z])."""
    r = rotations.to_matrix(q_cam_to_world)
    t = np.asarray(position_enu, np.float64)
    v = np.eye(4)
    v[:3, :3] = r.T
    v[:3, 3] = -r.T @ t
    return v


def look_at_quat(
    eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike = (0.0, 0.0, 1.0)
) -> FloatArray:
    """Camera -> ENU quaternion for a camera at eye looking at target with the given world up."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    f = target - eye
    if np.linalg.norm(f) < EPS_DEGENERATE:
        raise ValueError("look-at target coincides with the eye")
    f /= np.linalg.norm(f)
    x = np.cross(f, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight up or down: pick north as up
        x = np.cross(f, np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return rotations.from_matrix(np.stack([x, y, -f], axis=1))


@dataclass(frozen=True)
class Camera:
    """A posed camera: intrinsics, near/far planes (m), ENU position (m), orientation q, and an
    optional real lens (app.camera.lens.Lens). With a lens, `intrinsics` is the pinhole that encloses
    the lens's whole image (the depth pass's frustum) and `project`/`pixel_rays` go through the
    lens model."""

    intrinsics: Intrinsics
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    near: float = DEFAULT_NEAR_M
    far: float = DEFAULT_FAR_M
    lens: Lens | None = None
    rs_turn: tuple[float, float, float] | None = (
        None  # rolling shutter: the camera's turn (rad, camera frame) from first to last row
    )
    rs_axis: tuple[float, float, float] = (
        0.0,
        1.0,
        0.0,
    )  # the sensor row's read fraction = a u/W + b v/H + c of the displayed pixel

    @classmethod
    def create(
        cls,
        intrinsics: Intrinsics,
        position: npt.ArrayLike,
        orientation: npt.ArrayLike,
        near: float = DEFAULT_NEAR_M,
        far: float = DEFAULT_FAR_M,
        lens: Lens | None = None,
        rs_turn: npt.ArrayLike | None = None,
        rs_axis: tuple[float, float, float] = (0.0, 1.0, 0.0),
    ) -> Camera:
        p = np.asarray(position, np.float64).reshape(3)
        q = rotations.canonical(np.asarray(orientation, np.float64).reshape(4))
        turn = (
            None
            if rs_turn is None
            else tuple(float(v) for v in np.asarray(rs_turn, np.float64).reshape(3))
        )
        return cls(
            intrinsics,
            tuple(map(float, p)),
            tuple(map(float, q)),
            near,
            far,
            lens,
            turn,
            tuple(map(float, rs_axis)),
        )

    # The matrices are worked out once a camera (frozen: they never change) and kept read-only;
    # a frame asks each projector's dozens of times (depth pass, reach, uniforms).
    @cached_property
    def view(self) -> FloatArray:
        """Camera-from-world 4x4 (read-only)."""
        return _frozen(view_matrix(self.position, self.orientation))

    @cached_property
    def projection(self) -> FloatArray:
        """Clip-from-camera 4x4 (read-only)."""
        return _frozen(projection_matrix(self.intrinsics, self.near, self.far))

    @cached_property
    def view_projection(self) -> FloatArray:
        """Clip-from-world 4x4 (read-only)."""
        return _frozen(self.projection @ self.view)

    def pinhole(self, factor: float = 1.0) -> Camera:
        """The same pose through its pinhole alone (no lens), sampled at `factor` times its
        resolution (same field of view; at least 2 px a side): what off-screen renderings of
        this camera draw."""
        i = self.intrinsics
        size = (max(2, round(i.width * factor)), max(2, round(i.height * factor)))
        return Camera.create(i.scaled(*size), self.position, self.orientation, self.near, self.far)

    def project(self, points_enu: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """World points (N, 3) -> pixel coordinates (N, 2) as (u, v) and camera depth (N,) metres.

        Depth is the distance along the optical axis (positive in front of the camera).
        """
        p = np.atleast_2d(np.asarray(points_enu, np.float64))
        cam = (p - np.asarray(self.position)) @ rotations.to_matrix(self.orientation)
        depth = -cam[:, 2]
        if self.lens is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                return self.lens.distort(
                    np.column_stack([cam[:, 0] / depth, -cam[:, 1] / depth])
                ), depth
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.intrinsics.fx * cam[:, 0] / depth + self.intrinsics.cx
            v = self.intrinsics.cy - self.intrinsics.fy * cam[:, 1] / depth
        return np.stack([u, v], axis=1), depth

    def pixel_rays(self, uv: npt.ArrayLike) -> FloatArray:
        """Unit ray directions (N, 3) in ENU through pixel coordinates (N, 2) (u, v)."""
        uv = np.atleast_2d(np.asarray(uv, np.float64))
        if self.lens is not None:
            ab = self.lens.undistort(uv)
            d = np.column_stack([ab[:, 0], -ab[:, 1], -np.ones(len(uv))])
        else:
            d = np.stack(
                [
                    (uv[:, 0] - self.intrinsics.cx) / self.intrinsics.fx,
                    (self.intrinsics.cy - uv[:, 1]) / self.intrinsics.fy,
                    -np.ones(len(uv)),
                ],
                axis=1,
            )
        d = d @ rotations.to_matrix(self.orientation).T
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def frustum_corners(self, distance: float | None = None) -> FloatArray:
        """(8, 3) ENU corners: the near plane's four then the plane at `distance` (default far),
        each in the order top-left, top-right, bottom-right, bottom-left."""
        w, h = self.intrinsics.width, self.intrinsics.height
        uv = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
        rays = self.pixel_rays(uv)
        fwd = -rotations.to_matrix(self.orientation)[:, 2]
        cos = rays @ fwd
        pos = np.asarray(self.position)
        far = self.far if distance is None else distance
        near_pts = pos + rays * (self.near / cos)[:, None]
        far_pts = pos + rays * (far / cos)[:, None]
        return np.concatenate([near_pts, far_pts])


def depth_map_size(video_width: int, video_height: int, long_side: int) -> tuple[int, int]:
    """Depth-map (width, height) in texels: `long_side` on the video's long side, its aspect."""
    if video_width >= video_height:
        return long_side, max(1, round(long_side * video_height / video_width))
    return max(1, round(long_side * video_width / video_height)), long_side


def camera_in_frame(
    camera: Camera, src: LocalFrame, dst: LocalFrame, lift_m: float = 0.0
) -> Camera:
    """The camera moved from local frame `src` into `dst` (another clip's session): its
    position through ECEF (then raised by lift_m, app.footage.clips.ground_lift), its orientation
    turned by the tangent planes' difference."""
    position = dst.ecef_to_enu(src.enu_to_ecef(np.asarray(camera.position, np.float64)))
    position = position + [0.0, 0.0, lift_m]
    orientation = rotations.multiply(
        rotations.from_matrix(src.rotation_to(dst)), camera.orientation
    )
    return Camera.create(
        camera.intrinsics, position, orientation, camera.near, camera.far, camera.lens
    )


def image_size(camera: Camera) -> tuple[int, int]:
    """(width, height) px of the image a camera takes: its lens's, else its pinhole's."""
    if camera.lens is not None:
        return camera.lens.width, camera.lens.height
    return camera.intrinsics.width, camera.intrinsics.height


def looking_down(
    size_px: tuple[int, int],
    centre_xy: npt.ArrayLike,
    cell_m: float,
    ground_z: float,
    z_range: tuple[float, float],
    above_m: float,
) -> Camera:
    """A pinhole looking straight down over centre_xy (ENU east, north m), north up: size_px
    (width, height) pixels, cell_m metres a pixel on the plane z = ground_z (ENU m). It stands
    above_m over the scene's top (z_range: the scene's lowest and highest ENU z, m), far enough
    for a near-orthographic view, its clip planes around the scene."""
    w, h = size_px
    lo_z, hi_z = z_range
    eye = np.array([*np.asarray(centre_xy, np.float64)[:2], hi_z + above_m])
    f = (eye[2] - ground_z) / cell_m  # cell_m a pixel on the ground, not at the scene's top
    return Camera.create(
        Intrinsics(w, h, f, f, w / 2, h / 2), eye,
        look_at_quat(eye, eye - [0.0, 0.0, 1.0]), above_m - 1.0, above_m + (hi_z - lo_z) + 1.0,
    )  # fmt: skip
