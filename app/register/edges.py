"""Registration by geometry: a video frame aligned with a model that has no texture (a grey mesh,
a city's LoD2 buildings, a bare DEM with relief), as pure numpy and OpenCV.

The rendered model gives no colours to match, but its shape gives lines: where the surface under
neighbouring pixels jumps in range (a silhouette, the sky line) or turns (a crease: a wall's
corner, the foot of a wall on the ground, a roof's ridge). Those lines are where the frame has
edges too. One step:

1. the model's edge pixels (`model_edges`), lifted to 3D through the rendering's position map
   (the nearer surface, carried on half a pixel to the silhouette itself), each with its line's
   normal in the image;
2. the frame's edges (Canny on a blurred grey image, `FrameEdges`), sorted into bins by their
   normal's direction, with a distance transform per bin that names each pixel's nearest edge;
3. a search over image shifts at the coarsest level for where the model's edges land on the
   frame's (the truncated chamfer distance, oriented), taken as a small turn of the camera;
4. coarse to fine over `octaves`, iterated closest points: each model point's nearest frame edge
   of a like direction within a gate, the pose moved by Gauss-Newton on the point-to-line
   distances (Tukey weights), the correspondences found again; the shift and each level's fit
   kept only where they bring the model's lines nearer the frame's edges at full size (at coarse
   levels a window row or the blur of a building's detail can pull the fit off the pose that the
   finest level's edges prefer);
5. refused where the model's lines in view leave a direction of the pose unfixed (one wall's foot
   alone fixes neither distance along it nor height), where too few points find an edge, or where
   the residual stays large.

The comparison with other ways (docs/ACCURACY.md, "Registration by geometry" and "How the lines
are matched") chose this one; the lines matched whole as segments (app.register.segments,
`EdgeSettings.lines_by`) is the measured alternative, kept as a setting.

Frames and units: poses as app.register.keyframe (ENU metres; camera -> ENU quaternions in
OpenGL's camera axes). Pixels: this project's (u right, v down, centres at half-integers) of the
frame's camera at full size unless said.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry.base import BaseGeometry

from app.camera.pinhole import Camera
from app.geodesy import rotations
from app.register.keyframe import Frame, PoseFix, Rendering, nudged, projected
from app.register.segments import FrameSegments, group_lines
from app.scene.mesh import MeshData

FloatArray = npt.NDArray[np.float64]

BINS = 6  # directions of edge normals, over 180 degrees; a point looks up its own bin


@dataclass(frozen=True)
class EdgeSettings:
    """points: model edge points used at most; depth_jump: a relative range jump between
    neighbouring pixels that is a silhouette; crease_deg: a turn of the surface normal over two
    pixels that is a crease; octaves: coarse-to-fine levels (halvings of the matching size);
    search_px: the shift search's reach at the coarsest level (matching-size pixels); gate_px:
    a model point's nearest frame edge counts within this many pixels of its level (fine_gate_px:
    in a fine step, from a pose already close); blur_px:
    the frame's blur before Canny (pixels of each level); iterations: Gauss-Newton steps a
    level; min_points: model points that must find an edge; min_found: and the fraction of
    those in view that must; max_error_px: the RMS point-to-line distance at the end (full
    frame pixels); max_std_m / max_std_deg: the pose's worst-fixed direction, as the standard
    deviation one pixel of noise on every point would give it (the edges alone, without the
    prior), above which the step is refused; prior_m / prior_deg: the starting pose's standard deviations
    (position per axis, turn per axis): the fit is the most probable pose given the edges and
    that prior, so that a direction the model's lines do not fix (along the one wall in view)
    stays where the prior put it (0: no prior); noise_px / lines: the edge points' noise, and
    how many independent measurements they are worth (points along one line share its error);
    max_move_sigmas: a fit that moved the pose more than this many prior standard deviations is
    refused; guard_px: a coarse step (the shift search, a level's fit) is kept only where it
    lowers the model points' mean distance to the frame's edges at full size, each distance
    truncated at this many of that level's pixels (0: every step kept); lines_by: "points" (each model point's nearest frame edge of a like direction) or
    "segments" (the model's lines matched whole to the frame's LSD segments,
    app.register.segments), compared in docs/ACCURACY.md."""

    points: int = 2000
    depth_jump: float = 0.04
    crease_deg: float = 30.0
    octaves: int = 3
    search_px: int = 96
    gate_px: float = 6.0
    fine_gate_px: float = 3.0
    blur_px: float = 1.2
    iterations: int = 8
    min_points: int = 60
    min_found: float = 0.85
    max_error_px: float = 2.5
    max_std_m: float = 0.1
    max_std_deg: float = 0.03
    prior_m: float = 3.0
    prior_deg: float = 1.5
    noise_px: float = 1.5
    lines: int = 30
    max_move_sigmas: float = 3.0
    guard_px: float = 2.0
    lines_by: str = "points"


def _normals_map(positions: FloatArray) -> FloatArray:
    """Unit surface normals (H, W, 3) from a position map by central differences (NaN off the
    model); their sign is irrelevant here."""
    p = positions
    dx = np.full_like(p, np.nan)
    dy = np.full_like(p, np.nan)
    dx[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dy[1:-1] = p[2:] - p[:-2]
    n = np.cross(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.linalg.norm(n, axis=2, keepdims=True)


def _line_normals(edges: np.ndarray, sigma: float = 1.5) -> FloatArray:
    """The angle (H, W) radians in [0, pi) of the normal of the line through each pixel of a
    binary edge map, from its structure tensor (the dominant direction of the map's gradients)."""
    e = cv2.GaussianBlur(edges.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(e, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(e, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), sigma)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), sigma)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), sigma)
    return np.mod(0.5 * np.arctan2(2 * jxy, jxx - jyy), np.pi).astype(np.float64)


