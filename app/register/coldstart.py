"""Cold start without GNSS (issue 52): a clip with no fix at all, given only an area
(app.session.start.StartArea), the attitude its IMU gives and its height above the ground, finds
its first pose by searching the scene over the area, then registration carries on from it.

The search, for one frame, runs candidates through the usual registration (render-and-compare
until it converges, with its quality checks: app.register.solve.Registrar.keyframe) and takes
the first pose it accepts within the area, at the platform's height (within a share of it) and
near its attitude. The candidates, by the view's geometry (chosen by measurement,
docs/ACCURACY.md "Cold start"):
- a camera looking down (its optical axis within nadir_within_deg of straight down): the frame
  warped onto the ground plane below it (north up, a metre a cell) and correlated with the
  scene seen from straight above (rendered once over the area: a pinhole from far above,
  orthographic to within centimetres; normalised cross-correlation, blind to brightness and
  contrast); the best peaks are the candidates. Features do worse there: the frame's few
  features (grass, roofs) against a whole area's fail the ratio test on its repeated patterns;
- any other: a grid of camera positions over the area at the platform's height above the ground
  under each, from the area's centre out, spaced by a fraction of the distance the camera looks
  along its axis, each view rendered view_factor times wider and taller than the frame at the
  same focal length and matched with it (SIFT, the mutual ratio test:
  app.register.keyframe.Matcher); a view's matches, lifted to the model and solved for the
  frame's pose (RANSAC on SQPnP), are a candidate, tried at once where they are many, else the
  best few at the end. A position whose frame would hold too little of the scene (its footprint
  on the ground plane) is not rendered. The correlation fails here: the frame's 3D content
  (walls, roofs seen from the side) does not lie on the ground plane.
The frames searched are the clip's first and, where none is found, those `tries` seconds later.
A pose that passes every check but the attitude's (an IMU alone tilts its vertical in a turn)
is held, and taken when a later frame's is turned from the platform's attitude the same way
and lies where the first could have flown to (`agreeing`).

Once found, the prior (the attitude source's track) stands at the found position (held still),
and the keyframes after it are each searched from where the ones before lead
(app.register.solve.Registrar.run chains them at constant velocity); the track's positions are
then the scene's own (`scene_positions`, through the registered keyframes) and no frame stands
on a fix. Frames: world = the session's ENU metres; poses as app.register.keyframe's (camera
position ENU m, camera -> ENU quaternion in OpenGL axes); times are session seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry.base import BaseGeometry

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, looking_down
from app.camera.trajectory import PositionTrack
from app.core.errors import GeofuseError
from app.core.messages import INFO
from app.geodesy import rotations
from app.io.video import frames_at
from app.register.fuse import Keyframe
from app.register.keyframe import (
    Matcher,
    MatchSettings,
    PoseFix,
    Rendering,
    from_opencv,
    posed,
    solve_pose,
)
from app.render.views import ModelViews
from app.scene.ground import ground_heights
from app.scene.mesh import MeshData
from app.session.camera_track import CameraTrack, camera_track
from app.session.model import Session
from app.session.start import ELLIPSOID, HEIGHT_OVER_S, MIN_HEIGHT_M, StartArea

FloatArray = npt.NDArray[np.float64]
TOP_DOWN, PERSPECTIVE = "top-down", "perspective"
FAR_ABOVE_PER_M = 40.0  # a top-down view's camera stands this many times its tile's width high


@dataclass(frozen=True)
class SearchSettings:
    """long_side: views are matched with the frame at most this many pixels on the frame's long
    side, features: SIFT features of the frame and of each view; view_factor: a view's width
    and height over the frame's (same focal length);
    spacing_per_range: the grid's spacing over the distance along the optical axis to the
    ground, itself at most max_range_per_height times the height and at least min_range_m;
    min_scene: a position is rendered where at least this share of the frame's ground
    footprint lies over the scene; min_matches: a view with fewer matches is not solved;
    sure_matches: a view with this many is solved and registered at once (the views are
    searched from the area's centre out); verify: then at most this many more (the most
    matches first) a frame; nadir_within_deg: an optical axis this close to straight down is
    searched top-down: cell_m, the ground's cell there (m), the frame seen as far as
    max_range_per_height times the height, its best `peaks` at least min_peak_m apart the
    places of the views matched, and where none matches well enough, the `direct` best
    registered from as they are (a frame of grass and roofs has few features); tile_px: a top-down rendering's largest side (pixels);
    margin_m: a pose found at most this far outside the area is taken (the area is the user's
    rough idea); height_tolerance: nor one whose height above the ground differs from the
    platform's by more than this share of it, turn_tolerance_deg: nor one turned from the
    platform's attitude by more (degrees), unless it is turned by at most turned_within_deg
    and another frame's pose agrees with it: turned from the platform's attitude the same way
    (within agree_deg) and no farther from it than max_speed_mps for the time between them,
    plus agree_m (an IMU alone tilts its vertical in a turn: the offset holds between frames
    a second apart, a wrong pose's does not); start_pose: the thresholds (full-size pixels) a
    view's matches must meet to give the pose registration starts from (looser than
    registration's own: matched at a quarter of the pixels, it is only a start); tries:
    seconds after the first frame of the frames searched, in order, until one is found."""

    long_side: int = 320
    features: int = 1000
    view_factor: float = 1.5
    spacing_per_range: float = 0.45
    max_range_per_height: float = 3.0
    min_range_m: float = 10.0
    min_scene: float = 0.25
    min_matches: int = 12
    sure_matches: int = 25
    verify: int = 6
    nadir_within_deg: float = 30.0
    cell_m: float = 1.0
    min_peak_m: float = 10.0
    peaks: int = 12
    direct: int = 3
    tile_px: int = 2048
    margin_m: float = 50.0
    height_tolerance: float = 0.3
    turn_tolerance_deg: float = 10.0
    turned_within_deg: float = 30.0
    agree_deg: float = 3.0
    max_speed_mps: float = 30.0
    agree_m: float = 5.0
    tries: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0)
    start_pose: MatchSettings = MatchSettings(min_inliers=8, ransac_px=6.0, max_error_px=5.0)


@dataclass(frozen=True)
class ColdStart:
    """What the search did and found. ok: a pose found, at video frame `index` (session time
    time_s), position (3,) ENU m and q camera -> ENU; else reason. method: TOP_DOWN or
    PERSPECTIVE; asked_m2: the area given; searched_m2: the part of it with scene to search
    (where the views stood, or the scene's ground within it); views: renderings made; seconds:
    the search's time; off_centre_m: the pose's horizontal distance from the area's centre;
    above_ground_m: its height above the scene's ground; inliers, error_px: the registration's
    last step; turned_deg: where it was taken because an earlier frame's pose agreed with it,
    how far it is turned from the platform's attitude (deg; 0: within turn_tolerance_deg);
    height_m: the platform's height above the ground searched at, height_from: where it came
    from where the user did not give it ("": --height or a phone's mount height)."""

    ok: bool
    reason: str
    area: StartArea
    method: str
    asked_m2: float
    searched_m2: float
    views: int
    seconds: float
    index: int = -1
    time_s: float = float("nan")
    position: FloatArray | None = None
    q: FloatArray | None = None
    off_centre_m: float = float("nan")
    above_ground_m: float = float("nan")
    inliers: int = 0
    error_px: float = float("nan")
    turned_deg: float = 0.0
    height_m: float = float("nan")
    height_from: str = ""

    def said(self, geodetic: Callable[[FloatArray], FloatArray], t0_s: float) -> str:
        """One line for people: what was searched, in what time, and what was found (or not).
        geodetic: ENU (3,) m -> (lat, lon, h); t0_s: the clip's first frame's session time."""
        searched = (
            f"searched {self.searched_m2 / 1e6:.2f} km2 of scene in {self.area.said}"
            f" ({self.asked_m2 / 1e6:.2f} km2 asked; {self.views} {self.method} views) in {self.seconds:.1f} s"
        )
        if not self.ok:
            return f"cold start: {searched}: {self.reason}"
        lat, lon, _ = geodetic(np.asarray(self.position))
        return (
            f"cold start: {searched}: found at {lat:.6f}, {lon:.6f}, {self.above_ground_m:.0f} m above the ground"
            + (
                f" (searched at {self.height_m:.0f} m: {self.height_from})"
                if self.height_from
                else ""
            )
            + f" (t = {self.time_s - t0_s:.1f} s), {self.off_centre_m:.0f} m from the area's centre"
            f" ({self.inliers} inliers, {self.error_px:.2f} px)"
            + (
                f"; turned {self.turned_deg:.0f} deg from the platform's attitude, as the pose"
                " an earlier frame gave"
                if self.turned_deg
                else ""
            )
        )


@dataclass(frozen=True)
class _Candidate:
    """A view's matches with the frame: the model points (N, 3) ENU m under the view's matched
    pixels and the frame's pixels (N, 2) (full video size), and where the view stood."""

    matches: int
    points: FloatArray
    uv: FloatArray
    position: FloatArray


def searched(session: Session) -> bool:
    """Whether the session starts by searching its area: one is given and the clip has no GNSS
    fix at all (where it has, that is said once and the GNSS is the prior, as without an
    area: where its fixes begin late, the frames before them are searched for around the
    first, app.register.solve.RegistrationSettings.unfixed_radius)."""
    if session.start is None:
        return False
    if len(session.gnss.t):
        t0 = float(session.frame_times[0])
        session.messages.add_once(
            "cold-start-unused",
            f"{session.start.said}: not searched, the clip has GNSS (from t = {session.gnss.t[0] - t0:.1f} s)",
        )
        return False
    return True


def platform_height(session: Session) -> tuple[float, str]:
    """(the camera's height above the ground (m), where it comes from): the area's
    (`--height`; ""), else the telemetry's (Session.platform_heights: their median over the
    clip's first HEIGHT_OVER_S, where a search tries frames; above take-off, the take-off's
    ground taken for the ground under the platform; ellipsoidal, less the scene's ground under
    the area's centre; said), else a phone's mount height where the session's heights are the
    ground's (""). GeofuseError where none is known, or the telemetry's is below MIN_HEIGHT_M."""
    start = session.start
    if start is not None and start.height_m is not None:
        return float(start.height_m), ""
    given = session.platform_heights
    if given is not None and start is not None:
        early = np.asarray(given.t) <= float(session.frame_times[0]) + HEIGHT_OVER_S
        height = float(np.median(given.h[early] if early.any() else given.h[:1]))
        said = given.said
        if given.above == ELLIPSOID:
            lat, lon = start.centre
            z = float(session.frame.geodetic_to_enu(lat, lon, height)[2])
            ground = float(_ground(session.scene(), start.centre_enu(session.frame)[None])[0])
            height, said = (
                z - ground,
                f"{said} ({height:.0f} m) over the scene's ground at the area's centre",
            )
        if height < MIN_HEIGHT_M:
            raise GeofuseError(
                f"{session.path}: cold start: {said} is {height:.1f} m at the clip's start, too low above the ground to search the scene from (at least {MIN_HEIGHT_M:g} m): give --height M"
            )
        return height, said
    if session.height_mode == "ground":
        return float(session.mount_height_m), ""
    raise GeofuseError(
        f"{session.path}: cold start: the platform's height above the ground is not known: give --height M"
    )


def _ground(mesh: MeshData, xy: FloatArray) -> FloatArray:
    """(N,) the ground's height (ENU z, m) under points (N, 2): the scene's lowest surface, and
    where it has none the median of those found (the scene's lowest point where none is)."""
    z = ground_heights(mesh, xy) if len(xy) else np.zeros(0)
    fill = float(np.nanmedian(z)) if np.isfinite(z).any() else float(mesh.bounds()[0, 2])
    return np.where(np.isfinite(z), z, fill)


def _axis_pitch_deg(q: npt.ArrayLike) -> float:
    """The optical axis's pitch (deg above the horizon) of a camera -> ENU quaternion."""
    return float(rotations.hpr_from_camera_quat(np.asarray(q, np.float64)[None])[0, 1])


def ground_footprint(camera: Camera, ground_z: float, max_range_m: float) -> BaseGeometry:
    """The frame's footprint on the plane z = ground_z (ENU m) seen from above: the border's
    rays (five a side) met with the plane, each no farther than max_range_m horizontally (a ray
    at or above the horizon: that far along its heading); a shapely polygon of (east, north)."""
    w, h = camera.intrinsics.width, camera.intrinsics.height
    s = np.linspace(0.0, 1.0, 5)
    border = np.concatenate(
        [
            np.column_stack([s * w, np.zeros(5)]),
            np.column_stack([np.full(5, w), s * h]),
            np.column_stack([(1 - s) * w, np.full(5, h)]),
            np.column_stack([np.zeros(5), (1 - s) * h]),
        ]
    )
    rays = camera.pixel_rays(border)
    eye = np.asarray(camera.position, np.float64)
    flat = np.linalg.norm(rays[:, :2], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays[:, 2] < 0, (ground_z - eye[2]) / rays[:, 2], np.inf)
        reach = np.minimum(t * flat, max_range_m)
        unit = np.where(flat[:, None] > 1e-9, rays[:, :2] / flat[:, None], 0.0)
    return shapely.MultiPoint(eye[:2] + unit * reach[:, None]).convex_hull


def _scene_box(mesh: MeshData) -> BaseGeometry:
    lo, hi = mesh.bounds()
    return shapely.box(lo[0], lo[1], hi[0], hi[1])


def _grid(area: BaseGeometry, spacing: float) -> FloatArray:
    """(N, 2) points spacing metres apart inside the area (its centroid where none is; none in
    an empty area)."""
    if area.is_empty:
        return np.zeros((0, 2))
    x0, y0, x1, y1 = area.bounds
    xs = np.arange(x0 + (x1 - x0) % spacing / 2, x1, spacing)
    ys = np.arange(y0 + (y1 - y0) % spacing / 2, y1, spacing)
    pts = np.array([(x, y) for y in ys for x in xs], np.float64).reshape(-1, 2)
    inside = shapely.contains_xy(area, pts[:, 0], pts[:, 1]) if len(pts) else np.zeros(0, bool)
    if not inside.any():
        c = area.centroid
        return np.array([[c.x, c.y]])
    return pts[inside]


@dataclass(frozen=True)
class _Verified:
    """A candidate registered and checked: the camera (None: not, and why), and the
    registration's last step's inliers and RMS error (px)."""

    camera: Camera | None
    why: str
    inliers: int = 0
    error_px: float = float("nan")


@dataclass(frozen=True)
class _Turned:
    """A pose that passed every check but the turn (turned_within_deg at most): the registered
    camera, its checks' figures, and its offset from the platform's attitude (the world-side
    rotation, scalar-first quaternion, taking the platform's onto it)."""

    verified: _Verified
    offset: FloatArray


def agreeing(
    earlier: list[tuple[float, FloatArray, FloatArray]],
    time_s: float,
    position: npt.ArrayLike,
    offset: npt.ArrayLike,
    s: SearchSettings,
) -> bool:
    """Whether a pose held at session time time_s (s), at `position` (3,) ENU m and turned from
    the platform's attitude by `offset` (a world-side scalar-first quaternion), agrees with one
    of `earlier` ((session time s, position, offset) of poses held on frames searched before):
    its offset within agree_deg of that one's, and its position within max_speed_mps for the
    time between them plus agree_m (SearchSettings)."""
    p = np.asarray(position, np.float64)
    for t, at, turned_by in earlier:
        turn = float(np.degrees(rotations.angle_between(turned_by, offset)))
        moved = float(np.linalg.norm(np.asarray(at, np.float64) - p))
        if turn <= s.agree_deg and moved <= s.max_speed_mps * abs(time_s - t) + s.agree_m:
            return True
    return False


@dataclass(frozen=True)
class _Ortho:
    """The scene seen from straight above, north up: grey (H, W) float32, its cell (m) and the
    ENU east, north (m) of its top-left corner."""

    grey: np.ndarray
    cell_m: float
    west: float
    north: float


class Search:
    """The search of one area (module docstring): the scene (mesh) and its views
    (app.render.views.ModelViews), the registration that takes a start to a pose
    (`register(frame_rgb, start) -> (PoseFix, Camera | None)`, the usual render-and-compare
    loop with its checks), the area (a polygon of ENU east, north metres) and its centre (2,)
    (the views are searched from it out), the platform's height above the ground (m)."""

    def __init__(
        self,
        mesh: MeshData,
        views: ModelViews,
        register: Callable[[np.ndarray, Camera], tuple[PoseFix, Camera | None]],
        area_enu: BaseGeometry,
        centre: FloatArray,
        height_m: float,
        settings: SearchSettings = SearchSettings(),
    ) -> None:
        self.mesh, self.views, self.register = mesh, views, register
        self.area_enu, self.centre, self.height_m = area_enu, np.asarray(centre), height_m
        self.settings = settings
        self.matcher = Matcher(MatchSettings(features=settings.features))
        self.scene_box = _scene_box(mesh)
        self.rendered = 0
        self.turned: list[_Turned] = []  # the last frame's poses turned too far (_verify)
        self._orthos: list[_Ortho] | None = None

    def agreed(
        self, held: list[tuple[float, FloatArray, FloatArray]], time_s: float
    ) -> tuple[_Verified, float]:
        """The last frame's pose turned too far (`turned`) that one of `held` agrees with
        (`agreeing`; the frame's session time time_s, s), and how far it is turned from the
        platform's attitude (deg); (not found, 0) where none does. The frame's turned poses are
        added to `held` (time, position, offset) for the frames after it."""
        poses = [(np.asarray(x.verified.camera.position), x.offset) for x in self.turned]
        agreed = [
            x
            for x, (p, q) in zip(self.turned, poses, strict=True)
            if agreeing(held, time_s, p, q, self.settings)
        ]
        held += [(time_s, p, q) for p, q in poses]
        if not agreed:
            return _Verified(None, "no pose held agrees"), 0.0
        turn = float(np.degrees(rotations.angle_between(agreed[0].offset, [1.0, 0.0, 0.0, 0.0])))
        return agreed[0].verified, turn

    @property
    def max_range_m(self) -> float:
        s = self.settings
        return max(s.min_range_m, s.max_range_per_height * self.height_m)

    def frame(self, rgb: np.ndarray, camera: Camera) -> tuple[_Verified, str, float]:
        """Search for one frame: (what registered, or why not; the method; the searched area
        m2). rgb: the frame at any size; camera: its camera at full video size with the
        platform's attitude (its position is not used)."""
        s = self.settings
        self.turned = []
        image = camera.intrinsics if camera.lens is None else camera.lens.k
        scale = min(1.0, s.long_side / max(image.width, image.height))
        small = camera.pinhole(scale)
        if 90.0 + _axis_pitch_deg(camera.orientation) <= s.nadir_within_deg:
            method, m2 = TOP_DOWN, float(self.area_enu.intersection(self.scene_box).area)
            places, why = self._correlated(rgb, camera) if m2 > 0 else (np.zeros((0, 2)), "")
        else:
            method, (places, m2), why = PERSPECTIVE, self._grid_places(small), ""
        if m2 <= 0:
            return _Verified(None, "the area holds no scene to search"), method, 0.0
        if not len(places):
            return _Verified(None, why), method, m2
        size = (round(image.width * scale), round(image.height * scale))
        uv_f, desc_f = self.matcher.features(cv2.resize(rgb, size, interpolation=cv2.INTER_AREA))
        views = self._views(small, places)
        verified = self._candidates(rgb, camera, views, desc_f, from_opencv(uv_f, scale))
        if verified.camera is None and method == TOP_DOWN:  # too few features: the peaks alone
            near = places[: s.direct]
            for (x, y), z in zip(near, _ground(self.mesh, near), strict=True):
                start = posed(camera, [x, y, z + self.height_m], camera.orientation)
                direct = self._verify(rgb, start, camera)
                if direct.camera is not None:
                    return direct, method, m2
        return verified, method, m2

    def _verify(self, rgb: np.ndarray, start: Camera, attitude: Camera) -> _Verified:
        """The usual registration from `start`, the pose taken where it lies within the area
        (grown by margin_m), at the platform's height (within height_tolerance) and turned
        from its attitude (`attitude`'s) by at most turn_tolerance_deg: a frame with little to
        register (grass, a flat roof) can pass registration's checks at a wrong pose."""
        s = self.settings
        fix, solved = self.register(rgb, start)
        if solved is None:
            return _Verified(None, f"a candidate did not register ({fix.reason})")
        p = np.asarray(solved.position, np.float64)
        outside = self.area_enu.distance(shapely.Point(*p[:2]))
        if outside > s.margin_m:
            return _Verified(None, f"the pose found lies {outside:.0f} m outside the area")
        height = p[2] - float(_ground(self.mesh, p[None, :2])[0])
        if abs(height - self.height_m) > s.height_tolerance * self.height_m:
            return _Verified(
                None, f"a pose registered {height:.0f} m above the ground, not {self.height_m:g} m"
            )
        turn = float(np.degrees(rotations.angle_between(solved.orientation, attitude.orientation)))
        if turn > s.turn_tolerance_deg:
            if turn <= s.turned_within_deg:  # held: another frame may agree with it
                offset = rotations.multiply(
                    solved.orientation, rotations.conjugate(attitude.orientation)
                )
                self.turned.append(
                    _Turned(_Verified(solved, "", fix.inliers, fix.error_px), offset)
                )
            return _Verified(None, f"a pose registered {turn:.0f} deg from the platform's attitude")
        return _Verified(solved, "", fix.inliers, fix.error_px)

    # --- views matched with the frame -----------------------------------------------------------

    def _candidates(
        self,
        rgb: np.ndarray,
        camera: Camera,
        views: Iterator[Camera],
        desc_f: np.ndarray | None,
        uv_f: FloatArray,
    ) -> _Verified:
        """The views matched with the frame's features (desc_f, at pixels uv_f of the full-size
        frame) in order, a view with sure_matches solved and registered at once, then the best
        others (at most `verify`)."""
        s = self.settings
        found: list[_Candidate] = []
        best, why = 0, ""
        for view in views:
            cand = self._match(view, desc_f, uv_f)
            best = max(best, cand.matches if cand is not None else 0)
            if cand is None or cand.matches < s.min_matches:
                continue
            found.append(cand)
            if cand.matches >= s.sure_matches:  # a view this good is tried at once
                verified = self._solved(rgb, camera, cand)
                if verified.camera is not None:
                    return verified
                why = verified.why
        if not found:
            why = f"no view matched the frame well enough (at most {best} matches, {s.min_matches} needed)"
        rest = sorted((c for c in found if c.matches < s.sure_matches), key=lambda c: -c.matches)
        for cand in rest[: s.verify]:
            verified = self._solved(rgb, camera, cand)
            if verified.camera is not None:
                return verified
            why = verified.why
        return _Verified(None, why)

    def _solved(self, rgb: np.ndarray, camera: Camera, cand: _Candidate) -> _Verified:
        """A view's matches solved for the frame's pose (RANSAC on SQPnP), registered from it."""
        start = posed(camera, cand.position, camera.orientation)
        fix = solve_pose(start, cand.points, cand.uv, self.settings.start_pose)
        if not fix.ok:
            return _Verified(None, f"no view gave a pose ({fix.reason})")
        return self._verify(rgb, posed(camera, fix.position, fix.q), camera)

    def _match(
        self, view: Camera, desc_f: np.ndarray | None, uv_f: FloatArray
    ) -> _Candidate | None:
        """The view rendered and matched with the frame's features (None: too little scene)."""
        rgb, positions = self.views.render(view)
        self.rendered += 1
        on_model = np.isfinite(positions[..., 0])
        if on_model.mean() < 0.02:
            return None
        uv_v, desc_v = self.matcher.features(rgb, mask=on_model * 255)
        pairs = self.matcher.match(desc_f, desc_v)
        rendering = Rendering(rgb, positions, view)
        points, usable = rendering.lift(from_opencv(uv_v[pairs[:, 1]]), 0.02)
        return _Candidate(
            int(usable.sum()),
            points[usable],
            uv_f[pairs[usable, 0]],
            np.asarray(view.position, np.float64),
        )

    def _grid_places(self, small: Camera) -> tuple[FloatArray, float]:
        """The grid's places (N, 2) ENU m, from the area's centre out, whose frame footprint
        (the camera there at the platform's height) holds enough scene, and the area they stand
        over (m2: their count times the spacing squared, at most the area's)."""
        s = self.settings
        pitch = _axis_pitch_deg(small.orientation)
        cap = self.max_range_m
        along = self.height_m / np.sin(np.radians(-pitch)) if pitch < -1.0 else cap
        spacing = s.spacing_per_range * float(np.clip(along, s.min_range_m, cap))
        xy = _grid(self.area_enu, spacing)
        xy = xy[np.argsort(np.linalg.norm(xy - self.centre, axis=1))]
        ground = _ground(self.mesh, xy)
        keep = np.zeros(len(xy), bool)
        for k, ((x, y), z) in enumerate(zip(xy, ground, strict=True)):
            fp = ground_footprint(
                posed(small, [x, y, z + self.height_m], small.orientation), z, cap
            )
            keep[k] = fp.area > 0 and fp.intersection(self.scene_box).area >= s.min_scene * fp.area
        return xy[keep], min(int(keep.sum()) * spacing**2, float(self.area_enu.area))

    def _views(self, small: Camera, places: FloatArray) -> Iterator[Camera]:
        """The frame's camera (at the matching size, view_factor times wider and taller at the
        same focal length) at each place (N, 2), the platform's height above the ground there."""
        s = self.settings
        i = small.intrinsics
        wide = Intrinsics(
            round(i.width * s.view_factor),
            round(i.height * s.view_factor),
            i.fx,
            i.fy,
            i.cx + (s.view_factor - 1) * i.width / 2,
            i.cy + (s.view_factor - 1) * i.height / 2,
        )
        for (x, y), z in zip(places, _ground(self.mesh, places), strict=True):
            yield replace(
                posed(small, [x, y, z + self.height_m], small.orientation), intrinsics=wide
            )

    # --- top-down -------------------------------------------------------------------------------

    def _correlated(self, rgb: np.ndarray, camera: Camera) -> tuple[FloatArray, str]:
        """The frame warped onto the ground plane (north up, cell_m metres a cell, as far as
        max_range_m) correlated with the scene seen from above (normalised cross-correlation,
        blind to brightness and contrast): its best peaks within the area, min_peak_m apart (at
        most `peaks`), as places (N, 2) ENU m, the best first; why none, where none."""
        s = self.settings
        template, mask, nadir = self._ground_image(rgb, camera)
        if mask.sum() < 16:
            return np.zeros((0, 2)), "the frame shows too little ground to correlate"
        peaks: list[tuple[float, float, float]] = []
        for ortho in self._ortho():
            if ortho.grey.shape[0] < template.shape[0] or ortho.grey.shape[1] < template.shape[1]:
                continue
            score = cv2.matchTemplate(ortho.grey, template, cv2.TM_CCOEFF_NORMED, mask=mask)
            score = np.nan_to_num(score, nan=-1.0, posinf=-1.0, neginf=-1.0)
            for r, c in _peaks(score, max(1, round(s.min_peak_m / ortho.cell_m)), 4 * s.peaks):
                e = ortho.west + (c + nadir[0]) * ortho.cell_m
                n = ortho.north - (r + nadir[1]) * ortho.cell_m
                if self.area_enu.distance(shapely.Point(e, n)) <= s.margin_m:
                    peaks.append((float(score[r, c]), e, n))
        best = sorted(peaks, reverse=True)[: s.peaks]
        why = "" if best else "no place in the area correlates with the frame"
        return np.array([(e, n) for _, e, n in best], np.float64).reshape(-1, 2), why

    def _ground_image(
        self, rgb: np.ndarray, camera: Camera
    ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
        """The frame on the ground plane below it, north up, cell_m a cell: (grey (h, w)
        float32, mask (h, w) uint8 of the cells it sees within max_range_m, the camera's nadir
        (column, row) in it)."""
        g, reach = self.settings.cell_m, self.max_range_m
        half = int(np.ceil(reach / g))
        size = 2 * half + 1
        at = posed(camera, [0.0, 0.0, self.height_m], camera.orientation)
        last = size - 1  # cells by their centres (OpenCV's pixel convention)
        corners = np.array([[0, 0], [last, 0], [last, last], [0, last]], np.float64)
        ground = np.column_stack(
            [(corners[:, 0] - half) * g, (half - corners[:, 1]) * g, np.zeros(4)]
        )
        uv, depth = at.project(ground)
        rows, cols = np.mgrid[0:size, 0:size]
        cells = np.column_stack(
            [((cols - half) * g).ravel(), ((half - rows) * g).ravel(), np.zeros(size * size)]
        )
        seen_uv, seen_depth = at.project(cells)
        scale = rgb.shape[1] / (
            camera.intrinsics.width if camera.lens is None else camera.lens.width
        )
        i = camera.intrinsics if camera.lens is None else camera.lens.k
        seen = (
            (seen_depth > 0)
            & (np.hypot(cells[:, 0], cells[:, 1]) <= reach)
            & (seen_uv[:, 0] >= 0) & (seen_uv[:, 0] < i.width)
            & (seen_uv[:, 1] >= 0) & (seen_uv[:, 1] < i.height)
        )  # fmt: skip
        if (depth <= 0).any() or not seen.any():
            to_frame = None
        else:
            to_frame = cv2.getPerspectiveTransform(
                corners.astype(np.float32), (uv * scale - 0.5).astype(np.float32)
            )
        mask = seen.reshape(size, size).astype(np.uint8)
        if to_frame is None:  # a corner behind the camera: sample the frame cell by cell
            maps = (seen_uv * scale - 0.5).astype(np.float32).reshape(size, size, 2)
            warped = cv2.remap(rgb, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR)
        else:
            warped = cv2.warpPerspective(
                rgb, to_frame, (size, size), flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP
            )
        ys, xs = np.nonzero(mask)
        if not len(ys):
            return np.zeros((1, 1), np.float32), np.zeros((1, 1), np.uint8), (0.0, 0.0)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        grey = cv2.cvtColor(warped[y0:y1, x0:x1], cv2.COLOR_RGB2GRAY).astype(np.float32)
        return grey, mask[y0:y1, x0:x1], (half - x0 + 0.5, half - y0 + 0.5)

    def _ortho(self) -> list[_Ortho]:
        """The scene under the area (grown by max_range_m) seen from straight above, north up,
        cell_m a cell, in tiles of at most tile_px a side overlapping by a frame's ground
        (made once: every frame correlates with the same)."""
        if self._orthos is not None:
            return self._orthos
        self._orthos = []
        region = self.area_enu.buffer(self.max_range_m).intersection(self.scene_box)
        if region.is_empty:
            return self._orthos
        g = self.settings.cell_m
        tile, overlap = self.settings.tile_px * g, 2 * self.max_range_m
        step = max(tile - overlap, tile / 2)
        x0, y0, x1, y1 = region.bounds
        lo, hi = self.mesh.bounds()
        for down in _starts(y1 - y0, tile, step):
            for west in x0 + _starts(x1 - x0, tile, step):
                top = y1 - down
                w_m, h_m = min(tile, x1 - west), min(tile, top - y0)
                w_px, h_px = max(8, round(w_m / g)), max(8, round(h_m / g))
                centre = np.array([west + w_px * g / 2, top - h_px * g / 2])
                # g a cell on the ground under the tile's centre (where the frame is warped to)
                ground = float(_ground(self.mesh, centre[None])[0])
                above = FAR_ABOVE_PER_M * max(w_m, h_m)
                view = looking_down((w_px, h_px), centre, g, ground, (lo[2], hi[2]), above)
                rgb, _ = self.views.render(view)
                self.rendered += 1
                grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
                self._orthos.append(_Ortho(grey, g, west, top))
        return self._orthos


def _starts(length: float, tile: float, step: float) -> np.ndarray:
    """Offsets (m) of tiles `tile` long, `step` apart, covering [0, length] (the last flush
    with its end)."""
    if length <= tile:
        return np.zeros(1)
    return np.append(np.arange(0.0, length - tile, step), length - tile)


def _peaks(score: np.ndarray, apart: int, count: int) -> list[tuple[int, int]]:
    """Up to `count` (row, column) of the highest values of score, each the highest within
    `apart` cells (non-maximum suppression)."""
    local = cv2.dilate(score, np.ones((2 * apart + 1, 2 * apart + 1), np.uint8))
    rows, cols = np.nonzero((score >= local) & (score > -1.0))
    order = np.argsort(score[rows, cols])[::-1][:count]
    return [(int(rows[k]), int(cols[k])) for k in order]


def search_start(
    session: Session,
    source: str,
    views: ModelViews,
    register: Callable[[np.ndarray, Camera], tuple[PoseFix, Camera | None]],
    frames: Callable[[list[int]], Iterator[tuple[int, np.ndarray]]],
    settings: SearchSettings = SearchSettings(),
    clock: Callable[[], float] = time.perf_counter,
    **track_options: object,
) -> ColdStart:
    """Search the session's area (session.start) for the first pose (module docstring), with
    the attitude of `source`. views: the scene's renderer; register(frame_rgb, start): the usual
    registration from a start (the solved camera or None); frames(indices): the video's frames
    (index, RGB) decoded; clock: seconds (the search's time, said); track_options: to
    app.session.camera_track.camera_track."""
    area = session.start
    began = clock()
    height, height_from = platform_height(session)
    area_enu, centre = area.enu_area(session.frame), area.centre_enu(session.frame)
    prior = attitude_track(session, source, centre, height, **track_options)
    search = Search(session.scene(), views, register, area_enu, centre, height, settings)
    pts = np.asarray(session.video.pts_s, np.float64)
    wanted = sorted(
        {int(min(np.searchsorted(pts, pts[0] + t), len(pts) - 1)) for t in settings.tries}
    )
    method, m2, why = PERSPECTIVE, 0.0, "no frame to search"
    held: list[tuple[float, FloatArray, FloatArray]] = []  # poses turned too far: (t, p, offset)
    for k, rgb in frames(wanted):
        t_k = float(prior.clock.session_time([pts[k]])[0])
        verified, method, m2 = search.frame(rgb, prior.frame_camera(k))
        why = verified.why
        turned = 0.0
        if verified.camera is None:  # a pose turned too far, that an earlier frame's agrees with
            verified, turned = search.agreed(held, t_k)
        if verified.camera is not None:
            p = np.asarray(verified.camera.position, np.float64)
            return ColdStart(
                True, "", area, method, float(area_enu.area), m2, search.rendered, clock() - began,
                int(k), t_k, p, np.asarray(verified.camera.orientation),
                float(np.linalg.norm(p[:2] - centre)), float(p[2] - _ground(search.mesh, p[None, :2])[0]),
                verified.inliers, verified.error_px, turned, height, height_from,
            )  # fmt: skip
        if m2 <= 0:
            break  # no scene under the area: another frame will not find one
    if m2 <= 0:
        far = search.scene_box.distance(shapely.Point(*centre))
        why = f"the area holds no scene (the scene's nearest edge is {far:.0f} m from its centre)"
    else:
        why = f"not found in the frames at t = {', '.join(f'{t:g}' for t in settings.tries)} s ({why})"
    return ColdStart(
        False, why, area, method, float(area_enu.area), m2, search.rendered, clock() - began,
        height_m=height, height_from=height_from,
    )  # fmt: skip


def held_positions(session: Session, enu: FloatArray) -> PositionTrack:
    """A position track standing still at enu (3,) m over the whole clip (and a second each side)."""
    t = np.array([session.frame_times[0] - 1.0, session.frame_times[-1] + 1.0], np.float64)
    lat, lon, h = session.frame.enu_to_geodetic(np.asarray(enu, np.float64)[None])[0]
    return PositionTrack.from_fixes(t, [lat, lat], [lon, lon], [h, h], np.zeros((2, 3)))


def attitude_track(
    session: Session, source: str, centre: FloatArray, height_m: float, **track_options: object
) -> CameraTrack:
    """The source's camera track standing at the area's centre, height_m above the ground there
    (its attitude is what the search uses)."""
    xy = np.asarray(centre, np.float64)[None, :2]
    z = float(_ground(session.scene(), xy)[0]) + height_m
    return camera_track(
        session, source, positions=held_positions(session, [*xy[0], z]), **track_options
    )


def seeded_track(
    session: Session, source: str, found: ColdStart, **track_options: object
) -> CameraTrack:
    """The source's camera track standing still at the found position, its attitude turned
    (world-side, once for all) onto the found one: registration's prior, its keyframes chained
    from there."""
    track = camera_track(
        session, source, positions=held_positions(session, found.position), **track_options
    )
    _, _, q = track.poses.at([found.time_s])
    turn = rotations.multiply(found.q, rotations.conjugate(q[0]))
    q_device = rotations.canonical(rotations.multiply(turn, track.poses.q_device))
    return replace(track, poses=replace(track.poses, q_device=q_device))


def scene_positions(
    session: Session,
    keyframes: list[Keyframe],
    within_s: float = 1.5,
    off_m: float = 2.5,
    carry_s: float = 3.0,
) -> PositionTrack | None:
    """The positions the registered keyframes give, as a position track (velocities from
    neighbours), without those a straight line through the registered ones within within_s
    seconds either side misses by more than off_m metres (a keyframe registered wrongly does
    not pull the track: the fusion's gate then sets it aside), carried on toward the clip's
    first and last frames at the end keyframes' velocity for at most carry_s seconds; None
    where fewer than two remain."""
    solved = [k for k in keyframes if k.registered]
    t = np.array([k.time_s for k in solved], np.float64)
    p = np.array([k.position for k in solved], np.float64).reshape(-1, 3)
    keep = np.ones(len(t), bool)
    while True:  # the worst one out, until none is off
        off = _off_line(t, p, keep, within_s)
        worst = int(np.argmax(off)) if len(off) else 0
        if not len(off) or off[worst] <= off_m:
            break
        keep[worst] = False
    if keep.sum() < 2:
        return None
    t, p = t[keep], p[keep]
    # to the clip's ends, at most carry_s seconds, at the velocity of the last two keyframes
    first, last = float(session.frame_times[0]), float(session.frame_times[-1])
    ends = [max(first, t[0] - carry_s), min(last, t[-1] + carry_s)]
    v0, v1 = (p[1] - p[0]) / (t[1] - t[0]), (p[-1] - p[-2]) / (t[-1] - t[-2])
    if ends[0] < t[0]:
        t, p = np.r_[ends[0], t], np.vstack([p[0] + v0 * (ends[0] - t[0]), p])
    if ends[1] > t[-1]:
        t, p = np.r_[t, ends[1]], np.vstack([p, p[-1] + v1 * (ends[1] - t[-1])])
    geo = session.frame.enu_to_geodetic(p)
    return PositionTrack.from_fixes(t, geo[:, 0], geo[:, 1], geo[:, 2])


def _off_line(
    t: FloatArray, p: FloatArray, keep: npt.NDArray[np.bool_], within_s: float
) -> FloatArray:
    """(N,) how far (m) each kept position p (N, 3) at times t (N,) s lies from the straight
    line fitted through the other kept ones within within_s seconds (0 where fewer than two,
    and for those not kept)."""
    off = np.zeros(len(t))
    for i in np.flatnonzero(keep):
        near = np.flatnonzero(keep & (np.abs(t - t[i]) <= within_s) & (np.arange(len(t)) != i))
        if len(near) >= 2 and np.ptp(t[near]) > 0:
            fit = np.polynomial.polynomial.polyfit(t[near] - t[i], p[near], 1)
            off[i] = float(np.linalg.norm(fit[0] - p[i]))
    return off


class Registers(Protocol):
    """What the cold start asks of app.register.solve.Registrar (typed here so that this module
    does not import the one that calls it): the scene's views, the frames' size, and one
    keyframe's render-and-compare from a start."""

    views: ModelViews
    settings: Any  # app.register.solve.RegistrationSettings: long_side

    def keyframe(
        self, frame_rgb: np.ndarray, start: Camera
    ) -> tuple[PoseFix, Camera | None, int]: ...


def started(
    session: Session,
    source: str,
    registrar: Registers,
    settings: SearchSettings = SearchSettings(),
    **track_options: object,
) -> CameraTrack:
    """The cold start of a session (`searched` says when): its area searched with `registrar`,
    what was found said in the session's messages, and registration's prior returned: the
    source's track standing at the found pose (`seeded_track`). GeofuseError saying what was
    searched where nothing was found."""
    found = search_start(
        session,
        source,
        registrar.views,
        lambda rgb, start: registrar.keyframe(rgb, start)[:2],
        lambda wanted: frames_at(session.video, wanted, registrar.settings.long_side),
        settings,
        **track_options,
    )
    said = found.said(session.frame.enu_to_geodetic, float(session.frame_times[0]))
    if not found.ok:
        raise GeofuseError(f"{session.path}: {said}")
    session.messages.add_once("cold-start", said, INFO)
    return seeded_track(session, source, found, **track_options)


def on_scene(session: Session, prior: CameraTrack, keyframes: list[Keyframe]) -> CameraTrack:
    """The prior with its positions the scene's own (`scene_positions`) where two keyframes or
    more registered; as it was otherwise."""
    positions = scene_positions(session, keyframes)
    if positions is None:
        return prior
    return replace(prior, poses=replace(prior.poses, positions=positions))
