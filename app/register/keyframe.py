"""One keyframe's registration against the scene, as pure numpy and OpenCV: match the video frame
with a rendering of the model from the current pose estimate, lift the rendering's matched
pixels to 3D through its position map, and solve the camera's absolute pose robustly (RANSAC on
SQPnP, then Levenberg-Marquardt on the inliers).

Frames and units: world = ENU metres; a pose is the camera's position (ENU m) and its camera ->
ENU quaternion in OpenGL's camera axes (x right, y up, looking down -z), as app.camera.pinhole.Camera.
OpenCV's camera axes (x right, y down, z forward) appear only inside this module. Pixels: u right,
v down from the top-left corner, pixel centres at half-integers (app.camera.pinhole).

The matcher was chosen by measurement (docs/ACCURACY.md, "Registration"): SIFT with Lowe's ratio
test and a mutual check; the rendering and the frame are compared in grey after a local contrast
normalisation (CLAHE), which absorbs the exposure and white-balance differences between a model's
textures and the day the video was taken.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt
from shapely.geometry.base import BaseGeometry

from app.camera.pinhole import Camera
from app.geodesy import rotations

FloatArray = npt.NDArray[np.float64]

# OpenGL camera axes -> OpenCV camera axes (and back: the matrix is its own inverse).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class MatchSettings:
    """detector: "sift" or "orb" (the coarse step's features; docs/ACCURACY.md compares them;
    OpenCV 5's main modules have no AKAZE); features: features per image (SIFT, ORB); ratio: Lowe's ratio test; edge_m_per_m: a rendered
    pixel is lifted to 3D only where its 3x3 neighbourhood's depths agree within this fraction
    of its range (occlusion edges, where a match may belong to either surface, are dropped);
    ransac_px: RANSAC's inlier threshold, pixels of the frame; min_inliers: fewer is a failure;
    max_error_px: an RMS reprojection error over the inliers above this is a failure;
    refine_corners / refine_px / refine_window: corners tracked, the inlier threshold (frame
    pixels) and Lucas-Kanade's window (pixels a side; 13 tracks as well as 21 where the pose is
    within a few pixels, at 0.4 of the cost: docs/PERFORMANCE.md, "Orthophotos") of the fine
    step (`refine`); align_finest_octave: the dense alignment (`align`) stops this many
    halvings above the rendering's size (1: half size; its pose is a coarse one, which the fine
    step that follows brings to the full size's pixel, and the full size's ECC cost three
    quarters of the alignment's time; 0 where coarse steps alone give the pose)."""

    detector: str = "sift"
    features: int = 3000
    ratio: float = 0.85
    edge_m_per_m: float = 0.02
    ransac_px: float = 3.0
    min_inliers: int = 15
    max_error_px: float = 2.5
    refine_corners: int = 4000
    refine_px: float = 1.5
    refine_window: int = 13
    align_finest_octave: int = 1


@dataclass(frozen=True)
class PoseFix:
    """The outcome of one render-and-compare step: ok with the solved pose, or not with the
    reason. matches: putative matches lifted to 3D; inliers: RANSAC inliers; error_px: RMS
    reprojection error of the inliers at the refined pose (frame pixels)."""

    ok: bool
    reason: str
    matches: int
    inliers: int
    error_px: float
    position: FloatArray | None = None
    q: FloatArray | None = None


_CLAHE = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))