@dataclass(frozen=True)
class ModelEdges:
    """Points on the model's lines: points (N, 3) ENU m, their rendered pixels uv (N, 2)
    (the rendering's own), the angle (N,) radians in [0, pi) of their line's normal in the
    image, and what made each (N,) 0 silhouette or sky line, 1 crease."""

    points: FloatArray
    uv: FloatArray
    angle: FloatArray
    kind: npt.NDArray[np.int8]


def model_edges(rendering: Rendering, settings: EdgeSettings = EdgeSettings()) -> ModelEdges:
    """The lines of the rendered model (`ModelEdges`): pixels on the model beside the sky or
    a farther surface (range jumps by more than depth_jump; the nearer side is kept: the
    silhouette belongs to it), and pixels where the surface normal turns by more than crease_deg
    over two pixels. At most `points` of them, spread evenly over the lines (a fixed sample).
    Where the model ends against the sky at the outline of a cut primitive (rendering.cut: a
    terrain read over a window), there is no line: the world goes on (within CUT_PX pixels'
    reach on the ground of it, and a metre at least)."""
    pos = rendering.positions
    h, w = pos.shape[:2]
    rng = np.linalg.norm(pos - np.asarray(rendering.camera.position), axis=2)
    on = np.isfinite(rng)
    log_r = np.where(on, np.log(np.where(on, rng, 1.0)), np.nan)
    sil = np.zeros((h, w), bool)
    sky_line = np.zeros((h, w), bool)
    big = np.log1p(settings.depth_jump)
    # where each silhouette pixel's boundary lies: half a pixel towards the farther side, per
    # axis (v, u), in pixels
    half = np.zeros((2, h, w))
    for axis in (0, 1):
        lr = log_r if axis == 1 else log_r.T
        d = np.diff(lr, axis=1)  # (., W - 1): between pixel j and j + 1
        sky = np.isnan(d) & (np.isfinite(lr[:, :-1]) | np.isfinite(lr[:, 1:]))
        # a smooth surface's range changes steadily along a row (a ground seen at a grazing angle
        # by a lot); a jump is a step several times its neighbours' on both sides
        pad = np.pad(np.abs(d), ((0, 0), (2, 2)), constant_values=np.nan)
        with np.errstate(invalid="ignore"):
            around = np.fmax(np.fmax(pad[:, :-4], pad[:, 1:-3]), np.fmax(pad[:, 3:-1], pad[:, 4:]))
            jump = (np.abs(d) > big) & ~(np.abs(d) < 3.0 * around)
            sky_first, sky_second = sky & np.isfinite(lr[:, :-1]), sky & np.isfinite(lr[:, 1:])
            first_near = sky_first | jump & (lr[:, :-1] < lr[:, 1:])
            second_near = sky_second | jump & (lr[:, 1:] < lr[:, :-1])
        mark = np.zeros(lr.shape, bool)
        mark[:, :-1] |= first_near
        mark[:, 1:] |= second_near
        by_sky = np.zeros(lr.shape, bool)
        by_sky[:, :-1] |= sky_first
        by_sky[:, 1:] |= sky_second
        sky_line |= by_sky if axis == 1 else by_sky.T
        toward = np.zeros(lr.shape)
        toward[:, :-1] += 0.5 * first_near
        toward[:, 1:] -= 0.5 * second_near
        sil |= mark if axis == 1 else mark.T
        half[axis] = toward if axis == 1 else toward.T
    sil &= on
    if rendering.cut is not None:
        sil &= ~_at_cut(pos, rng, sky_line & sil, rendering)
    boundary = _to_boundary(pos, log_r, half, big)
    n = _normals_map(pos)
    cos_max = np.cos(np.radians(settings.crease_deg))
    crease = np.zeros((h, w), bool)
    with np.errstate(invalid="ignore"):
        dots = np.abs(np.sum(n[:, :-2] * n[:, 2:], axis=2))
        crease[:, 1:-1] |= dots < cos_max
        dots = np.abs(np.sum(n[:-2] * n[2:], axis=2))
        crease[1:-1] |= dots < cos_max
    # a crease's normals are taken over a silhouette too: only where no range jumps near
    near_sil = cv2.dilate(sil.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    crease &= on & ~near_sil
    edges = sil | crease
    border = np.zeros((h, w), bool)
    border[2:-2, 2:-2] = True
    edges &= border  # the image's own border is no line of the model
    angle = _line_normals(edges)
    rows, cols = np.nonzero(edges)
    if len(rows) > settings.points:
        keep = np.linspace(0, len(rows) - 1, settings.points).round().astype(int)
        rows, cols = rows[keep], cols[keep]
    on_sil = sil[rows, cols]
    points = np.where(on_sil[:, None], boundary[rows, cols], pos[rows, cols])
    return ModelEdges(
        points,
        np.column_stack(
            [cols + 0.5 + on_sil * half[1, rows, cols], rows + 0.5 + on_sil * half[0, rows, cols]]
        ),
        angle[rows, cols],
        np.where(on_sil, 0, 1).astype(np.int8),
    )


CUT_PX = 3.0  # a sky line this many pixels' reach from a cut outline is the model's end


def cut_outline(mesh: MeshData) -> BaseGeometry | None:
    """Where the scene's data ends (ENU east, north m): the outline of each cut primitive
    (app.scene.mesh.Primitive.cut: a terrain read over a window, the assumed ground), the
    boundary of its vertices' convex hull; None where it has none."""
    hulls = [
        shapely.convex_hull(shapely.multipoints(p.positions[:, :2].astype(np.float64)))
        for p in mesh.primitives
        if p.cut and len(p.positions) >= 3
    ]
    return shapely.union_all([h.boundary for h in hulls]) if hulls else None


def _at_cut(
    pos: FloatArray, rng: FloatArray, sky_line: np.ndarray, rendering: Rendering
) -> np.ndarray:
    """(H, W) the pixels of `sky_line` whose surface point lies on rendering.cut (within CUT_PX
    pixels' reach on the ground at its range and sight line, a metre at least)."""
    out = np.zeros(sky_line.shape, bool)
    rows, cols = np.nonzero(sky_line)
    if not len(rows):
        return out
    xy = pos[rows, cols, :2]
    r = rng[rows, cols]
    # a pixel's reach on the ground grows as the sight line grazes it (1 / sine of its angle)
    grazing = np.maximum(np.abs(pos[rows, cols, 2] - rendering.camera.position[2]) / r, 0.05)
    tol = np.maximum(1.0, CUT_PX * r / rendering.camera.intrinsics.fx / grazing)
    out[rows, cols] = shapely.distance(shapely.points(xy), rendering.cut) <= tol
    return out


def _to_boundary(pos: FloatArray, log_r: FloatArray, half: FloatArray, big: float) -> FloatArray:
    """The position map (H, W, 3) moved, at silhouette pixels, to the silhouette itself: by
    `half` (2, H, W: v, u pixels towards the farther side) times the near surface's own step a
    pixel (taken away from the silhouette, where that neighbour lies on the same surface; else not
    moved). A silhouette lies between a near and a far pixel, half a pixel beyond the near
    pixel's centre; left there, every outline would be drawn half a pixel inside the model."""
    out = pos.copy()
    for shift, p, lr, back_t in (
        (half[1], pos, log_r, lambda a: a),
        (half[0].T, pos.transpose(1, 0, 2), log_r.T, lambda a: a.transpose(1, 0, 2)),
    ):
        # along rows of p: the step from pixel j to j + 1 where both lie on one surface
        step = p[:, 1:] - p[:, :-1]
        step[~(np.abs(lr[:, 1:] - lr[:, :-1]) < big)] = np.nan
        per_px = np.full_like(p, np.nan)
        ahead = shift[:, 1:] > 0  # the far side ahead: the step from behind
        per_px[:, 1:][ahead] = step[ahead]
        behind = shift[:, :-1] < 0  # the far side behind: the step from ahead
        per_px[:, :-1][behind] = step[behind]
        out += back_t(np.nan_to_num(shift[..., None] * per_px))
    return out


def _subpixel(mag: np.ndarray, angle: FloatArray, edges: np.ndarray) -> FloatArray:
    """Where each edge pixel's edge lies along its normal (pixels from the pixel's centre, within
    half a pixel): the peak of a parabola through the gradient magnitude at the pixel and one
    pixel either side along the normal (bilinear)."""
    h, w = mag.shape
    rows, cols = np.nonzero(edges)
    out = np.zeros((h, w))
    if not len(rows):
        return out
    c, s = np.cos(angle[rows, cols]), np.sin(angle[rows, cols])
    m = mag.astype(np.float32)
    map_x = np.stack([cols - c, cols, cols + c]).astype(np.float32)[:, :, None]
    map_y = np.stack([rows - s, rows, rows + s]).astype(np.float32)[:, :, None]
    before, here, after = cv2.remap(m, map_x.reshape(3, -1), map_y.reshape(3, -1), cv2.INTER_LINEAR)
    curve = before - 2 * here + after
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where(curve < 0, 0.5 * (before - after) / curve, 0.0)
    out[rows, cols] = np.clip(np.nan_to_num(off), -0.5, 0.5)
    return out


def _bin_of(angle: npt.ArrayLike) -> npt.NDArray[np.int64]:
    return np.round(np.asarray(angle) / (np.pi / BINS)).astype(np.int64) % BINS


class FrameEdges:
    """A frame's edges at one level: Canny on its grey image blurred by blur_px, each edge
    pixel's gradient direction; per direction bin (BINS over 180 degrees, each holding the edges
    within one bin of its centre) the distance to, and the coordinates of, the nearest edge.
    factor: this level's pixels per full-size frame pixel."""

    def __init__(self, rgb: np.ndarray, factor: float, blur_px: float) -> None:
        self.factor = factor
        g = cv2.GaussianBlur(rgb.astype(np.float32), (0, 0), blur_px)
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
        # the colour channel with the strongest gradient at each pixel (a cream wall against a
        # pale blue sky differs in hue far more than in grey)
        strongest = np.argmax(gx * gx + gy * gy, axis=2)[..., None]
        gx = np.take_along_axis(gx, strongest, axis=2)[..., 0]
        gy = np.take_along_axis(gy, strongest, axis=2)[..., 0]
        mag = np.hypot(gx, gy)
        high = float(np.percentile(mag, 90))
        # Canny on the gradients found here (its 16-bit derivative form)
        dx = np.clip(gx, -32767, 32767).astype(np.int16)
        dy = np.clip(gy, -32767, 32767).astype(np.int16)
        edges = cv2.Canny(dx, dy, 0.4 * high, high, L2gradient=True) > 0
        self.edges = edges
        self.angle = np.mod(np.arctan2(gy, gx), np.pi).astype(np.float64)
        self.shape = edges.shape
        self.subpixel = _subpixel(mag, self.angle, edges)
        bins = _bin_of(self.angle)
        self.dist: list[np.ndarray] = []
        self.nearest: list[np.ndarray] = []  # (H, W) flat index of the nearest edge pixel
        for b in range(BINS):
            near_b = ((bins == b) | (bins == (b + 1) % BINS) | (bins == (b - 1) % BINS)) & edges
            src = np.where(near_b, 0, 255).astype(np.uint8)
            if not near_b.any():
                self.dist.append(np.full(self.shape, np.inf, np.float32))
                self.nearest.append(np.zeros(self.shape, np.int64))
                continue
            dist, labels = cv2.distanceTransformWithLabels(
                src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
            )
            # labels number the zero pixels in raster order, from 1
            flat = np.flatnonzero(near_b.ravel())
            self.dist.append(dist)
            self.nearest.append(flat[np.maximum(labels, 1) - 1])

    def lookup(
        self, uv: FloatArray, angle: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """For full-size pixels uv (N, 2) of lines whose normals have `angle` (N,): the nearest
        frame edge of a like direction (full-size pixels (N, 2)), its unit normal (N, 2), and the
        distance to it in this level's pixels (inf outside the image)."""
        h, w = self.shape
        c = np.floor(uv[:, 0] * self.factor).astype(np.int64)
        r = np.floor(uv[:, 1] * self.factor).astype(np.int64)
        inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
        c, r = np.clip(c, 0, w - 1), np.clip(r, 0, h - 1)
        bins = _bin_of(angle)
        idx = np.zeros(len(uv), np.int64)
        dist = np.full(len(uv), np.inf)
        for b in range(BINS):
            sel = bins == b
            idx[sel] = self.nearest[b][r[sel], c[sel]]
            dist[sel] = self.dist[b][r[sel], c[sel]]
        dist[~inside] = np.inf
        er, ec = np.divmod(idx, w)
        a = self.angle[er, ec]
        n = np.column_stack([np.cos(a), np.sin(a)])
        q = (np.column_stack([ec + 0.5, er + 0.5]) + n * self.subpixel[er, ec, None]) / self.factor
        return q, n, dist


def _moved(camera: Camera, x: FloatArray) -> Camera:
    """The camera turned by x[:3] (rad, ENU) and moved by x[3:] (ENU m): the fit's six
    parameters (app.register.keyframe.nudged)."""
    return nudged(camera, x[:3], x[3:])


_STEPS = np.array([1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-3])  # rad, rad, rad, m, m, m


def _jacobian(camera: Camera, points: FloatArray, normals: FloatArray) -> FloatArray:
    """d(normal . uv)/d(pose) (N, 6) by central differences, pixels per rad and per m."""
    cols = []
    for k, h in enumerate(_STEPS):
        dx = np.zeros(6)
        dx[k] = h
        plus, _ = _moved(camera, dx).project(points)
        minus, _ = _moved(camera, -dx).project(points)
        cols.append(np.sum(normals * (plus - minus), axis=1) / (2 * h))
    return np.column_stack(cols)


def _tukey(r: FloatArray, c: float) -> FloatArray:
    w = (1 - (r / c) ** 2) ** 2
    return np.where(np.abs(r) < c, w, 0.0)


def _search_shift(camera: Camera, edges: ModelEdges, level: FrameEdges, reach_px: float) -> Camera:
    """The camera turned so that the model's edges land where the image shift (searched over
    +-reach_px full-size pixels) puts most of them near frame edges of a like direction
    (truncated chamfer distance)."""
    uv, ok = projected(camera, edges.points)
    if ok.sum() < 10:
        return camera
    uv, angle = uv[ok], edges.angle[ok]
    step = 2.0 / level.factor  # two of the level's pixels
    shifts = np.arange(-reach_px, reach_px + step / 2, step)
    h, w = level.shape
    bins = _bin_of(angle)
    truncate = 4.0
    best, best_cost = (0.0, 0.0), np.inf
    for dy in shifts:
        r = np.floor((uv[:, 1] + dy) * level.factor).astype(np.int64)
        for dx in shifts:
            c = np.floor((uv[:, 0] + dx) * level.factor).astype(np.int64)
            inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
            cost = np.full(len(uv), truncate)
            for b in range(BINS):
                sel = inside & (bins == b)
                cost[sel] = np.minimum(level.dist[b][r[sel], c[sel]], truncate)
            total = float(cost.mean())
            if total < best_cost - 1e-9 or (
                abs(total - best_cost) <= 1e-9 and dx * dx + dy * dy < best[0] ** 2 + best[1] ** 2
            ):
                best, best_cost = (float(dx), float(dy)), total
    if best == (0.0, 0.0):
        return camera
    # the shift as a turn: the ray through the image centre moved to where it lands shifted
    centre = np.array([[camera.intrinsics.cx, camera.intrinsics.cy]])
    a = camera.pixel_rays(centre)[0]
    b = camera.pixel_rays(centre + np.array(best))[0]
    axis = np.cross(b, a)
    angle_rad = np.arctan2(np.linalg.norm(axis), float(a @ b))
    if np.linalg.norm(axis) < 1e-12:
        return camera
    return _moved(camera, np.concatenate([axis / np.linalg.norm(axis) * angle_rad, np.zeros(3)]))


@dataclass(frozen=True)
class EdgeFit:
    """The outcome of aligning the model's lines with the frame's edges: the camera, the model
    points that found an edge (of those in view), the RMS point-to-line distance over them (full
    frame pixels) and the standard deviations (m, deg) of the pose's worst-fixed position and
    turn for one pixel of noise a point."""

    camera: Camera
    found: int
    in_view: int
    error_px: float
    std_m: float
    std_deg: float


def _offset(camera: Camera, prior: Camera) -> FloatArray:
    """The pose of `camera` against `prior` as (rotation vector (rad, ENU), move (ENU m))."""
    turn = rotations.multiply(
        np.asarray(camera.orientation), rotations.conjugate(np.asarray(prior.orientation))
    )
    return np.concatenate(
        [
            rotations.to_scipy(turn).as_rotvec(),
            np.asarray(camera.position) - np.asarray(prior.position),
        ]
    )


def _pairs(
    camera: Camera, gate: float, edges: ModelEdges, level: FrameEdges
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], FloatArray, FloatArray]:
    """Each model point's nearest frame edge of a like direction: (which found one within
    `gate` of the level's pixels, which are in view; for those found: the edges' normals (M, 2)
    and the signed point-to-line distances (M,) in full-size pixels)."""
    uv, in_view = projected(camera, edges.points)
    q, nq, dist = level.lookup(np.where(in_view[:, None], uv, -1.0), edges.angle)
    found = in_view & (dist <= gate)
    return found, in_view, nq[found], np.sum(nq[found] * (uv[found] - q[found]), axis=1)


Pairs = Callable[
    [Camera, float], tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], FloatArray, FloatArray]
]


