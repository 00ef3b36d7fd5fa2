"""The `registered` pose source: keyframes of the video registered against the scene by
render-and-compare, fused with a prior source's track (app.register.fuse).

For each keyframe (one every `every_s` seconds of video): start from the prior's pose, corrected
by what the keyframes before it found; render the model there (colour and positions, off-screen,
app.render.views) with the clip's lens's enclosing pinhole at about the video's resolution;
match the frame against the rendering and solve the pose (app.register.keyframe); render again
at the solved pose until it moves less than converge_m and converge_deg, at most max_iterations
renderings. Then the GNSS fixes are tested against the keyframes and the IMU, the track is
carried through what they reject (app.register.inertial), and the keyframes a lie lost (started
from its fixes) are registered once more, led by the keyframes found before them and by that
carried track, and again from each carry the found ones make (RETRY_ROUNDS). Times are session
seconds, poses ENU metres and camera -> ENU quaternions.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import moderngl
import numpy as np
import shapely

from app.camera.fixes import USED, FixStatus
from app.camera.pinhole import Camera
from app.camera.trajectory import PositionTrack
from app.core.constants import KEYFRAMES_S
from app.core.errors import GeofuseError
from app.geodesy import rotations
from app.io.video import frames_at
from app.register import coldstart, inertial
from app.register.edges import EdgeSettings, cut_outline, fit_edges
from app.register.flow_motion import Seen
from app.register.fuse import (
    Correction,
    FuseSettings,
    Keyframe,
    corrected_pose_track,
    estimate_delay,
    gate,
    retimed,
)
from app.register.gnss import CheckSettings, GnssCheck, check_fixes, merged
from app.register.keyframe import (
    Frame,
    Matcher,
    MatchSettings,
    PoseFix,
    Rendering,
    compare,
    nudged,
    posed,
    refine,
)
from app.register.points import (
    ControlSolution,
    control_path,
    corrected_track,
    read_points,
    solve_control,
)
from app.render.views import ModelViews
from app.scene.ground import ground_heights
from app.scene.mesh import MeshData
from app.session.camera_track import CameraTrack, camera_track
from app.session.model import REGISTERED, Session

BACKGROUND_NICE = 10  # a background registration's thread priority (Linux nice value)
# keyframes a lie lost tried again from the carry, then from each carry those found make anew
RETRY_ROUNDS = 3


class Cancelled(GeofuseError):
    """A registration stopped on request (the viewer closed the session)."""


@dataclass(frozen=True)
class RegistrationSettings:
    """every_s: seconds of video between keyframes; long_side: the frames and renderings are
    matched at most this many pixels on their long side; max_iterations: renderings per keyframe;
    coarse steps (SIFT matches, app.register.keyframe.compare) run until one moves the pose less
    than fine_within_m and fine_within_deg, then fine steps (corners tracked, `refine`) until one
    moves it less than converge_m and converge_deg (fine=False: coarse steps only, until one moves
    it less than converge_m and converge_deg); estimate_delay: estimate and remove the frame
    times' offset from the keyframes (app.register.fuse.estimate_delay); by_geometry: align the
    model's lines with the frame's edges (app.register.edges) instead of matching textures, with
    `edges` its settings; a scene without texture is always registered so (`by_geometry`), and
    a keyframe whose lines leave a direction of the pose loosely fixed is refused (a street
    along one facade, a view straight down: docs/ACCURACY.md); geometry_fallback: where
    matching textures finds no pose (a scene textured in part: a city's grey LoD2 buildings on
    an orthophoto-draped terrain), align the lines from the same start; chain_m, chain_s: where
    the prior's start lies more than chain_m metres from the position the last registered
    keyframes (within chain_s seconds) lead to at constant velocity, the keyframe is searched
    from the latter first (a GNSS that jumps or drags off must not lose the scene: issue 52),
    and so is one where the prior stands on no fix it used (a lie, an outage: the IMU carried
    it); with an accelerometer the keyframes lead on by the IMU's motion, not a constant
    velocity (app.register.inertial.chained); a pose found farther than chain_reach_m from
    where they lead is not taken (the platform cannot be there: a false match). Lost: where no
    keyframe has registered for reacquire_after_s seconds and the prior stands on no fix it
    used or has moved unlike the scene (farther from where the registered keyframes lead than
    chain_m plus what that lead may err by), a keyframe that does not register is searched for
    as a cold start does (app.register.coldstart.Search, at most every reacquire_every_s) over
    discs around where they lead and, where no fix holds the prior, where the IMU carried it:
    reacquire_m plus half of reacquire_accel (m/s^2) times the seconds lost squared, at most
    reacquire_max_m. Before any keyframe has registered, where no fix holds the prior (a
    clip whose GNSS begins late, or stops at its start), a keyframe that does not register is
    searched for over the disc the platform can fly from the nearest fix in time: reacquire_m
    plus unfixed_speed_mps times the seconds to it, at most unfixed_max_m (a cold start from
    that fix)."""

    every_s: float = KEYFRAMES_S
    long_side: int = 960
    max_iterations: int = 6
    converge_m: float = 0.05
    converge_deg: float = 0.05
    fine_within_m: float = 1.0
    fine_within_deg: float = 1.0
    match: MatchSettings = field(default_factory=MatchSettings)
    edges: EdgeSettings = field(default_factory=EdgeSettings)
    fuse: FuseSettings = field(default_factory=FuseSettings)
    estimate_delay: bool = True
    fine: bool = True
    by_geometry: bool = False
    geometry_fallback: bool = True
    chain_m: float = 3.0
    chain_s: float = 3.0
    chain_reach_m: float = 10.0
    reacquire_after_s: float = 2.0
    reacquire_every_s: float = 4.0
    reacquire_m: float = 30.0
    reacquire_accel: float = 1.0
    reacquire_max_m: float = 300.0
    unfixed_speed_mps: float = 20.0
    unfixed_max_m: float = 1000.0

    def lost_radius(self, lost_s: float) -> float:
        """The disc (m) a keyframe lost for lost_s seconds is searched over (the class doc)."""
        return min(self.reacquire_m + 0.5 * self.reacquire_accel * lost_s**2, self.reacquire_max_m)

    def unfixed_radius(self, away_s: float) -> float:
        """The disc (m) around the nearest fix, away_s seconds off, that a keyframe is searched
        over before any has registered (the class doc)."""
        return min(self.reacquire_m + self.unfixed_speed_mps * away_s, self.unfixed_max_m)


@dataclass(frozen=True)
class Registration:
    """Every keyframe's outcome (app.register.fuse.Keyframe), the prior source it corrected, and
    the time per stage (seconds: render, match (features, matching and pose), decode)."""

    prior: str
    keyframes: tuple[Keyframe, ...]
    stage_s: dict[str, float]
    control: ControlSolution | None = None  # control points by hand, applied to the prior first
    delay_s: float | None = (
        None  # how late the frame times were (s), estimated from the keyframes; None: not estimated
    )
    gnss: GnssCheck | None = None  # the GNSS fixes tested against the keyframes (issue 52)
    # the track the IMU's motion carries over the fixes kept and the keyframes used: each
    # frame's position sigma (app.register.inertial, app.solve.uncertainty)
    carried: inertial.Carried | None = None
    # registration lost, searched for as a cold start: (session time s, disc radius m, found)
    searched: tuple[tuple[float, float, bool], ...] = ()
    # keyframes a GNSS lie lost, registered again from the track carried through it and used
    # (session s)
    retried: tuple[float, ...] = ()

    @property
    def used(self) -> int:
        return sum(k.used for k in self.keyframes)

    @property
    def used_fraction(self) -> float:
        return self.used / max(1, len(self.keyframes))

    def summary(self) -> str:
        """One line for people: how many keyframes were used, the commonest reason not, and where
        none was, that the prior stands and what can correct it."""
        n = len(self.keyframes)
        line = f"registered {self.used} of {n} keyframes ({100 * self.used_fraction:.0f} %) against the scene, correcting {self.prior}"
        reasons = [k.reason.split(" (")[0] for k in self.keyframes if not k.used]
        if reasons:
            common = max(set(reasons), key=reasons.count)
            line += f"; {len(reasons)} not used (most often: {common})"
        if n and not self.used:
            line += (
                f"; the track is {self.prior}'s (control points by hand can correct it: V in the"
                " viewer, or `geofuse register SESSION.toml --points pairs.csv`)"
            )
        if self.searched:
            found = sum(f for _, _, f in self.searched)
            line += (
                f"; lost with no fix to trust, searched for {len(self.searched)} times within "
                f"{max(r for _, r, _ in self.searched):.0f} m, found again {found}"
            )
        if self.retried:
            line += f"; {len(self.retried)} lost under a GNSS lie registered again from the track carried through it"  # fmt: skip
        if self.delay_s is not None:
            line += f"; frame times {1000 * self.delay_s:+.1f} ms late, corrected"
        if self.control is not None:
            line += f"; control points by hand: boresight {self.control.boresight_deg:.2f} deg, median residual {np.median(self.control.residual_px):.1f} px"
        return line


@dataclass(frozen=True)
class KeyframePlot:
    """What the error panel plots of a registration: (seconds from the first frame, inliers) of
    the used and the unused keyframes, and the reprojection error (px) of the registered ones."""

    keyframes: tuple[Keyframe, ...]
    used: tuple[np.ndarray, np.ndarray]
    unused: tuple[np.ndarray, np.ndarray]
    error_t: np.ndarray
    error_px: np.ndarray

    def nearest(self, frame: int) -> Keyframe | None:
        """The keyframe nearest to video frame `frame`."""
        if not self.keyframes:
            return None
        return min(self.keyframes, key=lambda k: abs(k.index - frame))


def keyframe_plot(reg: Registration, t0: float) -> KeyframePlot:
    """The plot's arrays, times in seconds after session time t0 (the first frame's)."""

    def pick(flag: bool) -> tuple[np.ndarray, np.ndarray]:
        ks = [k for k in reg.keyframes if k.used == flag]
        return np.array([k.time_s - t0 for k in ks], np.float64), np.array(
            [k.inliers for k in ks], np.float64
        )

    solved = [k for k in reg.keyframes if k.registered]
    return KeyframePlot(
        reg.keyframes, pick(True), pick(False),
        np.array([k.time_s - t0 for k in solved], np.float64), np.array([k.error_px for k in solved], np.float64),
    )  # fmt: skip


def keyframe_indices(media_s: np.ndarray, every_s: float) -> np.ndarray:
    """Video frames (indices into media_s, increasing) nearest to every every_s seconds, and the
    last frame where the video ends more than half a spacing after the last of those: else its
    last frames would be carried past everything that measured them (where their fixes are
    rejected or missing, a weave's curve left as a straight line)."""
    if every_s <= 0:
        raise ValueError(f"keyframe spacing must be positive, got {every_s} s")
    targets = np.arange(media_s[0], media_s[-1] + 1e-9, every_s)
    if media_s[-1] - targets[-1] > every_s / 2:
        targets = np.append(targets, media_s[-1])
    return np.unique(np.clip(np.searchsorted(media_s, targets), 0, len(media_s) - 1))


def _moved(a: Camera, b: Camera) -> tuple[float, float]:
    """(metres, degrees) between two camera poses."""
    metres = float(np.linalg.norm(np.subtract(a.position, b.position)))
    return metres, float(np.degrees(rotations.angle_between(a.orientation, b.orientation)))


def _chained(
    keyframes: list[Keyframe],
    t: float,
    start: Camera,
    within_s: float,
    motion: inertial.Motion | None = None,
    correction: Correction | None = None,
) -> Camera | None:
    """`start` moved to where the last registered keyframes lead at session time t (s): with
    an accelerometer (`motion`), the last four within within_s seconds carried on by the IMU's
    motion (app.register.inertial.chained: a turn is followed), under the attitude the
    keyframes registered (correction's rotation at the last of them, held: the prior's tilt
    errs in a turn, where the attitude filter takes part of the turn's acceleration for
    gravity, and the motion with it); without, the last one's position carried on at the
    velocity from the one before it (ENU m, m/s); None where none is that recent."""
    solved = [k for k in keyframes[-4:] if k.registered and t - k.time_s <= within_s]
    if not solved:
        return None
    last = solved[-1]
    p = np.asarray(last.position, np.float64)
    times = [k.time_s for k in solved]
    if motion is not None and motion.felt and len(solved) > 1 and times[-1] > times[0]:
        if correction is not None and len(correction.t):
            _, dr = correction([times[-1]])
            motion = motion.turned(dr[0], (times[0], max(t, times[-1])))
        p = inertial.chained(motion, times, [k.position for k in solved], t)
    elif len(solved) > 1 and last.time_s > solved[-2].time_s:
        v = (p - np.asarray(solved[-2].position)) / (last.time_s - solved[-2].time_s)
        p = p + v * (t - last.time_s)
    return posed(start, p, np.asarray(start.orientation))


def _shifted(camera: Camera, correction: Correction, t: float) -> Camera:
    """The camera moved by the correction at session time t."""
    dp, dr = correction([t])
    return nudged(camera, dr[0], dp[0])


def by_geometry(mesh: MeshData) -> bool:
    """Whether a scene is registered by its geometry: it has no texture to match (no textured
    primitive, no streamed tileset: tiles are taken as textured)."""
    return not mesh.tilesets and not any(p.textured for p in mesh.primitives)


class Registrar:
    """Registers keyframes of one session's video against its scene (owns an off-screen GL
    context: use from one thread, then `release()`)."""

    def __init__(
        self,
        session: Session,
        settings: RegistrationSettings = RegistrationSettings(),
        ctx: moderngl.Context | None = None,
        background: bool = False,
    ) -> None:
        refusal = session.registration_refusal()
        if refusal is not None:
            raise GeofuseError(f"{session.path}: {refusal}")
        self._start(session.scene(), settings, ctx, background)
        self.session = session

    @classmethod
    def of_scene(
        cls,
        mesh: MeshData,
        settings: RegistrationSettings = RegistrationSettings(),
        background: bool = False,
        ctx: moderngl.Context | None = None,
    ) -> Registrar:
        """A registrar of single keyframes (`keyframe`) against a scene without a session (a
        live feed's, app.live.register); `run` needs a session. ctx: a GL context to render in
        (default: its own)."""
        self = cls.__new__(cls)
        self._start(mesh, settings, ctx, background)
        self.session = None
        return self

    def _start(self, mesh: MeshData, settings, ctx, background: bool) -> None:
        if background:
            _lower_priority()
        if by_geometry(mesh):
            settings = replace(settings, by_geometry=True)
        self.settings = settings
        self.mesh = mesh
        self.views = ModelViews(mesh, ctx)
        self.cut = cut_outline(mesh)  # where the model's data ends: no line (app.register.edges)
        self.matcher = Matcher(settings.match)
        self.stage_s = {"render": 0.0, "match": 0.0, "decode": 0.0}

    def keyframe(
        self, frame_rgb: np.ndarray, start: Camera, begin: Camera | None = None
    ) -> tuple[PoseFix, Camera | None, int]:
        """Render-and-compare from `start` (the frame's camera at full video size) until the pose
        converges: (the last step's fix, the solved camera or None, renderings made). By the
        scene's textures, and where they find no pose by its lines (geometry_fallback); by its
        lines alone where it has no texture. begin: where the search begins instead (the lines'
        fit is still held to `start` as its prior; the bench begins at the true pose, to measure
        what the lines' objective gives a perfect search)."""
        s = self.settings
        fix, solved, renders = self._keyframe(frame_rgb, start, s.by_geometry, begin)
        if solved is None and not s.by_geometry and s.geometry_fallback:
            lines, solved, more = self._keyframe(frame_rgb, start, True, begin)
            renders += more
            fix = (
                lines
                if solved is not None
                else replace(lines, reason=f"textures: {fix.reason}; lines: {lines.reason}")
            )
        return fix, solved, renders

    def _keyframe(
        self, frame_rgb: np.ndarray, start: Camera, by_geometry: bool, begin: Camera | None
    ) -> tuple[PoseFix, Camera | None, int]:
        s = self.settings
        scale = (
            frame_rgb.shape[1] / start.intrinsics.width
            if start.lens is None
            else frame_rgb.shape[1] / start.lens.width
        )
        cam, solved, fix, fine = begin or start, None, None, False
        for it in range(1, s.max_iterations + 1):
            small = cam.pinhole(scale)
            with _lap(self.stage_s, "render"):
                rgb, positions = self.views.render(small)
            with _lap(self.stage_s, "match"):
                frame = Frame(frame_rgb, scale, cam)
                rendering = Rendering(rgb, positions, small, self.cut)
                if by_geometry:
                    step = fit_edges(frame, rendering, s.edges, not fine, start)[0]
                elif fine:
                    step = refine(s.match, frame, rendering)
                else:
                    step = compare(self.matcher, frame, rendering)
            if not step.ok:
                if fine:  # the coarse pose stands
                    break
                return (fix or step), solved, it
            fix = step
            nxt = posed(cam, step.position, step.q)
            metres, degrees = _moved(cam, nxt)
            cam = solved = nxt
            if (fine or not s.fine) and metres < s.converge_m and degrees < s.converge_deg:
                break
            fine = fine or (s.fine and metres < s.fine_within_m and degrees < s.fine_within_deg)
        return fix, solved, it

    def run(
        self,
        prior: CameraTrack,
        progress: Callable[[float], None] | None = None,
        stop: Callable[[], bool] | None = None,
        begin: Callable[[int], Camera] | None = None,
        motion: inertial.Motion | None = None,
    ) -> Registration:
        """Every keyframe of the video registered, starting each from the prior's pose moved by
        the corrections found so far; the keyframes gated against their neighbours. stop() is
        asked before each keyframe: True raises Cancelled. begin(k): where the search of the
        keyframe at video frame k begins (keyframe's `begin`; default: its start). motion: the
        platform's acceleration the keyframes are chained by (app.register.inertial.motion_of
        under the prior's attitude, as `screened` found it; default: computed here)."""
        s = self.settings
        video = self.session.video
        idx = keyframe_indices(np.asarray(video.pts_s, np.float64), s.every_s)
        keyframes: list[Keyframe] = []
        frames = frames_at(video, idx, s.long_side)
        if motion is None:  # keyframes chained by the IMU
            motion = inertial.motion_of(self.session, prior.poses)
        last_t, searched_t = None, -np.inf  # the last keyframe registered; the last search
        held: list = []  # poses a search held for their attitude (coldstart.Search.agreed)
        searches: list[tuple[float, float, bool]] = []  # (t s, radius m, found)
        while True:
            with _lap(self.stage_s, "decode"):
                k, rgb = next(frames, (None, None))
            if k is None:
                break
            if stop is not None and stop():
                raise Cancelled(
                    f"registration of {video.path} cancelled after {len(keyframes)} of {len(idx)} keyframes"
                )
            prior_cam = prior.frame_camera(k)
            t = float(prior.clock.session_time([video.pts_s[k]])[0])
            so_far = Correction.from_keyframes(keyframes[-5:], s.fuse)
            first = None if begin is None else begin(int(k))
            start = _shifted(prior_cam, so_far, t)
            chained = _chained(keyframes, t, start, s.chain_s, motion, so_far)
            fix, solved, renders = None, None, 0
            starts = [start, prior_cam] if len(so_far.t) else [start]  # the plain prior last
            # where the prior moved unlike the scene (GNSS jumped or drags off) or stands on no
            # fix (rejected, missing: carried by the IMU, which drifts), from the scene first
            trusted = prior.fixes is None or prior.fixes.at([t])[0] == USED
            if chained is not None and (not trusted or _moved(start, chained)[0] > s.chain_m):
                starts.insert(0, chained)
            for searched in starts:
                fix, solved, more = self.keyframe(rgb, searched, first)
                renders += more
                off = None if solved is None or chained is None else _moved(solved, chained)[0]
                if off is not None and off > s.chain_reach_m:  # a false match on a repeated texture
                    fix, solved = replace(fix, reason=f"found {off:.0f} m from where the last keyframes lead"), None  # fmt: skip
                if solved is not None:
                    break
            if solved is not None and last_t is None and not trusted:
                # nothing to trust yet, neither a fix nor a keyframe: taken as a search takes
                # it, turned as the platform is (a frame of grass registers at a wrong pose)
                turn = float(np.degrees(rotations.angle_between(solved.orientation, prior_cam.orientation)))  # fmt: skip
                if turn > coldstart.SearchSettings().turn_tolerance_deg:
                    reason = f"registered {turn:.0f} deg from the platform's attitude, with no fix or keyframe to trust yet"  # fmt: skip
                    fix, solved = replace(fix, reason=reason), None
            lost = None if last_t is None else t - last_t
            due = t - searched_t > s.reacquire_every_s - 0.05
            if solved is None and lost is not None and lost > s.reacquire_after_s - 0.05:
                # where the last keyframes registered lead, however long ago
                lead = _chained([kf for kf in keyframes if kf.registered], t, start, np.inf, motion, so_far)  # fmt: skip
                drift = s.chain_m + 0.5 * s.reacquire_accel * lost**2  # what the lead may err by
                doubted = not trusted or (lead is not None and _moved(start, lead)[0] > drift)
                if doubted and due:
                    searched_t = t  # lost: searched for, as a cold start, where the keyframes
                    # lead and, where no fix holds the prior, where the IMU carried it
                    near = [c for c in (lead, None if trusted else start) if c is not None]
                    radius = s.lost_radius(lost)
                    fix, solved = self.reacquired(rgb, prior_cam, near or [start], radius, t, held, fix, f"lost {lost:.0f} s")  # fmt: skip
                    searches.append((t, radius, solved is not None))
            elif solved is None and last_t is None and not trusted and due:
                # none registered yet, no fix holding the prior (GNSS that begins late): the
                # platform is no farther from the nearest fix than it flies in the time between
                away = _to_fix(prior.fixes, t)
                if away is not None:
                    searched_t = t
                    radius = s.unfixed_radius(away)
                    fix, solved = self.reacquired(rgb, prior_cam, [start], radius, t, held, fix, f"{away:.0f} s from a fix")  # fmt: skip
                    searches.append((t, radius, solved is not None))
            if solved is not None:
                last_t = t
            keyframes.append(Keyframe(
                int(k), t, solved is not None, "" if solved is not None else fix.reason, fix.matches, fix.inliers, fix.error_px, renders,
                np.asarray(prior_cam.position), np.asarray(prior_cam.orientation),
                None if solved is None else np.asarray(solved.position), None if solved is None else np.asarray(solved.orientation),
            ))  # fmt: skip
            if progress is not None:
                progress(len(keyframes) / len(idx))
        return Registration(
            prior.source,
            tuple(gate(keyframes, s.fuse)),
            dict(self.stage_s),
            searched=tuple(searches),
        )

    def reacquired(
        self,
        rgb: np.ndarray,
        prior_cam: Camera,
        near: list[Camera],
        radius: float,
        t: float,
        held: list,
        fix: PoseFix,
        why: str,
        off_scene_ground_m: float | None = None,
    ) -> tuple[PoseFix, Camera | None]:
        """A keyframe searched for over discs of radius (m) around each of `near` (where the
        last keyframes lead, where the IMU carried the prior, the nearest fix; a live feed's
        home point), at the first one's height above the scene's ground under it (where the
        scene has none there: above off_scene_ground_m, ENU z m, and not searched where that is
        None), with the prior's attitude (prior_cam), from the first one out; a pose turned
        beyond the search's tolerance is taken where one held from an earlier search (`held`,
        session times t s) agrees. (fix, the pose or None); fix says what was found, or keeps
        the keyframe's reason with why it was searched ("lost 3 s")."""
        p = np.asarray(near[0].position, np.float64)
        ground = ground_heights(self.mesh, p[None, :2])
        z = float(ground[0]) if len(ground) and np.isfinite(ground[0]) else off_scene_ground_m
        height = float(p[2] - z) if z is not None else np.nan
        if not np.isfinite(height) or height <= 0.0:
            return fix, None
        discs = [shapely.Point(*np.asarray(c.position)[:2]).buffer(radius) for c in near]
        search = coldstart.Search(
            self.mesh,
            self.views,
            lambda frame, start: self.keyframe(frame, start)[:2],
            shapely.union_all(discs),
            p[:2],
            height,
            coldstart.SearchSettings(margin_m=0.0),  # the disc is the uncertainty already
        )
        verified = search.frame(rgb, prior_cam)[0]
        if verified.camera is None:
            verified = search.agreed(held, t)[0]
        if verified.camera is None:
            return replace(fix, reason=f"{fix.reason}; {why}, not found within {radius:.0f} m"), None  # fmt: skip
        found = verified.camera
        return PoseFix(True, "", verified.inliers, verified.inliers, verified.error_px, np.asarray(found.position), np.asarray(found.orientation)), found  # fmt: skip

    def retried(
        self,
        keyframes: list[Keyframe],
        prior: CameraTrack,
        spans: list[tuple[float, float]],
        carried: inertial.Carried,
        stop: Callable[[], bool] | None = None,
        motion: inertial.Motion | None = None,
    ) -> list[Keyframe]:
        """The keyframes inside spans (session s: where the GNSS lied, and the first pass
        started them from its fixes) that no fused track takes, registered again in time order:
        from where the keyframes registered within chain_s before lead (_chained, by `motion`:
        those used and those this found), then from the prior's pose (the track the scene and
        the IMU carry there) under the keyframes' correction, then from the prior alone. A pose
        farther than chain_reach_m from where those keyframes lead is not taken (a false match
        on a repeated texture, a period away: the carry may stand half of one off), nor, where
        none leads, one farther from the prior than chain_reach_m plus three of the carry's
        horizontal sigma (m). Those that register replace their first pass's, used again (gate
        them); the list itself where none does. stop() is asked before each: True raises
        Cancelled."""
        s = self.settings
        video = self.session.video
        todo = {
            kf.index: n
            for n, kf in enumerate(keyframes)
            if not kf.used and any(a <= kf.time_s <= b for a, b in spans)
        }
        if not todo:
            return keyframes
        correction = Correction.from_keyframes(keyframes, s.fuse)
        out, found = list(keyframes), set()
        for k, rgb in frames_at(video, sorted(todo), s.long_side):
            if stop is not None and stop():
                raise Cancelled(f"registration of {video.path} cancelled while keyframes a lie lost were tried again")  # fmt: skip
            kf = keyframes[todo[k]]
            prior_cam = prior.frame_camera(k)
            behind = [b for b in out if b.time_s < kf.time_s and (b.used or b.index in found)]
            chained = _chained(behind, kf.time_s, prior_cam, s.chain_s, motion, correction)
            if chained is None:
                lead, reach = prior_cam, s.chain_reach_m + 3.0 * np.hypot(*carried.at([kf.time_s])[1][0, :2])  # fmt: skip
            else:
                lead, reach = chained, s.chain_reach_m
            starts = [_shifted(prior_cam, correction, kf.time_s), prior_cam]
            renders = kf.iterations
            for start in starts if chained is None else [chained, *starts]:
                fix, solved, more = self.keyframe(rgb, start)
                renders += more
                if solved is not None and _moved(solved, lead)[0] <= reach:
                    out[todo[k]] = Keyframe(
                        int(k), kf.time_s, True, "", fix.matches, fix.inliers, fix.error_px, renders,
                        np.asarray(prior_cam.position), np.asarray(prior_cam.orientation),
                        np.asarray(solved.position), np.asarray(solved.orientation),
                    )  # fmt: skip
                    found.add(int(k))
                    break
        return out if found else keyframes

    def release(self) -> None:
        self.views.release()


def _to_fix(fixes: FixStatus | None, t: float) -> float | None:
    """Seconds (s) from session time t to the nearest fix not rejected, either side; None
    where there is none."""
    if fixes is None:
        return None
    kept = fixes.t[~fixes.rejected]
    return float(np.min(np.abs(kept - t))) if len(kept) else None


def _lower_priority() -> None:
    """Run this thread (and the rasteriser threads its GL context starts) at a lower priority, so
    that a viewer playing on the same cores keeps its frame rate (Linux: a thread's own nice
    value); elsewhere nothing."""
    if hasattr(os, "setpriority") and hasattr(threading, "get_native_id"):
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)
        except OSError:
            pass


