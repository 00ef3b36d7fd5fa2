"""Registration of a live feed, forward only: keyframes registered in the background against the
scene (app.register's render-and-compare), and the correction they find applied to the frames
drawn from then on, never to frames already drawn.

The correction is a bias, as a GNSS position and a gimbal's angles carry one: a shift (ENU m, the
position's) and a rotation in the camera's own frame (the angles': a gimbal's heading, pitch or
mounting bias stays the same turn of the camera while the aircraft turns, which a rotation fixed in
the world would not) between the telemetry's camera and the registered one. The applied rotation is
the median of the last KEEP kept keyframes' (by its rotation vector). The applied shift, while the
keyframe's fix agrees with the scene, is the median of the last KEEP agreeing keyframes' within
KEEP_S of the newest (componentwise: a GNSS wanders by about a metre in a few seconds, and an older
keyframe's shift only lags it). Where the GNSS lies (app.live.gnss_watch: the newest keyframe's own
fix beyond its threshold, before any alarm is said) the drawn pose stands on the scene: the shift
is the line through the last LIE_FIT disagreeing keyframes' shifts (Theil-Sen; fewer than three:
the newest held; an axis moving slower than RATE_MIN_MPS: their median; a line they do not lie on,
LINE_M: their median), carried on in time (a drag-off grows steadily, a
jump holds) for at most HOLD_S past the newest.

Each keyframe is searched from the camera drawn at its time (the telemetry's, corrected); before
that from where the last two registered keyframes lead at constant velocity, and from where the
last one leads carried by the telemetry's own motion since (its steps faster than any platform left
out: a jump), each where it lies more than RegistrationSettings.chain_m from those tried after it
(a GNSS that jumps or drags off must not lose the scene); last from the telemetry's own camera. A
keyframe is kept where it agrees with the correction (within GATE_M of the camera drawn) or with
the scene's own motion (within the chain's reach, chain_m plus half ACCEL_MPS2 t^2 up to
CHAIN_MAX_M, of where the last two registered keyframes, within CHAIN_S, lead, or where the last
one leads carried by the telemetry's motion): once GATED have been kept, one that agrees with none
is set aside (counted) as a mismatch; once TURN_GATED have been kept, so is one whose rotation
lies more than GATE_DEG from the median of theirs (a GNSS lie moves the position, never the
attitude: such a keyframe registered astray, and leads no chain). The rotation is gated only once the telemetry's
attitude is settled (`settled`: a MAVLink feed's once the video's lag behind it is estimated,
until then the turns show the lag), and from the keyframes kept since: those before had the lag
in them. A keyframe is offered every `every_s` of video while the
thread is free (never queued: the newest frame is what matters live); the display never waits.

A feed without a current fix (`unfixed`: its newest held, older than HELD_S and HELD_INTERVALS of
its usual interval, through
an outage; or none at all, app.io.mavlink: the camera stands at the home point, at the
barometer's height above it) is carried by the scene: a held fix is no fix to test, nor to follow
(until CARRIED_FROM keyframes have registered since it was lost, the frames are drawn where the
last two registered lead at their velocity).
Where no keyframe has registered yet, it is searched for as a cold start searches (app.register.coldstart,
through Registrar.reacquired): the first keyframe over a disc of search_radius_m around the home
point, at that height, with the telemetry's attitude, each search that ran over the scene and
missed widening the disc WIDEN times, up to the settings' unfixed_max_m (a stream joined
mid-flight: the aircraft may be farther from home than the disc asked; what a search costs
grows with the scene inside the disc, not with its area); once found, the drawn pose stands on
the scene, its shift moving as the last two keyframes do (as under a frozen fix), each keyframe
registered from where they lead (frames are drawn from the second kept, CARRIED_FROM: the first
gives no velocity); one not registered for LOST_S is searched for again over the
disc a lost keyframe is (RegistrationSettings.lost_radius) around where they lead. No fix is
tested (there is none): every frame's GNSS is `missing`.

One thread with its own off-screen GL context renders the scene for the matcher.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.stats import theilslopes

from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_START_RADIUS_M
from app.core.messages import INFO, Messages
from app.core.worker import Worker
from app.geodesy import rotations
from app.io.streams import MAX_SPEED_MPS
from app.live.gnss_watch import GnssWatch
from app.playback.decoder import planes_to_rgb
from app.register.gnss import FROZEN
from app.register.keyframe import PoseFix, posed
from app.register.solve import Registrar, RegistrationSettings
from app.scene.mesh import MeshData

EVERY_S = 1.0  # a keyframe offered every this much video (s)
KEEP = 5
KEEP_S = 3.0  # the agreeing keyframes' shifts a median is taken of: within this of the newest (s)
GATE_M, GATE_DEG, GATED = 2.0, 1.5, 3
TURN_GATED = 2  # the rotation is gated once this many keyframes are kept (the attitude is not GNSS)
CHAIN_S = 6.0  # the chain: the last two registered keyframes within this many seconds
CHAIN_MAX_M = 10.0  # the chain's reach at most (keyframes far apart: a gate that keeps anything)
STEP_S = 0.1  # the telemetry's motion since the last registered keyframe summed in these steps (s)
LIE_FIT = 4  # disagreeing keyframes the shift's line is drawn through
RATE_MIN_MPS = 0.3  # slower, a line through a few keyframes is their own noise (~0.1 m)
LINE_M = 1.0  # a keyframe farther than this from the line drawn through its run is off it (m)
HOLD_S = 5.0  # the line carried on at most this long past the newest keyframe (s)
ACCEL_MPS2 = 3.0  # the platform's acceleration the chain allows for (a drone's weave: 3.3)
LOST_S = 2.0  # without a fix: a keyframe not registered for this long is searched for (s)
# a fix older than HELD_S and HELD_INTERVALS of the feed's usual interval is held, not current:
# the scene carries the pose (MAVLink's 10 Hz: 0.5 s; a KLV feed's 1 Hz sets: 3 s)
HELD_S, HELD_INTERVALS = 0.5, 3.0
UNFIXED_EVERY_S = 0.5  # without a fix a keyframe is offered this often (s): they carry the position
# without a fix, frames are drawn once this many keyframes are kept: one alone gives no velocity,
# and the platform flies on while the next registers (10-25 m drawn off in a real-time bench)
CARRIED_FROM = 2
HELD_POSES = 8  # turned poses a search found, kept for a later one to agree with
WIDEN = 2.0  # never found: each search that misses widens the disc around home this many times
LIVE_SETTINGS = RegistrationSettings(long_side=640, max_iterations=5)


@dataclass(frozen=True)
class Kept:
    """A keyframe kept: media time (s), shift (ENU m) and rotation vector (rad, camera frame)
    from the telemetry's camera to the registered one, and whether the pose stands on the scene
    there: its fix disagreed with the scene beyond the threshold, or a lie was going on
    (app.live.gnss_watch.Verdict), or no current fix placed it (`unfixed`: the shift stood on
    a held fix or a home point, and means nothing once a fix is back)."""

    t_s: float
    shift: np.ndarray
    rotvec: np.ndarray
    on_scene: bool
    unfixed: bool = False


@dataclass
class LiveCorrection:
    """What registration has found so far: keyframes tried, registered, set aside; the applied
    shift (ENU m) at media time at_s, growing at rate_mps (ENU m/s, zero while the GNSS agrees)
    and rotation (rotation vector, rad, camera frame); the first media time it applied from."""

    tried: int = 0
    registered: int = 0
    mismatched: int = 0
    shift_m: np.ndarray | None = None
    rotvec: np.ndarray | None = None
    since_s: float | None = None
    last_failure: str = ""
    kept: list[Kept] = field(default_factory=list)
    rate_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    at_s: float = 0.0

    def shift_at(self, t_s: float) -> np.ndarray:
        """The shift (ENU m) applied to the frame of media time t_s (s)."""
        dt = float(np.clip(t_s - self.at_s, -HOLD_S, HOLD_S))
        return self.shift_m + self.rate_mps * dt

    def line(self) -> str:
        if self.shift_m is None:
            why = f" (the last: {self.last_failure})" if self.last_failure else ""
            return f"registered: none of {self.tried} keyframes{why}"
        return (
            f"registered: {self.registered} of {self.tried} keyframes ({self.mismatched} set aside), "
            f"correction {np.linalg.norm(self.shift_m):.2f} m, {np.degrees(np.linalg.norm(self.rotvec)):.2f} deg, "
            f"applied from {self.since_s:.1f} s"
        )


class LiveRegistration(Worker):
    """See the module docstring. mesh: the scene (textured: app.session.model.scene_refusal);
    watch: where each kept keyframe's fix is tested against the scene (None: not tested);
    accuracy_at(media s): the accuracy (m) the feed states for its fix then, None: none;
    fix_at(media s): the telemetry's position then (ENU m, None: none yet); jumps_between(a, b):
    the (from, to) media times of the steps in the telemetry's position no platform makes,
    drawn in (a, b] (app.live.pose: LivePoses.jumps_between, MavlinkPoses.jumps_between; none:
    never held off); unfixed(media s): whether the telemetry's camera then stands where no fix
    put it (a home point, searched around over search_radius_m: the module docstring)."""

    def __init__(
        self,
        mesh: MeshData,
        messages: Messages,
        every_s: float = EVERY_S,
        settings: RegistrationSettings = LIVE_SETTINGS,
        watch: GnssWatch | None = None,
        accuracy_at: Callable[[float], float | None] = lambda t: None,
        fix_at: Callable[[float], np.ndarray | None] = lambda t: None,
        jumps_between: Callable[[float, float], list[tuple[float, float]]] = lambda a, b: [],
        unfixed: Callable[[float], bool] = lambda t: False,
        search_radius_m: float = DEFAULT_START_RADIUS_M,
        settled: Callable[[], bool] = lambda: True,
        around: Callable[[], str] = lambda: "the telemetry's camera",
    ) -> None:
        self.mesh, self.messages, self.every_s, self.settings = mesh, messages, every_s, settings
        self.watch, self.accuracy_at, self.fix_at = watch, accuracy_at, fix_at
        self.jumps_between = jumps_between
        self.unfixed, self.search_radius_m = unfixed, search_radius_m
        self.radius_m = search_radius_m  # the disc searched around home now (widened: WIDEN)
        self._held: list = []  # poses a search found turned too far: (t, position, offset)
        self.settled, self.around = settled, around  # (around: what a search stood on, said)
        self._settled_s: float | None = None  # media s from which the rotation is gated
        self.state = LiveCorrection()
        self._lock = threading.Lock()
        self._offer: tuple[float, tuple, Camera] | None = None
        self._last_offered: float | None = None
        self._solved: list[tuple[float, np.ndarray]] = []  # the last registered: (t, ENU m)
        self._busy = False
        super().__init__("geofuse-register")

    def offer(self, t: float, planes, prior: Camera, unfixed: bool | None = None) -> None:
        """A frame drawn (media time t s, its yuv planes, the telemetry's camera; unfixed: the
        caller's `unfixed(t)` where it has it): taken as the next keyframe when every_s has
        passed since the last (UNFIXED_EVERY_S while no fix is current or the watch is in
        doubt) and the thread is free."""
        since = math.inf if self._last_offered is None else t - self._last_offered
        if self._busy or since < min(UNFIXED_EVERY_S, self.every_s):
            return
        if since < self.every_s:  # sooner only where the keyframes carry the pose (no fix) or
            # tell a drag-off sooner (a fix in doubt): asked only then, not on every frame
            unfixed = self.unfixed(t) if unfixed is None else unfixed
            if not (unfixed or (self.watch is not None and self.watch.suspect)):
                return
        self._last_offered = t
        with self._lock:
            self._offer = (t, tuple(np.array(p, copy=True) for p in planes), prior)
        self._busy = True
        self._wake.set()

    @property
    def busy(self) -> bool:
        """Whether a keyframe is being registered (offered and not yet done)."""
        return self._busy

    def held_off(self, t: float) -> np.ndarray | None:
        """The telemetry's jumps (ENU m, summed) since the newest keyframe kept, up to media
        time t (s): a step no platform makes is not drawn until a keyframe past it registers
        (the scene says whether the fix or the track before it was right); None where there is
        none, or no correction yet."""
        with self._lock:
            at = self.state.at_s if self.state.shift_m is not None else None
        if at is None:
            return None
        steps = []
        for t0, t1 in self.jumps_between(at, t):  # as far as the step is drawn by t
            before, after = self.fix_at(t0), self.fix_at(min(t1, t))
            if before is not None and after is not None:
                steps.append(np.asarray(after, np.float64) - before)
        return np.sum(steps, axis=0) if steps else None

    def correct(self, camera: Camera, t: float) -> Camera:
        """The telemetry's camera of media time t (s) moved by the correction in force, less
        the jumps held off (`held_off`); itself before any correction."""
        return self.corrected(camera, t)[0]

    def corrected(
        self, camera: Camera, t: float, unfixed: bool | None = None
    ) -> tuple[Camera, float]:
        """(`correct`'s camera, how far (m) the jumps held off in it are: 0 where none is);
        unfixed: the caller's `unfixed(t)` where it has it."""
        jump = self.held_off(t)
        unfixed = self.unfixed(t) if unfixed is None else unfixed
        lead = self._chained(t) if unfixed else None
        with self._lock:
            s = self.state
            if s.shift_m is None:
                return camera, 0.0
            shift, rotvec = s.shift_at(t), s.rotvec
            carried = all(k.on_scene for k in s.kept[-CARRIED_FROM:])
            if not unfixed and s.kept and s.kept[-1].unfixed:  # a fix back: the shifts stood
                shift = np.zeros(3)  # on a held fix or a home point; the fix as it is, until a
                # keyframe is kept under it
            elif lead is not None and not carried:  # a fix just lost: too few keyframes since
                shift = lead[0] - np.asarray(camera.position)  # to move by; they lead on
        if jump is not None:
            shift = shift - jump
        q = rotations.multiply(
            np.asarray(camera.orientation, np.float64), rotations.from_rotvec(rotvec)
        )
        moved = Camera.create(
            camera.intrinsics,
            np.asarray(camera.position) + shift,
            q,
            camera.near,
            camera.far,
            camera.lens,
        )
        return moved, 0.0 if jump is None else float(np.linalg.norm(jump))

    def _run(self) -> None:
        registrar = Registrar.of_scene(self.mesh, self.settings, background=True)
        try:
            while not self._stop.is_set():
                self._wake.wait(0.5)
                self._wake.clear()
                with self._lock:
                    offer, self._offer = self._offer, None
                if offer is None:
                    continue
                try:
                    self._keyframe(registrar, *offer)
                finally:
                    self._busy = False
        finally:
            registrar.release()

    def _chained(self, t: float) -> tuple[np.ndarray, float] | None:
        """(where the last two registered keyframes, within CHAIN_S of t, lead at constant
        velocity at media time t (ENU m), how far ahead that is (s)); None where they do not."""
        near = [(k, p) for k, p in self._solved[-2:] if t - k <= CHAIN_S]
        if len(near) < 2 or near[1][0] <= near[0][0]:
            return None
        (ta, pa), (tb, pb) = near
        return pb + (pb - pa) / (tb - ta) * (t - tb), t - tb

    def _carried(self, t: float) -> np.ndarray | None:
        """Where the last registered keyframe leads at media time t carried by the telemetry's
        own motion since (ENU m), summed over STEP_S steps, those faster than any platform
        (app.io.streams.MAX_SPEED_MPS: a jump) left out; None before any or without a fix."""
        if not self._solved:
            return None
        t1, p1 = self._solved[-1]
        times = np.linspace(t1, t, max(2, int(np.ceil((t - t1) / STEP_S)) + 1))
        fixes = [self.fix_at(float(x)) for x in times]
        if any(f is None for f in fixes):
            return None
        steps = np.diff(np.asarray(fixes, np.float64), axis=0)
        dt = max(float(times[1] - times[0]), 1e-6)
        steps[np.linalg.norm(steps[:, :2], axis=1) > MAX_SPEED_MPS * dt] = 0.0
        return p1 + steps.sum(axis=0)

    def _search(self, registrar: Registrar, rgb, t: float, prior: Camera):
        """(the last try's fix, the solved camera or None, the camera drawn at t, the chain's
        lead (position, seconds ahead) or None, whether it was searched for over an area: the
        search's own checks stand for the gate): see the module docstring's order."""
        start = self.correct(prior, t)
        if self.unfixed(t) and not self._solved:  # never found: around the telemetry's camera
            radius = self.radius_m
            asked = PoseFix(False, "no GNSS fix", 0, 0, float("nan"))
            fix, solved = self._area(registrar, rgb, t, prior, radius, "no GNSS fix", asked)
            widest = max(self.search_radius_m, self.settings.unfixed_max_m)
            # widened only after a search that ran over the scene and missed (not where the
            # camera stands on the ground, or no scene lies under it: the fix is returned as is)
            if solved is None and fix is not asked and radius < widest:
                self.radius_m = min(radius * WIDEN, widest)
                self.messages.add_once(
                    f"live-widen-{self.radius_m:.0f}",
                    f"not found within {radius:.0f} m of {self.around()}: searching within {self.radius_m:.0f} m",
                    INFO,
                )
            return fix, solved, start, None, True
        fix, solved, start, chain = self._tried(registrar, rgb, t, prior, start)
        lost = t - self._solved[-1][0] if self._solved else 0.0
        if solved is None and self.unfixed(t) and lost >= LOST_S:
            near = posed(start, chain[0], np.asarray(start.orientation)) if chain else start
            radius = self.settings.lost_radius(lost)
            fix, solved = self._area(registrar, rgb, t, near, radius, f"lost {lost:.0f} s", fix)
            return fix, solved, start, chain, True
        return fix, solved, start, chain, False

    def _area(self, registrar: Registrar, rgb, t: float, around: Camera, radius: float, why: str, fix=None):  # fmt: skip
        """(fix, the pose or None) of a keyframe searched for within radius (m) of `around`
        (Registrar.reacquired), at its height above the scene's ground (above the frame's
        origin, the home's ground, where the scene has none under it)."""
        fix = fix if fix is not None else PoseFix(False, why, 0, 0, float("nan"))
        found = registrar.reacquired(rgb, around, [around], radius, t, self._held, fix, why, 0.0)
        del self._held[:-HELD_POSES]  # (the newest: an earlier frame's pose to agree with)
        return found

    def _tried(self, registrar: Registrar, rgb, t: float, prior: Camera, start: Camera):
        """_search's tries from the camera drawn (`start`), the chain and the telemetry's motion."""
        chain = self._chained(t)
        tries = [start]
        heads = [chain[0]] if chain is not None else []
        carried = self._carried(t)
        if carried is not None:
            heads.append(carried)
        for head in reversed(heads):  # the chain first, then the fix's motion, then `start`
            if all(np.linalg.norm(head - np.asarray(c.position)) > self.settings.chain_m for c in tries):  # fmt: skip
                tries.insert(0, posed(start, head, np.asarray(start.orientation)))
        if start is not prior and not self.unfixed(t):  # (a home point is no place to try)
            tries.append(prior)
        fix = None
        for cam in tries:
            fix, solved, _ = registrar.keyframe(rgb, cam)
            if solved is not None:
                return fix, solved, start, chain
        return fix, None, start, chain

    def _keyframe(self, registrar: Registrar, t: float, planes, prior: Camera) -> None:
        rgb = planes_to_rgb(planes)
        long_side = max(rgb.shape[:2])
        if long_side > self.settings.long_side:
            f = self.settings.long_side / long_side
            rgb = cv2.resize(
                rgb,
                (round(rgb.shape[1] * f), round(rgb.shape[0] * f)),
                interpolation=cv2.INTER_AREA,
            )
        fix, solved, start, chain, searched = self._search(registrar, rgb, t, prior)
        unfixed = self.unfixed(t)
        s = self.state
        s.tried += 1
        if solved is None:
            s.last_failure = fix.reason
            return
        where = np.asarray(solved.position, np.float64)
        shift = where - np.asarray(prior.position)
        delta = rotations.multiply(
            rotations.conjugate(np.asarray(prior.orientation)), np.asarray(solved.orientation)
        )
        rotvec = rotations.to_scipy(delta).as_rotvec()
        if self._settled_s is None and self.settled():
            self._settled_s = t
        gating = [k.rotvec for k in s.kept if self._settled_s is not None and k.t_s >= self._settled_s]  # fmt: skip
        turned = (  # (no fix: no GNSS lie to tell from the telemetry's attitude, held in turns)
            not unfixed
            and len(gating) >= TURN_GATED
            and np.degrees(np.linalg.norm(rotvec - np.median(gating, axis=0))) > GATE_DEG
        )
        gated = len(s.kept) >= GATED and not searched
        agrees = not gated or self._agrees(where, start, chain, t)
        if not turned:  # (turned: registered astray, its position no lead for the next)
            self._solved = (self._solved + [(t, where)])[-2:]
        if turned or not agrees:
            s.mismatched += 1
            return
        s.registered += 1
        on_scene = unfixed  # no fix: the pose stands on the scene
        if self.watch is not None and not unfixed:
            verdict = self.watch.keyframe(t, np.asarray(prior.position), where, self.accuracy_at(t))
            on_scene = verdict.disagrees or verdict.lying  # a drift caught short of the threshold
        kept = Kept(t, shift, rotvec, on_scene, unfixed)
        s.kept = (s.kept + [kept])[-max(KEEP, LIE_FIT) :]
        first = s.shift_m is None
        frozen = unfixed or (
            self.watch is not None and self.watch.lying and self.watch.lies[-1].kind == FROZEN
        )  # the telemetry's position stands still: the shift moves as the keyframes do
        shift_now, rate = shift_model(s.kept, frozen)
        with self._lock:
            s.shift_m, s.rate_mps, s.at_s = shift_now, rate, t
            s.rotvec = np.median([k.rotvec for k in s.kept[-KEEP:]], axis=0)
            if first:
                s.since_s = t
        if first and unfixed:
            self.messages.info(
                f"found live at {t:.1f} s by searching {self.radius_m:.0f} m around {self.around()}: "
                f"{np.linalg.norm(shift[:2]):.0f} m from it ({fix.inliers} inliers, {fix.error_px:.2f} px); "
                "drawn from then on, carried by the keyframes"
            )
        elif first:
            self.messages.info(
                f"registered live from {t:.1f} s: the telemetry's pose was {np.linalg.norm(shift):.1f} m and "
                f"{np.degrees(np.linalg.norm(rotvec)):.1f} deg off; corrected from then on"
            )

    def _agrees(self, where: np.ndarray, start: Camera, chain, t: float) -> bool:
        """Whether a keyframe of media time t (s) registered at `where` (ENU m) agrees with the
        camera drawn (`start`), with the scene's own motion (`chain`: where the last two
        registered keyframes lead, and how far ahead (s)), or with where the last one, within
        CHAIN_S, leads carried by the telemetry's own motion (`_carried`: after a stretch
        where none registered, the second keyframe needs no third to be kept; a drag moves
        that lead by its speed times the gap, 2 m in a second at 2 m/s)."""
        if np.linalg.norm(where - np.asarray(start.position)) <= GATE_M:
            return True
        leads = [chain] if chain is not None else []
        if self._solved and t - self._solved[-1][0] <= CHAIN_S:
            carried = self._carried(t)
            if carried is not None:
                leads.append((carried, t - self._solved[-1][0]))
        return any(
            np.linalg.norm(where - lead) <= min(self.settings.chain_m + 0.5 * ACCEL_MPS2 * ahead**2, CHAIN_MAX_M)
            for lead, ahead in leads
        )  # fmt: skip


def shift_model(kept: list[Kept], frozen: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(the shift at the newest kept keyframe's time (ENU m), its rate (ENU m/s)) from the kept
    keyframes (oldest first): the trailing run of those standing as the newest does (on the
    scene or not); the median of the last KEEP of an agreeing run within KEEP_S of the newest, no
    rate; the line through the
    last LIE_FIT of a disagreeing run, on each axis where it moves RATE_MIN_MPS or more
    (elsewhere their median, held), unless more of them lie LINE_M off it than one in four or
    more (their median held); fewer than three: the newest held (a line through two is as wrong
    as either: one registered astray by 3 m half a second from the other draws a 6 m/s drag
    that the frames carry on until the next keyframe, seen under load). Under a frozen fix
    (`frozen`) the shift moves as the platform does, turns and all: the newest with the rate of
    the last two (a line through four averages a turn away, and four off one line were held)."""
    run: list[Kept] = []
    for k in reversed(kept):
        if k.on_scene != kept[-1].on_scene:
            break
        run.insert(0, k)
    if not kept[-1].on_scene:
        recent = [k.shift for k in run[-KEEP:] if k.t_s >= run[-1].t_s - KEEP_S]
        return np.median(recent, axis=0), np.zeros(3)
    run = run[-LIE_FIT:]
    shifts = np.array([k.shift for k in run])
    if frozen and len(run) >= 2:  # the fix stands still: the shift moves as the platform does
        return shifts[-1], (shifts[-1] - shifts[-2]) / max(run[-1].t_s - run[-2].t_s, 1e-3)
    if len(run) < 3:
        return shifts[-1], np.zeros(3)
    t = np.array([k.t_s for k in run]) - run[-1].t_s
    # Theil-Sen on each axis: one keyframe registered astray among three moves neither
    rate = np.array([theilslopes(shifts[:, j], t)[0] for j in range(3)])
    at_newest = np.median(shifts - rate * t[:, None], axis=0)
    steady = np.abs(rate) < RATE_MIN_MPS  # no trend: the registrations' own noise, held
    shift, rate = (
        np.where(steady, np.median(shifts, axis=0), at_newest),
        np.where(steady, 0.0, rate),
    )
    # a line the keyframes do not lie on (three, one of them off it; four or more, two) is no
    # drag: one registered astray, or one whose fix was taken mid-step, drew lines of 20 m/s
    off = np.linalg.norm(shifts - (shift + rate * t[:, None]), axis=1) > LINE_M
    if rate.any() and off.sum() > (len(run) > 3):
        return np.median(shifts, axis=0), np.zeros(3)
    return shift, rate
