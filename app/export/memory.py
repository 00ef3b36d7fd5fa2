"""What the video saw, kept on the scene's surfaces: one colour, time and quality per surface
sample (a texel of a painted model's atlas, a cell of an orthophoto's grid). Pure numpy; the
GL part (each frame's distances, for the occlusion test) comes in as an array.

A sample is painted by a frame when its point (ENU m) lies in the image (through the camera's
lens), the frame's own distance map, rendered through the camera's pinhole, says nothing nearer
hides it, within a bias that grows with range (as the drape's depth test), and the frame sees
its surface less obliquely than MIN_COS_INCIDENCE (a wall seen edge-on from a drone is a few
pixels wide, and any error in the pose paints it with the ground beside it). Its colour is
the frame's, bilinear; its time the frame's (UTC s); its quality in (0, 1] the incidence's cosine
over (1 + range / QUALITY_RANGE_M) and over (1 + u / QUALITY_UNCERTAINTY_M), u the metres on
the surface the pose's uncertainty explains there (the position's, and the attitude's times the
range, in quadrature; app.solve.uncertainty), times the frame's agreement with the model there
where one is given (`agreement`: how much the frame looks like the model rendered from its pose; an
unmodelled car or a misregistered frame is still painted, but a frame that agrees wins under
the best rule). The rule decides what a sample keeps: newest (the last frame
that saw it, default), best (the highest quality) or first. Samples are kept in blocks of
BLOCK consecutive ones with their bounding boxes, and a frame only looks at the blocks its
frustum meets. The memory's size is fixed by its samples, whatever the number of frames.

With a `history` (t0, t1, E), each sample also keeps, for each of E equal epochs of [t0, t1] s,
its newest sighting in that epoch (colour and time), whatever the rule: the viewer's time slider
shows the memory as it was at an earlier moment from them (app.export.memory_view), exact to one
epoch, in 7 bytes a sample an epoch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit
from scipy.ndimage import map_coordinates

from app.camera.pinhole import Camera, image_size
from app.geodesy import rotations
from app.render.coverage import frustum_planes

RULES = ("newest", "best", "first")
QUALITY_RANGE_M = 100.0  # quality halves at this range (head-on)
QUALITY_UNCERTAINTY_M = 1.0  # ... and at this much of the pose's uncertainty on the surface
DEPTH_BIAS_M = 0.15  # a surface point within this of the frame's distance map is the one seen,
DEPTH_BIAS_PER_M = 0.01  # plus this much per metre of range
BLOCK = 4096  # samples a culling block
AGREEMENT_WINDOW = 9  # pixels (of the distance map) over which the frame and the model are compared
AGREEMENT_MIN = 0.25  # the least a disagreeing pixel's quality is multiplied by
FLAT_VARIANCE = 4.0  # grey levels^2: a model this flat around a pixel says nothing to agree with
MIN_COS_INCIDENCE = (
    0.2  # surfaces seen more obliquely than 78 deg from their normal are not painted
)


def boxes_in_frustum(camera: Camera, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(B,) bool: which boxes (lo, hi (B, 3) ENU m corners) the camera's pinhole frustum
    meets (conservatively: a box beside a corner of the frustum may be counted in)."""
    inside = np.ones(len(lo), bool)
    for a, b, c, d in frustum_planes(camera.view_projection):  # a sign test: unnormalised
        far_corner = np.where(np.array([a, b, c]) > 0, hi, lo)
        inside &= far_corner @ np.array([a, b, c]) + d >= 0
    return inside