@contextmanager
def _lap(totals: dict[str, float], key: str) -> Iterator[None]:
    """Adds the seconds spent inside the block to totals[key] (benchmark figures only: nothing
    decides by them)."""
    start = time.perf_counter()
    try:
        yield
    finally:
        totals[key] += time.perf_counter() - start


def default_prior(session: Session) -> str:
    """The source registration corrects: the offline filter where the session has an IMU, else
    its first source (a recorded or derived attitude)."""
    own = [s for s in session.sources if s not in (REGISTERED, "truth")]
    if not own:
        raise GeofuseError(f"{session.path}: no attitude source to start registration from")
    return "offline" if "offline" in own else own[0]


def registered_track(
    session: Session,
    prior: str | None = None,
    settings: RegistrationSettings = RegistrationSettings(),
    progress: Callable[[float], None] | None = None,
    ctx: moderngl.Context | None = None,
    stop: Callable[[], bool] | None = None,
    background: bool = False,
    begin: Callable[[int], Camera] | None = None,
    **track_options: object,
) -> CameraTrack:
    """The camera track of the `registered` source: the prior source's track (default_prior)
    corrected by the keyframes registered against the scene; `registration` holds every
    keyframe's outcome. Control points kept beside the input (`geofuse register --write`)
    correct the prior first. ctx: a GL context to render in (default: one of its own); stop:
    asked between keyframes, True cancels (Cancelled); background: run at a lower priority (the
    viewer's solver thread); begin(k): where keyframe k's search begins (Registrar.run). track_options go to app.session.camera_track.camera_track for the prior."""
    source, control = prior or default_prior(session), None
    cold = coldstart.searched(session)  # no GNSS fix at all, an area to search
    if not cold:
        prior_track = camera_track(session, source, **track_options)
    if not cold and control_path(session.path).is_file():
        # points given by hand: the automatic keyframes start from them
        control = solve_control(prior_track, read_points(control_path(session.path)))
        for note in control.notes:
            session.messages.add_once(f"control: {note}", note)
        prior_track = corrected_track(prior_track, control)
    screen = None
    if not cold:  # the fixes tested against the IMU first: a lie it catches moves no start
        fixes_track, screen = prior_track, inertial.screened(session, prior_track)
        prior_track = screen.track
    registrar = Registrar(session, settings, ctx, background)
    try:
        if cold:
            prior_track = coldstart.started(session, source, registrar, **track_options)
        motion = None if screen is None else screen.motion  # the same attitude's
        reg = registrar.run(prior_track, progress, stop, begin, motion)
        keyframes = list(reg.keyframes)
        if cold:  # the positions are the scene's own, through the registered keyframes
            prior_track = coldstart.on_scene(session, prior_track, keyframes)
            keyframes = _regated(keyframes, prior_track, settings)
        check, carried, retried = None, None, ()
        if screen is not None:
            prior_track, keyframes, check, carried, retried = _witnessed(
                session, fixes_track, prior_track, keyframes, screen, settings, registrar, stop
            )
    finally:
        registrar.release()
    delay = (
        estimate_delay(keyframes, prior_track.poses, settings.fuse)
        if settings.estimate_delay
        else None
    )
    if delay is not None:
        keyframes = _regated(keyframes, prior_track, settings, delay)
    poses = corrected_pose_track(
        prior_track.poses, Correction.from_keyframes(keyframes, settings.fuse), delay or 0.0
    )
    reg = replace(
        reg,
        keyframes=tuple(keyframes),
        control=control,
        delay_s=delay,
        gnss=check,
        carried=carried,
        retried=retried,
    )
    fixes = prior_track.fixes if check is None else check.status
    return replace(prior_track, source=REGISTERED, poses=poses, registration=reg, fixes=fixes)


