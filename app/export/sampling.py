"""How finely the video sees each triangle of a scene: the texel size a memory of it needs, from
the cameras that will paint it. Pure numpy.

A camera's pixel, decoded at `long_side` pixels on the image's long side (the painter's
frames, app.export.painting.DECODE_LONG_SIDE), covers range / f metres on a surface facing it
(f the focal length in those pixels, range in m) and 1 / cos(incidence) times that along the
slope of one seen obliquely; a triangle's ground sampling is the finest, over the cameras and
over its corners, edge middles and centre in the camera's image and in front of it, of the
geometric mean of the two: range / (f sqrt(cos)). Surfaces seen more obliquely than the
memory paints (app.export.memory.MIN_COS_INCIDENCE) do not count; occlusion is not tested (a
wall behind another gets the texel it would get if seen). A triangle no camera sees gets
`coarsest_m`. At most MAX_CAMERAS cameras are looked at, evenly spread over those given.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.camera.pinhole import Camera, image_size
from app.export.memory import MIN_COS_INCIDENCE

MAX_CAMERAS = 96
FINEST_M = 0.02  # no texel finer than this, whatever the video
COARSEST_M = 1.0  # a triangle no camera sees
CHUNK = 200_000  # triangle-points a step


def _probe_points(tri: np.ndarray) -> np.ndarray:
    """(T, 7, 3): each triangle's corners, edge middles and centre."""
    mids = (tri + np.roll(tri, -1, axis=1)) / 2
    return np.concatenate([tri, mids, tri.mean(axis=1, keepdims=True)], axis=1)


def texel_targets(
    triangles: np.ndarray,
    cameras: Sequence[Camera],
    long_side: int,
    finest_m: float = FINEST_M,
    coarsest_m: float = COARSEST_M,
) -> np.ndarray:
    """(T,) m: the ground sampling of each triangle (T, 3, 3) ENU m by the cameras' frames
    decoded at `long_side` px (see the module docstring), within [finest_m, coarsest_m]."""
    tri = np.asarray(triangles, np.float64)
    best = np.full(len(tri), np.inf)
    if not len(tri) or not len(cameras):
        return np.full(len(tri), coarsest_m)
    pick = np.unique(np.linspace(0, len(cameras) - 1, min(len(cameras), MAX_CAMERAS)).round())
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    probes = _probe_points(tri)
    step = max(1, CHUNK // probes.shape[1])
    for k in pick.astype(int):
        cam = cameras[k]
        w, h = image_size(cam)
        f = cam.intrinsics.fx * min(1.0, long_side / max(w, h))
        eye = np.asarray(cam.position, np.float64)
        for s in range(0, len(tri), step):
            p = probes[s : s + step]
            n = len(p)
            uv, depth = cam.project(p.reshape(-1, 3))
            uv, depth = uv.reshape(n, -1, 2), depth.reshape(n, -1)
            inside = (depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < w)
            inside &= (uv[..., 1] >= 0) & (uv[..., 1] < h)
            ray = p - eye
            rng = np.linalg.norm(ray, axis=2)
            cos = np.abs(np.einsum("tpk,tk->tp", ray, normal[s : s + step])) / np.maximum(rng, 1e-9)
            ok = inside & (cos >= MIN_COS_INCIDENCE)
            gsd = np.where(ok, rng / (f * np.sqrt(np.maximum(cos, MIN_COS_INCIDENCE))), np.inf)
            best[s : s + step] = np.minimum(best[s : s + step], gsd.min(axis=1))
    return np.where(np.isfinite(best), np.clip(best, finest_m, coarsest_m), coarsest_m)