def grey(rgb: np.ndarray) -> np.ndarray:
    """An RGB image (H, W, 3) uint8 as contrast-normalised grey (H, W) uint8."""
    return _CLAHE.apply(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


class Matcher:
    """Features (SIFT by default) and mutual ratio-test matching between a video frame and a
    rendering."""

    def __init__(self, settings: MatchSettings = MatchSettings()) -> None:
        self.settings = settings
        if settings.detector == "sift":
            self.detector, norm = cv2.SIFT_create(nfeatures=settings.features), cv2.NORM_L2
        elif settings.detector == "orb":
            self.detector, norm = cv2.ORB_create(nfeatures=settings.features), cv2.NORM_HAMMING
        else:
            raise ValueError(f"detector must be sift or orb, got {settings.detector!r}")
        self.matcher = cv2.BFMatcher(norm)

    def features(
        self, rgb: np.ndarray, mask: np.ndarray | None = None
    ) -> tuple[FloatArray, np.ndarray | None]:
        """(keypoints (N, 2) in OpenCV's pixel convention (from_opencv converts them);
        descriptors (N, D) or None)."""
        kps, desc = self.detector.detectAndCompute(
            grey(rgb), None if mask is None else mask.astype(np.uint8)
        )
        return np.array([k.pt for k in kps], np.float64).reshape(-1, 2), desc

    def match(self, desc_a: np.ndarray | None, desc_b: np.ndarray | None) -> npt.NDArray[np.int64]:
        """(M, 2) index pairs (into a, into b) passing the ratio test both ways."""
        if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
            return np.zeros((0, 2), np.int64)
        ab = self.matcher.knnMatch(desc_a, desc_b, k=2)
        ba = self.matcher.knnMatch(desc_b, desc_a, k=2)
        r = self.settings.ratio
        best_ba = {
            m[0].queryIdx: m[0].trainIdx
            for m in ba
            if len(m) == 2 and m[0].distance < r * m[1].distance
        }
        pairs = [
            (m[0].queryIdx, m[0].trainIdx)
            for m in ab
            if len(m) == 2
            and m[0].distance < r * m[1].distance
            and best_ba.get(m[0].trainIdx) == m[0].queryIdx
        ]
        return np.array(pairs, np.int64).reshape(-1, 2)


def from_opencv(pts: npt.ArrayLike, scale: float = 1.0) -> FloatArray:
    """OpenCV image points (N, 2), whose pixel (c, r) has its centre at (c, r), as this project's
    pixel coordinates (centres at half-integers) of the image `scale` times larger than theirs
    (scale: the image they were found in over the full-size one)."""
    return (np.asarray(pts, np.float64).reshape(-1, 2) + 0.5) / scale


def lift(
    uv: FloatArray, positions: FloatArray, eye: npt.ArrayLike, edge_m_per_m: float
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Model points (N, 3) ENU m under rendered pixels uv (N, 2), interpolated bilinearly in the
    position map (H, W, 3; its texel (r, c) holds the surface at pixel centre (c + 0.5, r + 0.5))
    of a camera at `eye`; and which are usable: on a surface, with all 3x3 neighbours on it and
    their ranges within edge_m_per_m of the pixel's own (no interpolation across an edge)."""
    h, w = positions.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0.0, w - 1.001)
    y = np.clip(uv[:, 1] - 0.5, 0.0, h - 1.001)
    col = np.clip(np.floor(x).astype(int), 1, w - 3)
    row = np.clip(np.floor(y).astype(int), 1, h - 3)
    fx = np.clip(x - col, 0.0, 1.0)[:, None]
    fy = np.clip(y - row, 0.0, 1.0)[:, None]
    rng = np.linalg.norm(positions - np.asarray(eye, np.float64), axis=2)
    centre = rng[row, col]
    spread = np.zeros(len(uv))
    for dr in (-1, 0, 1, 2):
        for dc in (-1, 0, 1, 2):
            spread = np.fmax(spread, np.abs(rng[row + dr, col + dc] - centre))
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(spread) & np.isfinite(centre) & (spread <= edge_m_per_m * centre)
    p = positions
    top = p[row, col] * (1 - fx) + p[row, col + 1] * fx
    bottom = p[row + 1, col] * (1 - fx) + p[row + 1, col + 1] * fx
    return top * (1 - fy) + bottom * fy, usable


@dataclass(frozen=True)
class Frame:
    """A video frame to register: rgb (H, W, 3) uint8, `scale` times the size of `camera`'s
    image (matching runs on smaller frames); camera: its intrinsics and lens, the pose to refine."""

    rgb: np.ndarray
    scale: float
    camera: Camera


@dataclass(frozen=True)
class Rendering:
    """The model seen by `camera` (a pinhole): colours (H, W, 3) uint8 and the surface positions
    (H, W, 3) ENU m under each pixel (NaN: none); cut: where the model's data ends (the outlines
    of its cut primitives, app.register.edges.cut_outline; None: nowhere)."""

    rgb: np.ndarray
    positions: FloatArray
    camera: Camera
    cut: BaseGeometry | None = None

    def lift(self, uv: FloatArray, edge_m_per_m: float) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        """Model points under rendered pixels uv (N, 2), and which are usable (`lift`)."""
        return lift(uv, self.positions, self.camera.position, edge_m_per_m)


def normalised(camera: Camera, uv: FloatArray) -> FloatArray:
    """Image pixels (N, 2) of `camera` (through its lens, if any) -> OpenCV normalised image
    coordinates (N, 2): x right, y down, at unit depth."""
    if camera.lens is not None:
        return np.asarray(camera.lens.undistort(uv), np.float64)
    i = camera.intrinsics
    return np.column_stack([(uv[:, 0] - i.cx) / i.fx, (uv[:, 1] - i.cy) / i.fy])


def pose_to_cv(position: npt.ArrayLike, q: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A camera pose (ENU m, camera -> ENU quaternion in OpenGL axes) as OpenCV's (rvec, tvec)
    of the world -> OpenCV-camera transform."""
    r_wc = GL_TO_CV @ rotations.to_matrix(q).T
    t = -r_wc @ np.asarray(position, np.float64)
    return cv2.Rodrigues(r_wc)[0].ravel(), t


def pose_from_cv(rvec: npt.ArrayLike, tvec: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """OpenCV's world -> camera (rvec, tvec) as (position ENU m, camera -> ENU quaternion in
    OpenGL axes)."""
    r_wc = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    position = -r_wc.T @ np.asarray(tvec, np.float64).ravel()
    return position, rotations.from_matrix(r_wc.T @ GL_TO_CV)


def posed(camera: Camera, position: npt.ArrayLike, q: npt.ArrayLike) -> Camera:
    """The camera (its intrinsics, lens and the rest) at another pose: position ENU m,
    camera -> ENU quaternion."""
    return replace(
        camera,
        position=tuple(map(float, np.asarray(position, np.float64))),
        orientation=tuple(map(float, rotations.canonical(q))),
    )


def nudged(camera: Camera, rotvec: npt.ArrayLike, shift: npt.ArrayLike) -> Camera:
    """The camera turned about its own centre by rotvec (rad, ENU axes) and moved by shift
    (ENU m)."""
    q = rotations.multiply(rotations.from_rotvec(rotvec), np.asarray(camera.orientation))
    return posed(camera, np.asarray(camera.position) + np.asarray(shift, np.float64), q)


def projected(camera: Camera, points: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Where `camera` projects points (N, 3) ENU m: their pixels (N, 2) and which (N,) lie in
    front of it with finite pixels."""
    uv, depth = camera.project(points)
    return uv, (depth > 0) & np.all(np.isfinite(uv), axis=1)


def reprojection_px(camera: Camera, points: FloatArray, uv: FloatArray) -> FloatArray:
    """Distances (N,) in pixels between uv and where `camera` (lens included) projects points."""
    proj, depth = camera.project(points)
    d = np.linalg.norm(proj - uv, axis=1)
    return np.where(depth > 0, d, np.inf)


def solve_pose(
    camera: Camera, points: FloatArray, uv: FloatArray, settings: MatchSettings = MatchSettings()
) -> PoseFix:
    """The pose of `camera` (its intrinsics and lens; its pose is only the starting point) that
    sees model points (N, 3) ENU m at frame pixels uv (N, 2): RANSAC over SQPnP minimal sets,
    then Levenberg-Marquardt on the inliers."""
    n = len(points)
    if n < settings.min_inliers:
        return PoseFix(
            False, f"{n} matches on the model (need {settings.min_inliers})", n, 0, float("nan")
        )
    xy = normalised(camera, uv)
    f = max(camera.intrinsics.fx, camera.intrinsics.fy)
    # Coordinates relative to the current camera position keep the solver well conditioned.
    origin = np.asarray(camera.position, np.float64)
    obj = np.ascontiguousarray(points - origin)
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            obj, np.ascontiguousarray(xy), np.eye(3), None, iterationsCount=500, reprojectionError=settings.ransac_px / f,
            confidence=0.999, flags=cv2.SOLVEPNP_SQPNP,
        )  # fmt: skip
    except cv2.error as exc:  # SQPnP refuses some degenerate minimal sets
        return PoseFix(False, f"the matches give no pose ({exc.err})", n, 0, float("nan"))
    if not ok or inl is None or len(inl) < settings.min_inliers:
        found = 0 if inl is None else len(inl)
        return PoseFix(
            False,
            f"{found} of {n} matches agree on a pose (need {settings.min_inliers})",
            n,
            found,
            float("nan"),
        )
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(
        obj[inl], np.ascontiguousarray(xy[inl]), np.eye(3), None, rvec, tvec
    )
    position, q = pose_from_cv(rvec, tvec)
    solved = Camera.create(
        camera.intrinsics, position + origin, q, camera.near, camera.far, camera.lens
    )
    err = reprojection_px(solved, points[inl], uv[inl])
    rms = float(np.sqrt(np.mean(err**2)))
    if not np.isfinite(rms) or rms > settings.max_error_px:
        return PoseFix(
            False,
            f"reprojection error {rms:.1f} px (at most {settings.max_error_px})",
            n,
            len(inl),
            rms,
        )
    return PoseFix(
        True, "", n, len(inl), rms, np.asarray(solved.position), np.asarray(solved.orientation)
    )