def _witnessed(
    session: Session,
    fixes_track: CameraTrack,
    prior_track: CameraTrack,
    keyframes: list[Keyframe],
    screen: inertial.Screened,
    settings: RegistrationSettings,
    registrar: Registrar,
    stop: Callable[[], bool] | None = None,
) -> tuple[CameraTrack, list[Keyframe], GnssCheck, inertial.Carried, tuple[float, ...]]:
    """The fixes tested against the keyframes and against the IMU (screen), and the track
    carried through what they reject: (the prior placed on that carry, the keyframes gated
    under it, the check as said, the carry, the session times (s) of the keyframes a lie lost
    that registered again from the carry: Registrar.retried, asking stop()); the lies said in
    the session's messages."""
    check = _tested(session, fixes_track, keyframes, screen)
    # where the GNSS lied or is missing the prior is carried by the IMU between the fixes
    # kept and the keyframes: no fusion across a lie, no straight line across an outage
    seen = Seen()  # the video's own motion, tracked once for the carries below
    positions, carried, said = _carried(session, fixes_track, keyframes, check, settings, seen)
    retried: tuple[float, ...] = ()
    if positions is not fixes_track.poses.positions or prior_track is not fixes_track:
        prior_track = _placed(fixes_track, positions)
        keyframes = _regated(keyframes, prior_track, settings)
        if not screen.motion.felt and check.lies:
            # no IMU screened the prior: the keyframes that the lie's own corrections made
            # disagree with their neighbours (at its edge) witness again, under the prior
            # the scene now carries, and the fixes they see are tested anew (else the
            # honest ones before a jump, untested, are taken into the lie)
            check, prior_track, keyframes, carried = _recarried(
                session, fixes_track, keyframes, screen, settings, seen
            )
        again_s: set[float] = set()
        for _ in range(RETRY_ROUNDS):  # again from each carry the ones found make anew
            spans = [(lie.began_s, lie.ended_s) for lie in check.lies]
            again = registrar.retried(keyframes, prior_track, spans, carried, stop, screen.motion) if spans else keyframes  # fmt: skip
            if again is keyframes:
                break
            # some registered: the fixes they see tested, carried anew
            again_s |= {b.time_s for a, b in zip(keyframes, again, strict=True) if b is not a}
            check, prior_track, keyframes, carried = _recarried(
                session, fixes_track, _regated(again, prior_track, settings), screen, settings, seen
            )
        retried = tuple(k.time_s for k in keyframes if k.used and k.time_s in again_s)
        _, carried, said = _carried(session, fixes_track, keyframes, check, settings, seen)
    check = said
    t0 = float(session.frame_times[0])
    for lie in check.lies:
        session.messages.add_once(f"gnss-lie-{lie.began_s:.1f}", lie.said(t0, session.utc_of))
    if carried.said:  # the final carry's: the earlier ones stood on keyframes gated since
        session.messages.add_once(f"flow-{carried.said}", carried.said)
    return prior_track, keyframes, check, carried, retried


