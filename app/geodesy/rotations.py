"""Quaternion maths. Quaternions are [w, x, y, z] (scalar first), unit, and map device/camera
vectors to the world: v_world = q * v * conj(q). This is the only module that talks to scipy's
Rotation, whose order is [x, y, z, w]; the conversion happens here and nowhere else.

Heading / pitch / roll are those of a camera's optical axis (camera looks down its -z axis,
y up, x right, the OpenGL convention): heading in degrees clockwise from true north, pitch in
degrees above the horizon, roll in degrees about the optical axis, positive when the image's
right side goes down.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation, Slerp

from app.core.constants import EPS_DEGENERATE

FloatArray = npt.NDArray[np.float64]

# Camera level and looking north: columns are the camera x, y, z axes in ENU.
_LEVEL_NORTH = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def to_scipy(q: npt.ArrayLike) -> Rotation:
    """[w, x, y, z] (..., 4) -> scipy Rotation."""
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(np.concatenate([q[..., 1:4], q[..., :1]], axis=-1))


def from_scipy(r: Rotation) -> FloatArray:
    """scipy Rotation -> [w, x, y, z] (..., 4) with w >= 0."""
    xyzw = r.as_quat()
    q = np.concatenate([xyzw[..., 3:4], xyzw[..., :3]], axis=-1)
    return canonical(q)


def canonical(q: npt.ArrayLike) -> FloatArray:
    """Normalise and flip sign so that w >= 0 (same rotation)."""
    q = np.asarray(q, np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < EPS_DEGENERATE):
        raise ValueError("zero-norm quaternion")
    q = q / n
    return np.where(q[..., :1] < 0.0, -q, q)


def multiply(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Hamilton product a * b of [w, x, y, z] quaternions (broadcast over leading axes)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def conjugate(q: npt.ArrayLike) -> FloatArray:
    """Conjugate (= inverse for unit quaternions)."""
    q = np.asarray(q, np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def from_rotvec(v: npt.ArrayLike) -> FloatArray:
    """Quaternion(s) [w, x, y, z] of rotation vectors (..., 3): axis times angle in radians."""
    return from_scipy(Rotation.from_rotvec(np.asarray(v, np.float64)))


def to_matrix(q: npt.ArrayLike) -> FloatArray:
    """[w, x, y, z] (..., 4) -> rotation matrices (..., 3, 3) with v_world = R @ v (normalised
    first, as scipy's Rotation does). Written out rather than through scipy: a frame's cameras
    ask for dozens of these, and scipy's Rotation costs a hundred times more for one."""
    q = np.asarray(q, np.float64)
    if q.shape == (4,):  # one: in floats, without numpy's per-call cost on tiny arrays
        n = math.sqrt(float(q @ q))
        if n < EPS_DEGENERATE:
            raise ValueError("zero-norm quaternion")
        return np.array(_matrix_rows(*(float(v) / n for v in q)))
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < EPS_DEGENERATE):
        raise ValueError("zero-norm quaternion")
    rows = _matrix_rows(*np.moveaxis(q / n, -1, 0))
    return np.stack([np.stack(row, -1) for row in rows], axis=-2)


def _matrix_rows(w, x, y, z) -> tuple:
    """The rotation matrix of a unit quaternion's components (floats or arrays), row by row."""
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def from_matrix(r: npt.ArrayLike) -> FloatArray:
    """Rotation matrices (..., 3, 3) -> [w, x, y, z] (..., 4)."""
    return from_scipy(Rotation.from_matrix(np.asarray(r, np.float64)))


def rotate(q: npt.ArrayLike, v: npt.ArrayLike) -> FloatArray:
    """Rotate vectors v (..., 3) by q: q * v * conj(q)."""
    return to_scipy(q).apply(np.asarray(v, np.float64))