@njit(cache=True)
def _pinhole_visible(
    points, normals, idx, r, pos, k, size, dscale, dist, agree, has_agree, sigmas
):  # pragma: no cover - compiled
    """SurfaceMemory._samples for a lensless camera in one pass over the samples idx: (N,)
    which are kept (inside the frame, within the distance map's surface plus the depth bias,
    facing the camera), (N, 2) their frame pixels, (N,) float32 quality. k = (fx, fy, cx, cy) of the
    camera's image scaled by (sx, sy) to the frame's, size its (w, h); dscale: the distance map's pixels per camera pixel (x, y); dist and
    agree: the distance (m) and agreement maps, looked up at the nearest pixel as scipy's
    map_coordinates(order=0, mode="nearest") does; sigmas: (position m, attitude rad)."""
    fx, fy, cx, cy, sx, sy = k
    w, h = size
    dsx, dsy = dscale
    dh, dw = dist.shape
    ah, aw = agree.shape
    s0, s1 = sigmas
    n = len(idx)
    keep = np.zeros(n, np.bool_)
    uv = np.empty((n, 2))
    quality = np.zeros(n, np.float32)
    for j in range(n):
        i = idx[j]
        dx = points[i, 0] - pos[0]
        dy = points[i, 1] - pos[1]
        dz = points[i, 2] - pos[2]
        x = dx * r[0, 0] + dy * r[1, 0] + dz * r[2, 0]
        y = dx * r[0, 1] + dy * r[1, 1] + dz * r[2, 1]
        d = -(dx * r[0, 2] + dy * r[1, 2] + dz * r[2, 2])
        if not d > 0.0:
            continue
        u = (fx * x / d + cx) * sx
        v = (cy - fy * y / d) * sy
        if not (u >= 0.0 and u < w and v >= 0.0 and v < h):
            continue
        rng = np.sqrt(dx * dx + dy * dy + dz * dz)
        row = int(np.floor((v / sy) * dsy - 0.5 + 0.5))
        col = int(np.floor((u / sx) * dsx - 0.5 + 0.5))
        if (
            not rng
            <= dist[min(max(row, 0), dh - 1), min(max(col, 0), dw - 1)]
            + DEPTH_BIAS_M
            + DEPTH_BIAS_PER_M * rng
        ):
            continue
        cos = abs(dx * normals[i, 0] + dy * normals[i, 1] + dz * normals[i, 2]) / rng
        if not cos >= MIN_COS_INCIDENCE:
            continue
        a = 1.0
        if has_agree:
            a = agree[min(max(row, 0), ah - 1), min(max(col, 0), aw - 1)]
        off_m = np.hypot(s0, rng * s1)
        quality[j] = a * cos / (1.0 + rng / QUALITY_RANGE_M) / (1.0 + off_m / QUALITY_UNCERTAINTY_M)
        uv[j, 0], uv[j, 1] = u, v
        keep[j] = True
    return keep, uv, quality