def _tested(
    session: Session,
    fixes_track: CameraTrack,
    keyframes: list[Keyframe],
    screen: inertial.Screened,
) -> GnssCheck:
    """The fixes tested against the keyframes (tested_fixes), merged with the IMU's test."""
    return merged(tested_fixes(session, fixes_track, keyframes), screen.check)


def _recarried(
    session: Session,
    fixes_track: CameraTrack,
    keyframes: list[Keyframe],
    screen: inertial.Screened,
    settings: RegistrationSettings,
    seen: Seen,
) -> tuple[GnssCheck, CameraTrack, list[Keyframe], inertial.Carried]:
    """The fixes the keyframes witness tested anew (_tested), the track carried through what
    they reject and the keyframes gated under it: (the check, the prior placed on the carry,
    the keyframes, the carry)."""
    check = _tested(session, fixes_track, keyframes, screen)
    positions, carried, _ = _carried(session, fixes_track, keyframes, check, settings, seen)
    prior_track = _placed(fixes_track, positions)
    return check, prior_track, _regated(keyframes, prior_track, settings), carried


def _regated(
    keyframes: list[Keyframe],
    prior: CameraTrack,
    settings: RegistrationSettings,
    delay_s: float = 0.0,
) -> list[Keyframe]:
    """The keyframes gated anew against the prior's poses, their frame times delay_s late
    (every registered one a candidate again)."""
    return gate(retimed(_ungated(keyframes), prior.poses, delay_s), settings.fuse)