def _fit_level(
    camera: Camera,
    edges: ModelEdges,
    pairs: Pairs,
    factor: float,
    settings: EdgeSettings,
    gate: float,
    prior: Camera,
) -> EdgeFit:
    if settings.prior_m > 0:
        inv_prior = np.diag(
            [1 / np.radians(settings.prior_deg) ** 2] * 3 + [1 / settings.prior_m**2] * 3
        )
    else:
        inv_prior = np.zeros((6, 6))
    for _ in range(settings.iterations):
        found, in_view, n, r = pairs(camera, gate)
        if found.sum() < 6:
            return EdgeFit(camera, int(found.sum()), int(in_view.sum()), np.inf, np.inf, np.inf)
        p = edges.points[found]
        wts = _tukey(r * factor, gate)
        jac = _jacobian(camera, p, n)
        k = settings.lines / (max(1.0, float(wts.sum())) * settings.noise_px**2)
        a = k * jac.T @ (wts[:, None] * jac) + inv_prior
        g = k * jac.T @ (wts * r) + inv_prior @ _offset(camera, prior)
        damp = 1e-6 * np.trace(a) / 6 + 1e-9
        try:
            dx = -np.linalg.solve(a + damp * np.eye(6), g)
        except np.linalg.LinAlgError:
            break
        camera = _moved(camera, dx)
        if np.all(np.abs(dx) < _STEPS):
            break
    return _assessed(camera, edges, pairs, gate)


