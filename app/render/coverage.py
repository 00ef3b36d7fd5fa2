"""What a projector covers on the screen, and how fine its depth map needs to be there.

Pure geometry (numpy, no GL) for the deferred projectors (app.render.decals): the part of the
window that a projector's frustum can touch is the projection of a convex polytope, the frustum
cut by the scene's bounding box and by the window camera's near plane; a projector is shaded
only inside that polygon. Its depth map needs one texel per screen pixel at the worst point of
that polytope: the ratio of the point's depth from the projector to its depth from the window
camera, times the window's focal length.

Frames: ENU metres; OpenGL clip conventions (app.camera.pinhole): a point x is inside a
camera's frustum when its clip coordinates c = VP x satisfy -c.w <= c.x, c.y, c.z <= c.w.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
import numpy.typing as npt

from app.camera.pinhole import Camera

MIN_DEPTH_LONG_SIDE = 128  # texels: below this a depth map saves nothing worth its blockiness
SIZE_STEPS_PER_OCTAVE = 4  # depth-map sizes are quantised to 2^(k/4): a moving view rarely
# changes the size, and a changed size costs a redraw


@dataclass(frozen=True)
class Coverage:
    """A projector's reach in one view: `polygon` (K, 2) the window-NDC convex polygon (counter-
    clockwise) it may touch, `ratio` the largest depth-from-projector / depth-from-view over the
    part of its frustum inside the scene and in front of the view (inf when the view's eye is
    inside it)."""

    polygon: npt.NDArray[np.float64]
    ratio: float


def frustum_planes(view_projection: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(6, 4) planes (a, b, c, d) of a frustum, a.x + d >= 0 inside: left, right, bottom, top,
    near, far, from the rows of its clip-from-world matrix (Gribb and Hartmann)."""
    m = np.asarray(view_projection, np.float64)
    return np.array([m[3] + m[0], m[3] - m[0], m[3] + m[1], m[3] - m[1], m[3] + m[2], m[3] - m[2]])