def refine(settings: MatchSettings, frame: Frame, rendering: Rendering) -> PoseFix:
    """A fine step once the pose is close (a few pixels): corners of the rendering tracked into
    the frame by pyramidal Lucas-Kanade (sub-pixel, many more and better spread than the SIFT
    matches, the ground included), kept where tracking back returns within half a pixel, lifted
    and solved as in `compare`."""
    g_r, g_f = grey(rendering.rgb), grey(frame.rgb)
    on_model = np.isfinite(rendering.positions[..., 0]).astype(np.uint8) * 255
    corners = cv2.goodFeaturesToTrack(g_r, settings.refine_corners, 0.002, 4, mask=on_model)
    if corners is None or len(corners) < settings.min_inliers:
        return PoseFix(False, "too few corners on the rendered model to refine", 0, 0, float("nan"))
    lk = dict(
        winSize=(settings.refine_window, settings.refine_window),
        maxLevel=3,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
    )
    fwd, ok1, _ = cv2.calcOpticalFlowPyrLK(g_r, g_f, corners, None, **lk)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(g_f, g_r, fwd, None, **lk)
    good = (
        (ok1.ravel() == 1)
        & (ok2.ravel() == 1)
        & (np.linalg.norm((back - corners)[:, 0], axis=1) < 0.5)
    )
    uv_r = from_opencv(corners[good, 0])
    uv_f = from_opencv(fwd[good, 0], frame.scale)
    points, usable = rendering.lift(uv_r, settings.edge_m_per_m)
    return solve_pose(
        frame.camera, points[usable], uv_f[usable], replace(settings, ransac_px=settings.refine_px)
    )