def _assessed(camera: Camera, edges: ModelEdges, pairs: Pairs, gate: float) -> EdgeFit:
    """The EdgeFit of `camera` as it stands: its pairs within `gate`, their RMS distance and how
    well they fix the pose."""
    found, in_view, n, r = pairs(camera, gate)
    if found.sum() < 6:
        return EdgeFit(camera, int(found.sum()), int(in_view.sum()), np.inf, np.inf, np.inf)
    jac = _jacobian(camera, edges.points[found], n)
    std_m, std_deg = _worst_std(jac)
    return EdgeFit(
        camera,
        int(found.sum()),
        int(in_view.sum()),
        float(np.sqrt(np.mean(r**2))),
        std_m,
        std_deg,
    )


def _worst_std(jac: FloatArray) -> tuple[float, float]:
    """(m, deg): the largest standard deviation of the position's and of the turn's components
    (any direction) for unit noise on every residual, from the normal equations' inverse."""
    a = jac.T @ jac
    try:
        cov = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return np.inf, np.inf
    if not np.all(np.isfinite(cov)):
        return np.inf, np.inf
    turn = np.sqrt(max(0.0, float(np.linalg.eigvalsh(cov[:3, :3])[-1])))
    move = np.sqrt(max(0.0, float(np.linalg.eigvalsh(cov[3:, 3:])[-1])))
    return move, float(np.degrees(turn))