def agreement(frame_rgb: np.ndarray, model_rgb: np.ndarray) -> np.ndarray:
    """(h, w) float32 in [AGREEMENT_MIN, 1], at model_rgb's size (h, w): how much the frame
    (any size, the same view through the same pinhole) looks like the model rendered from its
    pose, by the normalised cross-correlation of their greys over AGREEMENT_WINDOW pixels, mapped
    0.5 + 0.5 ncc; 1 where the model is flat there (nothing to agree with)."""
    h, w = model_rgb.shape[:2]
    f = cv2.cvtColor(
        cv2.resize(frame_rgb, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY
    )
    m = cv2.cvtColor(np.ascontiguousarray(model_rgb), cv2.COLOR_RGB2GRAY)
    f, m = f.astype(np.float32), m.astype(np.float32)
    k = (AGREEMENT_WINDOW, AGREEMENT_WINDOW)
    mf, mm = cv2.blur(f, k), cv2.blur(m, k)
    vf = np.maximum(cv2.blur(f * f, k) - mf * mf, 0.0)
    vm = np.maximum(cv2.blur(m * m, k) - mm * mm, 0.0)
    ncc = (cv2.blur(f * m, k) - mf * mm) / np.sqrt(vf * vm + 1.0)
    out = np.clip(0.5 + 0.5 * ncc, AGREEMENT_MIN, 1.0)
    return np.where(vm < FLAT_VARIANCE, 1.0, out).astype(np.float32)


@dataclass
class SurfaceMemory:
    """points (N, 3) float32 ENU m and normals (N, 3) float32 of the samples; rgb (N, 3) uint8,
    seen (N,) bool, time (N,) float64 (NaN unseen), quality (N,) float32 (0 unseen) as painted;
    with a history (t0, t1, epochs): history_rgb (N, E, 3) uint8 and history_dt (N, E) float32
    (s after the epoch's start, NaN none) of each sample's newest sighting in each epoch;
    frames: how many frames painted something."""

    points: np.ndarray
    normals: np.ndarray
    rule: str = "newest"
    history: tuple[float, float, int] | None = None
    rgb: np.ndarray = field(init=False)
    seen: np.ndarray = field(init=False)
    time: np.ndarray = field(init=False)
    quality: np.ndarray = field(init=False)
    history_rgb: np.ndarray | None = field(init=False)
    history_dt: np.ndarray | None = field(init=False)
    frames: int = 0

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise ValueError(f"rule {self.rule!r}: expected one of {', '.join(RULES)}")
        self.points = np.ascontiguousarray(self.points, np.float32)
        self.normals = np.ascontiguousarray(self.normals, np.float32)
        n = len(self.points)
        self.rgb = np.zeros((n, 3), np.uint8)
        self.seen = np.zeros(n, bool)
        self.time = np.full(n, np.nan)
        self.quality = np.zeros(n, np.float32)
        self.history_rgb = self.history_dt = None
        if self.history is not None:
            t0, t1, epochs = self.history
            if not (t1 >= t0 and epochs >= 1):
                raise ValueError(f"history {self.history}: expected t0 <= t1 and epochs >= 1")
            self.history_rgb = np.zeros((n, epochs, 3), np.uint8)
            self.history_dt = np.full((n, epochs), np.nan, np.float32)
        starts = np.arange(0, n, BLOCK)
        self._starts = starts
        self._lo = np.array([self.points[s : s + BLOCK].min(axis=0) for s in starts]).reshape(-1, 3)
        self._hi = np.array([self.points[s : s + BLOCK].max(axis=0) for s in starts]).reshape(-1, 3)

    @property
    def nbytes(self) -> int:
        """Bytes held, whatever the number of frames painted."""
        arrays = (self.points, self.normals, self.rgb, self.seen, self.time, self.quality)
        kept = () if self.history is None else (self.history_rgb, self.history_dt)
        return sum(a.nbytes for a in (*arrays, *kept)) + self._lo.nbytes + self._hi.nbytes

    def epoch_starts(self) -> np.ndarray:
        """(E,) s: where each epoch of the history begins."""
        t0, t1, epochs = self.history
        return t0 + (t1 - t0) * np.arange(epochs) / epochs

    def _epoch(self, time_s: float) -> int:
        t0, t1, epochs = self.history
        return int(np.clip((time_s - t0) / max(t1 - t0, 1e-9) * epochs, 0, epochs - 1))

    def _in_view(self, camera: Camera) -> np.ndarray:
        """Indices of the samples in the blocks the camera's frustum meets."""
        inside = boxes_in_frustum(camera, self._lo, self._hi)
        n = len(self.points)
        blocks = [np.arange(s, min(s + BLOCK, n)) for s in self._starts[inside]]
        return np.concatenate(blocks) if blocks else np.zeros(0, np.int64)

    def _pinhole_samples(self, idx, frame_hw, camera, distances, agreement, sigmas):
        """What `_samples` gives, for a lensless camera, in one compiled pass."""
        h, w = frame_hw
        iw, ih = image_size(camera)
        i = camera.intrinsics
        dh, dw = distances.shape
        keep, uv, quality = _pinhole_visible(
            self.points,
            self.normals,
            idx,
            rotations.to_matrix(camera.orientation),
            np.asarray(camera.position, np.float64),
            (i.fx, i.fy, i.cx, i.cy, w / iw, h / ih),
            (float(w), float(h)),
            (dw / i.width, dh / i.height),
            np.ascontiguousarray(distances),
            np.ones((1, 1), np.float32) if agreement is None else np.ascontiguousarray(agreement),
            agreement is not None,
            (float(sigmas[0]), float(np.radians(sigmas[1]))),
        )
        return idx[keep], uv[keep], quality[keep]

    def _samples(self, idx, frame_hw, camera, distances, agreement, sigmas):
        """(indices, frame pixels (N, 2), quality (N,) float32) of the samples idx that the
        camera sees in a frame of frame_hw (h, w): inside it, not hidden behind the distance
        map's surface, facing it; any camera (a real lens through Camera.project)."""
        h, w = frame_hw
        iw, ih = image_size(camera)
        scale = (w / iw, h / ih)  # frames may be decoded smaller than the camera's image
        p = self.points[idx].astype(np.float64)
        uv, depth = camera.project(p)
        uv = uv * scale
        inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)  # fmt: skip
        idx, p, uv = idx[inside], p[inside], uv[inside]
        ray = p - np.asarray(camera.position, np.float64)
        rng = np.linalg.norm(ray, axis=1)
        # the distance map is drawn through the camera's pinhole: where does the point fall?
        pin = uv / scale if camera.lens is None else camera.pinhole().project(p)[0]
        dh, dw = distances.shape
        sx, sy = dw / camera.intrinsics.width, dh / camera.intrinsics.height
        at = [pin[:, 1] * sy - 0.5, pin[:, 0] * sx - 0.5]
        nearest = map_coordinates(distances, at, order=0, mode="nearest")
        visible = rng <= nearest + DEPTH_BIAS_M + DEPTH_BIAS_PER_M * rng
        agree = (
            np.ones(len(idx), np.float32)
            if agreement is None
            else map_coordinates(agreement, at, order=0, mode="nearest")
        )
        idx, ray, rng, uv, agree = (
            idx[visible],
            ray[visible],
            rng[visible],
            uv[visible],
            agree[visible],
        )
        cos = np.abs(np.einsum("ij,ij->i", ray, self.normals[idx])) / rng
        facing = cos >= MIN_COS_INCIDENCE
        idx, cos, rng, uv, agree = idx[facing], cos[facing], rng[facing], uv[facing], agree[facing]
        off_m = np.hypot(sigmas[0], rng * np.radians(sigmas[1]))
        quality = (
            agree * cos / (1.0 + rng / QUALITY_RANGE_M) / (1.0 + off_m / QUALITY_UNCERTAINTY_M)
        )
        return idx, uv, quality.astype(np.float32)

    def paint(
        self,
        rgb: np.ndarray,
        camera: Camera,
        distances: np.ndarray,
        time_s: float,
        agreement: np.ndarray | None = None,
        sigmas: tuple[float, float] = (0.0, 0.0),
    ) -> int:
        """Paint one frame: rgb (H, W, 3) uint8 (the camera's image, at any scale); distances
        (h, w) metres from the camera to the scene through each pixel of its pinhole
        (app.render.views, any resolution: it is scaled), inf where none; agreement (h, w) the
        frame's with the model through the same pinhole pixels (`agreement`), or None; sigmas:
        the pose's uncertainty (position m, attitude deg; app.solve.uncertainty.frame_sigmas).
        Returns the samples painted."""
        idx = self._in_view(camera)
        if not len(idx):
            return 0
        if camera.lens is None:  # the image is the pinhole's: one compiled pass
            idx, uv, quality = self._pinhole_samples(
                idx, rgb.shape[:2], camera, distances, agreement, sigmas
            )
        else:
            idx, uv, quality = self._samples(
                idx, rgb.shape[:2], camera, distances, agreement, sigmas
            )
        if not len(idx):
            return 0
        # the history keeps every sighting, so its colours are read for all; else only for the kept
        colour = self._colours(rgb, uv) if self.history is not None else None
        if colour is not None:
            self._remember(idx, colour, time_s)
        if self.rule == "first":
            take = ~self.seen[idx]
        elif self.rule == "best":
            take = quality > self.quality[idx]
        else:
            take = np.ones(len(idx), bool)
        idx, quality = idx[take], quality[take]
        self.rgb[idx] = colour[take] if colour is not None else self._colours(rgb, uv[take])
        self.seen[idx] = True
        self.time[idx] = time_s
        self.quality[idx] = quality
        self.frames += 1
        return int(len(idx))

    @staticmethod
    def _colours(rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(n, 3) uint8: the image's colours at pixel positions uv (n, 2), bilinear."""
        u, v = uv[:, 0] - 0.5, uv[:, 1] - 0.5
        colour = np.stack(
            [map_coordinates(rgb[..., c].astype(np.float32), [v, u], order=1, mode="nearest") for c in range(3)],
            axis=1,
        )  # fmt: skip
        return np.clip(np.round(colour), 0, 255).astype(np.uint8)

    def _remember(self, idx: np.ndarray, colour: np.ndarray, time_s: float) -> None:
        """A sighting into its epoch's slot, where it is the newest there."""
        e = self._epoch(time_s)
        dt = np.float32(time_s - self.epoch_starts()[e])
        stored = self.history_dt[idx, e]
        newer = ~(stored > dt)  # NaN (none yet) too
        self.history_rgb[idx[newer], e] = colour[newer]
        self.history_dt[idx[newer], e] = dt