def box_planes(lo: npt.ArrayLike, hi: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(6, 4) planes of the axis-aligned box [lo, hi], inside >= 0: x >= lo_x, x <= hi_x, then
    y and z likewise."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    planes = np.zeros((6, 4))
    planes[0::2, :3] = np.eye(3)
    planes[1::2, :3] = -np.eye(3)
    planes[0::2, 3], planes[1::2, 3] = -lo, hi
    return planes


def polytope_vertices(planes: npt.ArrayLike, tol: float = 1e-6) -> npt.NDArray[np.float64]:
    """(N, 3) vertices of the bounded convex polytope {x: a.x + d >= 0 for every plane}: every
    point where three planes meet that lies inside all of them (relative tolerance `tol` of each
    plane's scale). Empty when the planes enclose nothing."""
    p = np.asarray(planes, np.float64)
    p = p / np.linalg.norm(p[:, :3], axis=1, keepdims=True)
    i, j, k = _triples(len(p))
    # Each triple's meeting point by Cramer's rule: x = (d_i (n_j x n_k) + d_j (n_k x n_i)
    # + d_k (n_i x n_j)) / (n_i . (n_j x n_k)), with the planes n.x = d (d = -offset).
    n, d = p[:, :3], -p[:, 3:4]
    ni, nj, nk = n[i], n[j], n[k]
    jk, ki, ij = _cross(nj, nk), _cross(nk, ni), _cross(ni, nj)
    det = np.einsum("ij,ij->i", ni, jk)
    ok = np.abs(det) > 1e-9
    x = (d[i] * jk + d[j] * ki + d[k] * ij)[ok] / det[ok, None]
    scale = 1.0 + np.abs(x).max(axis=1, keepdims=True)
    inside = np.all(x @ p[:, :3].T + p[:, 3] >= -tol * scale, axis=1)
    return x[inside]


_NEXT, _AFTER = [1, 2, 0], [2, 0, 1]


def _cross(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Row-wise cross products of (N, 3) arrays (np.cross's general axis handling costs more
    than the arithmetic at a frame's few hundred rows)."""
    return a[:, _NEXT] * b[:, _AFTER] - a[:, _AFTER] * b[:, _NEXT]


@lru_cache(maxsize=8)
def _triples(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The indices (i, j, k) of every three of n planes."""
    t = np.array(list(combinations(range(n), 3)))
    return t[:, 0], t[:, 1], t[:, 2]


def convex_hull_2d(points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(K, 2) the convex hull of 2-D points, counter-clockwise, without repeated points
    (Andrew's monotone chain)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]  # by x, then y
    if len(pts) > 1:
        pts = pts[np.concatenate([[True], np.any(pts[1:] != pts[:-1], axis=1)])]
    if len(pts) < 3:
        return pts

    def half(seq: npt.NDArray[np.float64]) -> list[npt.NDArray[np.float64]]:
        out: list[npt.NDArray[np.float64]] = []
        for q in seq:
            while len(out) >= 2:
                o, a = out[-2], out[-1]
                if (a[0] - o[0]) * (q[1] - o[1]) - (a[1] - o[1]) * (q[0] - o[0]) > 0:
                    break
                out.pop()
            out.append(q)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _depths(camera: Camera, points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Distance along each camera's optical axis (m) of ENU points."""
    forward = -np.asarray(camera.view, np.float64)[2, :3]  # the camera looks down its -z
    return (points - np.asarray(camera.position)) @ forward


def coverage(
    projector: Camera, view: Camera, scene_bounds: npt.ArrayLike, margin_m: float = 1.0
) -> Coverage | None:
    """Where `projector` can touch the scene in `view`: None when its frustum meets neither the
    scene's bounding box (ENU (2, 3) min/max, grown by margin_m) nor the view."""
    lo, hi = np.asarray(scene_bounds, np.float64)
    planes = np.concatenate(
        [
            frustum_planes(projector.view_projection),
            box_planes(lo - margin_m, hi + margin_m),
            frustum_planes(view.view_projection)[4:5],  # in front of the view's near plane
        ]
    )
    vertices = polytope_vertices(planes)
    if len(vertices) < 4:
        return None
    clip = (
        np.column_stack([vertices, np.ones(len(vertices))])
        @ np.asarray(view.view_projection, np.float64).T
    )
    ndc = clip[:, :2] / clip[:, 3:4]
    polygon = convex_hull_2d(ndc)
    if len(polygon) < 3 or np.any(polygon.max(axis=0) < -1.0) or np.any(polygon.min(axis=0) > 1.0):
        return None
    eye = np.asarray(view.position, np.float64)
    if np.all(planes[:12, :3] @ eye + planes[:12, 3] >= 0):  # the eye is inside the polytope
        return Coverage(polygon, float("inf"))
    # The ratio's largest value over the polytope: at its vertices where it stays below 1 (its
    # sublevel sets are then balls), and sampled on the segments between them otherwise.
    n = len(vertices)
    i, j = np.triu_indices(n, 1)
    t = np.linspace(0.0, 1.0, 5)[1:-1]
    between = (vertices[i, None] * (1 - t)[:, None] + vertices[j, None] * t[:, None]).reshape(-1, 3)
    samples = np.concatenate([vertices, between])
    d_view = _depths(view, samples)
    d_proj = _depths(projector, samples)
    near = max(view.near, 1e-3)
    ratio = float(np.max(np.maximum(d_proj, projector.near) / np.maximum(d_view, near)))
    return Coverage(polygon, ratio)


def depth_long_side(
    projector: Camera, view: Camera, ratio: float, cap: int, safety: float = 1.0
) -> int:
    """Depth-map texels on the projector's long side so that one texel spans at most one window
    pixel (times 1/safety) wherever the projector can touch the scene: its focal length in
    texels f_view * ratio, the view's focal length in pixels. Quantised to 2^(k/4), between
    MIN_DEPTH_LONG_SIDE and cap (the settings' size, used where the bound exceeds it)."""
    i = projector.intrinsics
    f_view = max(view.intrinsics.fx, view.intrinsics.fy)
    if not np.isfinite(ratio):
        return cap
    long_px = max(i.width, i.height)
    per_texel = max(i.fx, i.fy) / long_px  # the projector's focal per long-side texel
    wanted = safety * f_view * ratio / per_texel
    if wanted >= cap:
        return cap
    step = 2.0 ** (
        np.ceil(np.log2(max(wanted, 1.0)) * SIZE_STEPS_PER_OCTAVE) / SIZE_STEPS_PER_OCTAVE
    )
    return int(min(cap, max(MIN_DEPTH_LONG_SIDE, np.ceil(step))))


def polygon_pixels(polygon: np.ndarray, width: int, height: int) -> int:
    """Window pixels (about) inside an NDC polygon clipped to the screen: its area by the
    shoelace formula after clipping to [-1, 1]^2, in pixels."""
    clipped = _clip_to_square(np.asarray(polygon, np.float64))
    if len(clipped) < 3:
        return 0
    x, y = clipped[:, 0], clipped[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return int(round(area * width * height / 4.0))


def _clip_to_square(poly: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon to the square [-1, 1]^2."""
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            if len(poly) == 0:
                return poly
            out = []
            inside = sign * poly[:, axis] <= 1.0
            for k in range(len(poly)):
                a, b = poly[k - 1], poly[k]
                ia, ib = inside[k - 1], inside[k]
                if ib != ia:
                    t = (sign - a[axis]) / (b[axis] - a[axis])
                    out.append(a + t * (b - a))
                if ib:
                    out.append(b)
            poly = np.array(out).reshape(-1, 2)
    return poly