def _chamfer(camera: Camera, edges: ModelEdges, level: FrameEdges, truncate: float) -> float:
    """The model points' mean distance (the level's pixels, each truncated at `truncate`) to the
    nearest frame edge of a like direction, over the points in view under `camera` (inf when
    none is)."""
    uv, in_view = projected(camera, edges.points)
    if not in_view.any():
        return np.inf
    _, _, dist = level.lookup(uv[in_view], edges.angle[in_view])
    return float(np.mean(np.minimum(dist, truncate)))


def _pyramid(image: np.ndarray, octaves: int) -> list[np.ndarray]:
    levels = [image]
    for _ in range(octaves - 1):
        levels.append(cv2.pyrDown(levels[-1]))
    return levels


def fit_edges(
    frame: Frame,
    rendering: Rendering,
    settings: EdgeSettings = EdgeSettings(),
    search: bool = True,
    prior: Camera | None = None,
) -> tuple[PoseFix, EdgeFit | None]:
    """One step of registration by geometry (module docstring): the frame's camera aligned so
    that the rendered model's lines fall on the frame's edges. search: begin with the shift
    search (the coarse step; False: a fine step from a pose already close, finest level only);
    prior: the pose the prior gives (default: the frame's camera), which the fit is held to
    within prior_m and prior_deg.
    Returns the fix (matches: model points in view, inliers: those that found an edge) and the
    fit (None where the model shows no lines)."""
    edges = model_edges(rendering, settings)
    if len(edges.points) < settings.min_points:
        return PoseFix(
            False,
            f"the model shows too few lines to register by ({len(edges.points)} edge points, need {settings.min_points})",
            len(edges.points),
            0,
            float("nan"),
        ), None
    pyramid = _pyramid(frame.rgb, settings.octaves)
    levels = range(settings.octaves - 1, -1, -1) if search else [0]
    labels = group_lines(edges.uv, edges.angle) if settings.lines_by == "segments" else None
    guard = search and settings.guard_px > 0
    finest = FrameEdges(pyramid[0], frame.scale, settings.blur_px) if guard else None

    def kept(moved: Camera, camera: Camera, factor: float) -> Camera:
        """A coarse step's pose where it brings the lines nearer the finest level's edges (or
        with no guard), else the pose before it; the distances truncated at guard_px of the
        step's own level, so that a step from far off is judged within its reach."""
        if finest is None:
            return moved
        truncate = settings.guard_px * finest.factor / factor
        before, after = (_chamfer(c, edges, finest, truncate) for c in (camera, moved))
        return moved if after < before else camera

    camera, fit = frame.camera, None
    for i, lvl in enumerate(levels):
        img = pyramid[lvl]
        factor = frame.scale * img.shape[1] / frame.rgb.shape[1]
        shift = search and i == 0
        # the frame's edges serve the shift search and the point-by-point pairs
        level = None
        if shift or labels is None:
            level = (
                finest
                if lvl == 0 and finest is not None
                else FrameEdges(img, factor, settings.blur_px)
            )
        if shift:
            turned = _search_shift(camera, edges, level, settings.search_px / frame.scale)
            camera = kept(turned, camera, factor)
        if labels is None:
            pairs: Pairs = partial(_pairs, edges=edges, level=level)
        else:
            pairs = partial(FrameSegments(img, factor).pairs, points=edges.points, labels=labels)
        gate = settings.gate_px if search else settings.fine_gate_px
        fit = _fit_level(camera, edges, pairs, factor, settings, gate, prior or frame.camera)
        camera = kept(fit.camera, camera, factor)
    assert fit is not None
    if fit.camera is not camera:  # the last level's fit was not kept: the pose as it stands
        fit = _assessed(camera, edges, pairs, gate)
    return _judged(fit, settings, prior or frame.camera), fit