def compare(matcher: Matcher, frame: Frame, rendering: Rendering) -> PoseFix:
    """One render-and-compare step (the coarse one): features of the frame matched with those of
    the rendering, lifted and solved for the frame's camera; where that fails, the two aligned
    densely (`align`)."""
    uv_f, desc_f = matcher.features(frame.rgb)
    uv_f = from_opencv(uv_f, frame.scale)
    on_model = np.isfinite(rendering.positions[..., 0])
    if on_model.mean() < 0.05:
        return PoseFix(False, "the rendered view holds almost no model (sky)", 0, 0, float("nan"))
    uv_r, desc_r = matcher.features(rendering.rgb, mask=on_model * 255)
    uv_r = from_opencv(uv_r)
    pairs = matcher.match(desc_f, desc_r)
    if len(pairs) == 0:
        dense = align(matcher.settings, frame, rendering)
        if dense.ok:
            return dense
        return PoseFix(
            False,
            f"no matches ({len(uv_f)} features in the frame, {len(uv_r)} in the rendering)",
            0,
            0,
            float("nan"),
        )
    points, usable = rendering.lift(uv_r[pairs[:, 1]], matcher.settings.edge_m_per_m)
    step = solve_pose(frame.camera, points[usable], uv_f[pairs[usable, 0]], matcher.settings)
    if step.ok:
        return step
    dense = align(matcher.settings, frame, rendering)
    return dense if dense.ok else step


