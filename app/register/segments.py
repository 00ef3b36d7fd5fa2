"""Line matching for registration by geometry, as pure numpy and OpenCV: the model's edge points
grouped into straight segments, the frame's segments found by OpenCV's line segment detector
(LSD), and each model segment matched whole to one frame segment of a like direction that
overlaps it, so that a long line of the model (a wall's foot, a roof's rim) is not pulled point
by point onto the short edges beside it (a row of windows, lettering).

It is the alternative to app.register.edges' nearest edge pixel per point
(`EdgeSettings.lines_by = "segments"`), measured against it in docs/ACCURACY.md ("Registration
by geometry": lines matched as segments).

Pixels: this project's (u right, v down, centres at half-integers); a level's pixels are
`factor` times the full-size frame's.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from app.camera.pinhole import Camera
from app.register.keyframe import projected

FloatArray = npt.NDArray[np.float64]

ANGLE_BIN_DEG = 6.0  # model points whose line normals lie within one bin may share a segment
OFFSET_PX = 2.0  # and whose lines lie within this of one another (rendering pixels)
GAP_PX = 8.0  # a gap along the line longer than this ends a segment
MIN_POINTS = 5  # a segment has at least this many model points
MATCH_DEG = 8.0  # a frame segment matches a model segment within this turn
MIN_OVERLAP = 0.3  # of the shorter of the two, along the line (LSD breaks long lines up)
MIN_LENGTH_PX = 8.0  # frame segments shorter than this (level pixels) are left out


def group_lines(uv: FloatArray, angle: FloatArray) -> npt.NDArray[np.int64]:
    """Model edge points (uv (N, 2) rendering pixels, their line normals' angle (N,) rad in
    [0, pi)) grouped into straight segments: (N,) a segment number each, -1 for a point in none.
    Points share a segment when their normals lie in one ANGLE_BIN_DEG bin, their lines within
    OFFSET_PX and no gap along it exceeds GAP_PX."""
    labels = np.full(len(uv), -1, np.int64)
    if not len(uv):
        return labels
    bins = np.floor(np.degrees(angle) / ANGLE_BIN_DEG).astype(np.int64)
    nxt = 0
    for b in np.unique(bins):
        idx = np.flatnonzero(bins == b)
        theta = np.radians((b + 0.5) * ANGLE_BIN_DEG)
        n = np.array([np.cos(theta), np.sin(theta)])
        t = np.array([-n[1], n[0]])
        rho, along = uv[idx] @ n, uv[idx] @ t
        order = np.argsort(rho)
        cuts = np.flatnonzero(np.diff(rho[order]) > OFFSET_PX) + 1
        for line in np.split(order, cuts):
            line = line[np.argsort(along[line])]
            for seg in np.split(line, np.flatnonzero(np.diff(along[line]) > GAP_PX) + 1):
                if len(seg) >= MIN_POINTS:
                    labels[idx[seg]] = nxt
                    nxt += 1
    return labels


class FrameSegments:
    """A frame's straight segments at one level (LSD on its grey image), in full-size pixels:
    ends a and b (S, 2), unit normals (S, 2) and their angle (S,) rad in [0, pi), lengths (S,)."""

    def __init__(self, rgb: np.ndarray, factor: float) -> None:
        self.factor = factor
        grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
        found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(grey)[0]
        seg = np.zeros((0, 4)) if found is None else found.reshape(-1, 4).astype(np.float64)
        # OpenCV's pixel centres are at integers; this project's at half-integers
        seg = (seg + 0.5) / factor
        a, b = seg[:, :2], seg[:, 2:]
        length = np.linalg.norm(b - a, axis=1)
        keep = length * factor >= MIN_LENGTH_PX
        self.a, self.b, self.length = a[keep], b[keep], length[keep]
        d = (self.b - self.a) / self.length[:, None]
        self.normal = np.column_stack([-d[:, 1], d[:, 0]])
        self.angle = np.mod(np.arctan2(self.normal[:, 1], self.normal[:, 0]), np.pi)

    def pairs(
        self, camera: Camera, gate: float, points: FloatArray, labels: npt.NDArray[np.int64]
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], FloatArray, FloatArray]:
        """Each model segment (points (N, 3) ENU m grouped by `labels`) projected by `camera` and
        matched to the nearest frame segment within MATCH_DEG that overlaps MIN_OVERLAP of the
        shorter of the two and lies within `gate` level pixels of its middle: (which points
        found a line, which are in view on a segment; for those found, the matched lines'
        normals (M, 2) and the signed point-to-line distances (M,), full-size pixels), as
        app.register.edges' nearest-edge pairs."""
        uv, in_view = projected(camera, points)
        # a point on no segment is no candidate here
        in_view &= labels >= 0
        found = np.zeros(len(points), bool)
        normals = np.zeros((len(points), 2))
        resid = np.zeros(len(points))
        if not len(self.a):
            return found, in_view, normals[found], resid[found]
        for g in np.unique(labels[(labels >= 0) & in_view]):
            idx = np.flatnonzero((labels == g) & in_view)
            if len(idx) < 3:
                continue
            p = uv[idx]
            centre = p.mean(axis=0)
            _, _, vt = np.linalg.svd(p - centre, full_matrices=False)
            t = vt[0]
            theta = np.mod(np.arctan2(t[0], -t[1]), np.pi)  # the normal's angle
            turn = np.abs(np.mod(self.angle - theta + np.pi / 2, np.pi) - np.pi / 2)
            ta, tb = (self.a - centre) @ t, (self.b - centre) @ t
            lo, hi = np.minimum(ta, tb), np.maximum(ta, tb)
            along = p @ t - centre @ t
            overlap = np.minimum(hi, along.max()) - np.maximum(lo, along.min())
            shorter = np.minimum(self.length, along.max() - along.min())
            dist = np.abs(np.sum(self.normal * (centre - self.a), axis=1))
            ok = (
                (turn <= np.radians(MATCH_DEG))
                & (overlap >= MIN_OVERLAP * np.maximum(shorter, 1e-9))
                & (dist * self.factor <= gate)
            )
            if not ok.any():
                continue
            best = np.flatnonzero(ok)[np.argmin(dist[ok])]
            found[idx] = True
            normals[idx] = self.normal[best]
            resid[idx] = (p - self.a[best]) @ self.normal[best]
        return found, in_view, normals[found], resid[found]