def _judged(fit: EdgeFit, settings: EdgeSettings, prior: Camera) -> PoseFix:
    """The fit as a PoseFix: refused (with the reason) unless enough points found an edge, the
    residual is small, every direction of the pose is fixed and the pose stayed within
    max_move_sigmas of the prior."""
    nan = float("nan")
    reason = ""
    offset = _offset(fit.camera, prior)
    moved_deg = float(np.degrees(np.linalg.norm(offset[:3])))
    moved_m = float(np.linalg.norm(offset[3:]))
    k = settings.max_move_sigmas
    if fit.found < settings.min_points:
        reason = f"{fit.found} model edge points found a frame edge (need {settings.min_points})"
    elif fit.found < settings.min_found * fit.in_view:
        reason = f"only {fit.found} of {fit.in_view} model edge points found a frame edge"
    elif not fit.error_px <= settings.max_error_px:
        reason = f"edge distance {fit.error_px:.1f} px (at most {settings.max_error_px})"
    elif fit.std_m > settings.max_std_m or fit.std_deg > settings.max_std_deg:
        reason = (
            f"the model's lines in view leave the pose unfixed ({fit.std_m:.2f} m, "
            f"{fit.std_deg:.2f} deg a pixel)"
        )
    elif settings.prior_m > 0 and (
        moved_m > k * settings.prior_m or moved_deg > k * settings.prior_deg
    ):
        reason = (
            f"the lines moved the pose {moved_m:.1f} m and {moved_deg:.1f} deg from its prior "
            f"(at most {k * settings.prior_m:.0f} m and {k * settings.prior_deg:.1f} deg)"
        )
    if reason:
        return PoseFix(False, reason, fit.in_view, fit.found, fit.error_px if fit.found else nan)
    c = fit.camera
    return PoseFix(
        True,
        "",
        fit.in_view,
        fit.found,
        fit.error_px,
        np.asarray(c.position),
        np.asarray(c.orientation),
    )