ALIGN_OCTAVES = 4  # the alignment runs coarse to fine over this many halvings of the image
ALIGN_STEP_PX = 12  # the grid of rendered pixels it carries into the frame, pixels apart
ALIGN_MAX_DEPTH_RATIO = 3.0  # only a view whose far ranges are within this of its near ones


def align(settings: MatchSettings, frame: Frame, rendering: Rendering) -> PoseFix:
    """A coarse step where features fail (too few matches: a flat ground with textures taken
    again, seen from above): the rendering aligned with the frame by the homography that
    maximises their enhanced correlation coefficient (OpenCV's ECC, blind to brightness and
    contrast), coarse to fine over ALIGN_OCTAVES; a grid of the rendering's model pixels carried
    into the frame by it, lifted and solved as in `compare`. A homography holds exactly for a
    plane and nearly for a far scene, so it is tried only where the rendered ranges' 95th
    percentile is within ALIGN_MAX_DEPTH_RATIO of their 5th (a drone's view down, not a street
    between facades); RANSAC drops what it does not carry. Not for a camera with a lens (its
    image is not its pinhole rendering's)."""
    if frame.camera.lens is not None:
        return PoseFix(False, "no dense alignment through a lens", 0, 0, float("nan"))
    ranges = np.linalg.norm(rendering.positions - np.asarray(rendering.camera.position), axis=2)
    ranges = ranges[np.isfinite(ranges)]
    near, far = np.percentile(ranges, [5, 95]) if len(ranges) else (np.nan, np.nan)
    if not far <= ALIGN_MAX_DEPTH_RATIO * near:
        return PoseFix(False, "too deep a view to align as a plane", 0, 0, float("nan"))
    g_r = grey(rendering.rgb).astype(np.float32)
    h, w = g_r.shape
    g_f = cv2.resize(grey(frame.rgb), (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    mask = np.isfinite(rendering.positions[..., 0]).astype(np.uint8)
    warp = np.eye(3, dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    for level in range(
        ALIGN_OCTAVES - 1, min(settings.align_finest_octave, ALIGN_OCTAVES - 1) - 1, -1
    ):
        s = 2**level
        size = (max(8, w // s), max(8, h // s))
        down = np.diag([1.0 / s, 1.0 / s, 1.0])
        scaled = (down @ warp @ np.linalg.inv(down)).astype(np.float32)
        try:
            _, scaled = cv2.findTransformECC(
                cv2.resize(g_r, size, interpolation=cv2.INTER_AREA),
                cv2.resize(g_f, size, interpolation=cv2.INTER_AREA),
                scaled,
                cv2.MOTION_HOMOGRAPHY,
                criteria,
                cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST),
                5,
            )
        except cv2.error:
            return PoseFix(False, "the rendering and the frame do not align", 0, 0, float("nan"))
        warp = np.linalg.inv(down) @ scaled.astype(np.float64) @ down
    ys, xs = np.mgrid[
        ALIGN_STEP_PX // 2 : h : ALIGN_STEP_PX, ALIGN_STEP_PX // 2 : w : ALIGN_STEP_PX
    ]
    grid = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    grid = grid[mask[ys.ravel(), xs.ravel()] > 0]
    moved = np.column_stack([grid, np.ones(len(grid))]) @ warp.T
    uv_f = from_opencv(moved[:, :2] / moved[:, 2:], frame.scale * w / frame.rgb.shape[1])
    points, usable = rendering.lift(from_opencv(grid), settings.edge_m_per_m)
    i = frame.camera.intrinsics
    usable &= (uv_f[:, 0] > 0) & (uv_f[:, 0] < i.width) & (uv_f[:, 1] > 0) & (uv_f[:, 1] < i.height)
    return solve_pose(frame.camera, points[usable], uv_f[usable], settings)