def _placed(track: CameraTrack, positions: PositionTrack) -> CameraTrack:
    """The track with its positions replaced (its attitude as it was)."""
    return replace(track, poses=replace(track.poses, positions=positions))


def _ungated(keyframes: list[Keyframe]) -> list[Keyframe]:
    """The keyframes with every registered one used again (before gating them anew)."""
    return [
        replace(k, used=k.registered, reason="" if k.registered else k.reason) for k in keyframes
    ]


def tested_fixes(
    session: Session,
    prior: CameraTrack,
    keyframes: list[Keyframe],
    settings: CheckSettings | None = None,
) -> GnssCheck:
    """The prior's GNSS fixes tested against the registered keyframes' positions
    (app.register.gnss.check_fixes), with the accuracy the session's GNSS states."""
    fixes = prior.poses.positions
    enu = prior.poses.frame.geodetic_to_enu(fixes.lat, fixes.lon, fixes.h)
    acc = (
        session.gnss.h_acc
        if session.gnss.h_acc is not None and len(session.gnss.h_acc) == len(fixes.t)
        else None
    )
    # witnesses: the keyframes the gate kept (each agreeing with its neighbours), not every one
    # registered: a run of keyframes registered wrongly on a scene of repeated textures would
    # otherwise accuse a clean GNSS
    solved = [k for k in keyframes if k.used]  # used: registered, and kept by the gate
    key_t = np.array([k.time_s for k in solved], np.float64)
    key_enu = np.array([k.position for k in solved], np.float64).reshape(-1, 3)
    return check_fixes(fixes.t, enu, acc, key_t, key_enu, settings or CheckSettings())


def _carried(
    session: Session,
    fixes_track: CameraTrack,
    keyframes: list[Keyframe],
    check: GnssCheck,
    settings: RegistrationSettings,
    seen: Seen,
) -> tuple[PositionTrack, inertial.Carried, GnssCheck]:
    """app.register.inertial.carried_track under the keyframes' attitude correction (seen:
    the corners the video's motion tracked in the solve's carries so far)."""
    correction = Correction.from_keyframes(keyframes, settings.fuse)
    return inertial.carried_track(session, fixes_track, keyframes, check, correction, seen=seen)