def angle_between(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Total angle (radians) of the rotation taking b to a: 2 acos |<a, b>|."""
    d = np.abs(np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


def _rz(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def _rx(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack(
        [np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2
    )


def camera_matrix_from_hpr(
    heading_deg: npt.ArrayLike, pitch_deg: npt.ArrayLike, roll_deg: npt.ArrayLike
) -> FloatArray:
    """Camera -> ENU rotation matrices (..., 3, 3) from optical-axis heading, pitch, roll (deg).

    R = Rz(-heading) @ LEVEL_NORTH @ Rx(pitch) @ Rz(-roll): heading turns clockwise seen from above,
    pitch raises the optical axis, roll turns the image clockwise as the camera sees it.
    """
    h = np.radians(np.asarray(heading_deg, np.float64))
    p = np.radians(np.asarray(pitch_deg, np.float64))
    r = np.radians(np.asarray(roll_deg, np.float64))
    h, p, r = np.broadcast_arrays(h, p, r)
    return _rz(-h) @ _LEVEL_NORTH @ _rx(p) @ _rz(-r)


def camera_quat_from_hpr(
    heading_deg: npt.ArrayLike, pitch_deg: npt.ArrayLike, roll_deg: npt.ArrayLike
) -> FloatArray:
    """Camera -> ENU quaternions [w, x, y, z] from optical-axis heading, pitch, roll (deg)."""
    return from_matrix(camera_matrix_from_hpr(heading_deg, pitch_deg, roll_deg))


def hpr_from_camera_matrix(r: npt.ArrayLike) -> FloatArray:
    """Camera -> ENU matrices (..., 3, 3) -> (..., 3) heading [0, 360), pitch, roll (deg).

    At pitch +-90 deg heading is undefined; roll then absorbs the rotation.
    """
    r = np.asarray(r, np.float64)
    f = -r[..., :, 2]  # optical axis in ENU
    heading = np.degrees(np.arctan2(f[..., 0], f[..., 1])) % 360.0
    pitch = np.degrees(np.arcsin(np.clip(f[..., 2], -1.0, 1.0)))
    # Undo heading and pitch; what remains is Rz(-roll).
    rest = (
        np.swapaxes(_rx(np.radians(pitch)), -1, -2) @ _LEVEL_NORTH.T @ _rz(np.radians(heading)) @ r
    )
    roll = -np.degrees(np.arctan2(rest[..., 1, 0], rest[..., 0, 0]))
    return np.stack([heading, pitch, roll], axis=-1)


def hpr_from_camera_quat(q: npt.ArrayLike) -> FloatArray:
    """Camera -> ENU quaternions [w, x, y, z] -> heading, pitch, roll (deg); see hpr_from_camera_matrix."""
    return hpr_from_camera_matrix(to_matrix(q))


def circular_mean(angles_rad: npt.ArrayLike) -> float:
    """Mean direction (radians, in (-pi, pi]) of angles in radians: the angle of their mean unit vector."""
    a = np.asarray(angles_rad, np.float64)
    return float(np.arctan2(np.mean(np.sin(a)), np.mean(np.cos(a))))


def wrap_degrees(a: npt.ArrayLike) -> FloatArray:
    """Wrap angles (deg) into [-180, 180)."""
    return (np.asarray(a, np.float64) + 180.0) % 360.0 - 180.0


class Interpolator:
    """Spherical linear interpolation of quaternions (N, 4) given at times t_source (built once,
    queried many times); times outside the source range take the first/last quaternion, and a
    single quaternion holds at every time. Never interpolates Euler angles, so the +-180 deg
    heading wrap is harmless."""

    def __init__(self, t_source: npt.ArrayLike, q_source: npt.ArrayLike) -> None:

        self.t = np.asarray(t_source, np.float64)
        q = np.asarray(q_source, np.float64).reshape(-1, 4)
        self._one = canonical(q[0]) if len(q) == 1 else None
        self._slerp = None if len(q) == 1 else Slerp(self.t, to_scipy(q))

    def __call__(self, t_query: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_query, np.float64)
        if self._slerp is None:
            return np.broadcast_to(self._one, (*t.shape, 4)).copy()
        return from_scipy(self._slerp(np.clip(t, self.t[0], self.t[-1])))


def slerp(t_source: npt.ArrayLike, q_source: npt.ArrayLike, t_query: npt.ArrayLike) -> FloatArray:
    """One-off `Interpolator(t_source, q_source)(t_query)`."""
    return Interpolator(t_source, q_source)(t_query)


def about_z(angle_deg: float) -> FloatArray:
    """Quaternion of a rotation by angle_deg (counter-clockwise seen from +z) about z. In the
    device frame this is a roll of the device; in ENU use `heading_turn`."""
    half = np.radians(angle_deg) / 2.0
    return np.array([np.cos(half), 0.0, 0.0, np.sin(half)])


def heading_turn(heading_deg: float) -> FloatArray:
    """The world-frame turn about Up that adds heading_deg to every heading (clockwise seen from
    above, as headings count): left-multiply an ENU attitude by it. The one way to write it."""
    return about_z(-heading_deg)
