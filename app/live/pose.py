"""Camera poses of a live feed, forward only: each frame gets the pose of its own presentation
time from the KLV sets (LivePoses) or the MAVLink messages (MavlinkPoses) that have arrived by the
time it is drawn, never from later ones.

Between two arrived sets the position and the field of view (tag 16: a zoom) are interpolated
linearly and the attitude by slerp (across a jump no platform could make, once believed, the
position before it is held: a frame between is not drawn part-way); past the newest set the newest
is held. Each frame is drawn with the field of view of its own moment (a set that gives none keeps
the one before it; before any set gives one, the feed's pinhole). A pose whose newest set is older than its frame by more
than the jitter buffer is `stale` (drawn, marked); before any set with a pose the frame has none.
Thread-safe: the receiver adds, the drawing thread asks.
"""

from __future__ import annotations

import bisect
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import FOV_RANGE_DEG
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.klv_track import KlvTrack
from app.io.mavlink import MavlinkTelemetry, TelemetryPose, value_at
from app.io.misb import LocalSet, camera_orientation
from app.io.streams import impossible_step, usual_interval

FRESH, STALE, NONE = "fresh", "stale", "none"
JUMP_RUN = 10  # sets in a row that all jump from the last kept one: that one was the jump
JUMP_EDGE_S = 1e-3  # the drawn position just before a believed jump (s): where it stepped


@dataclass(frozen=True)
class LivePose:
    """A frame's camera (None before any pose), whether it is fresh, stale or none, and how old
    the newest set behind it is relative to the frame (s); fixed: False where no fix placed it
    (a MAVLink home point: app.io.mavlink), a camera to search around, never to draw."""

    camera: Camera | None
    state: str
    age_s: float
    fixed: bool = True
    fix_age_s: float | None = None  # past the newest position alone (s); None: age_s


def fov_between(a: float, b: float, w: float) -> float | None:
    """The field of view (deg) a fraction w in [0, 1] of the way from a set's (a) to the next
    one's (b): linear where both give one, the one that does where only one does (NaN: none
    given), None where neither does."""
    if np.isfinite(a) and np.isfinite(b):
        return float((1.0 - w) * a + w * b)
    if np.isfinite(a) or np.isfinite(b):
        return float(a if np.isfinite(a) else b)
    return None


class LivePoses:
    """Sets with a position and an attitude, in time order (media s); and every set with an
    attitude, with or without a position (a GNSS outage: the sensor's angles go on), which
    the camera's attitude is taken from."""

    def __init__(
        self, stale_after_s: float, assumed_home: tuple[float, float, float] | None = None
    ) -> None:
        """assumed_home: (lat, lon deg, ellipsoidal h m) where a feed that never places the
        sensor is searched for (a live feed's --origin): its camera stands there at the
        sensor's height, not fixed (LivePose.fixed), until a set places it."""
        self.stale_after_s = stale_after_s
        self.assumed_home = assumed_home
        self.t: list[float] = []
        self.geodetic: list[tuple[float, float, float]] = []
        self.fov: list[float] = []  # each set's horizontal field of view (deg), NaN: none given
        self.hfov_deg: float | None = None  # the last field of view a set gave (deg)
        self.centre_h: float | None = None
        self.without_pose = 0  # sets that arrived with a position or angles in error
        self.jumps = 0  # sets whose position no platform could reach from the set before it
        self._jump_run = 0  # of them, in a row
        self.believed: list[float] = []  # media times of the sets a jump was believed at
        self._utc_link: float | None = None  # Unix s - media s, from the first set with a time
        self._att_t: list[float] = []  # the sets with an attitude, placed or not
        self._att_q: list[np.ndarray] = []
        self._h_t: list[float] = []  # of those, the ones giving the sensor's height
        self._h: list[float] = []  # (ellipsoidal m)
        self._lock = threading.Lock()

    def add(self, t: float, s: LocalSet) -> bool:
        """One set at media time t; False (counted) when it gives no full pose, or when its
        position is a jump from the set before it in time (app.io.streams.impossible_step: a
        latitude flicking to the pole is not followed; forward only, so the set after a jump is
        judged against the last one kept, until JUMP_RUN sets in a row disagree with it)."""
        one = KlvTrack("", [t], [s])
        g = one.gnss()
        q = camera_orientation(s)
        if q is not None:
            lat, lon = self.assumed_home[:2] if self.assumed_home else (0.0, 0.0)
            h = float(one.heights("sensor_ellipsoid_m", "sensor_msl_m", [lat], [lon])[0])
            with self._lock:
                i = bisect.bisect_right(self._att_t, t)
                if not (i and self._att_t[i - 1] == t):
                    self._att_t.insert(i, t)
                    self._att_q.insert(i, q)
                    if np.isfinite(h):
                        j = bisect.bisect_right(self._h_t, t)
                        self._h_t.insert(j, t)
                        self._h.insert(j, h)
        if g is None or q is None:
            self.without_pose += 1
            return False
        fov = s.get("hfov_deg")
        centre = one.centre_heights()[0]
        if self._utc_link is None and s.time_us is not None:
            self._utc_link = s.time_us / 1e6 - t
        here = (float(g.lat[0]), float(g.lon[0]), float(g.h[0]))
        with self._lock:
            i = bisect.bisect_right(self.t, t)
            if i and self.t[i - 1] == t:
                return True
            if i and impossible_step(t - self.t[i - 1], self.geodetic[i - 1], here):
                self._jump_run += 1
                if self._jump_run < JUMP_RUN:
                    self.jumps += 1
                    return False
                bisect.insort(self.believed, t)
            self._jump_run = 0
            self.t.insert(i, t)
            self.geodetic.insert(i, here)
            usable = np.isfinite(fov) and FOV_RANGE_DEG[0] <= fov <= FOV_RANGE_DEG[1]  # 0: none
            # a set that gives none keeps the one before it (ST 0601's report on change)
            self.fov.insert(i, float(fov) if usable else (self.fov[i - 1] if i else np.nan))
            if usable:
                self.hfov_deg = float(fov)
            if np.isfinite(centre):
                self.centre_h = float(centre)
        return True

    def utc_of(self, t: float) -> float | None:
        """The UTC (Unix s) of media time t (s) by the sets' Precision Time Stamp (tag 2),
        None before a set gave one."""
        return None if self._utc_link is None else t + self._utc_link

    def accuracy_at(self, t: float) -> float | None:
        """The accuracy (m) the feed states for its fix at media time t (s): ST 0601 states
        none."""
        return None

    def jumps_between(self, a: float, b: float) -> list[tuple[float, float]]:
        """(from, to) media times (s) of the steps no platform makes drawn in (a, b]: at the
        sets a jump was believed at (JUMP_RUN sets in a row from the last one kept), the drawn
        position steps from its value just before (JUMP_EDGE_S) to the set's
        (app.live.register holds it off)."""
        with self._lock:
            at = self.believed[
                bisect.bisect_right(self.believed, a) : bisect.bisect_right(self.believed, b)
            ]
        return [(t - JUMP_EDGE_S, t) for t in at]

    @property
    def unplaced(self) -> bool:
        """Whether the camera stands at the assumed home for want of any set placing the
        sensor (its height given)."""
        return not self.t and self.assumed_home is not None and bool(self._h_t)

    def first(self) -> tuple[float, float, float] | None:
        """The first position (lat, lon, ellipsoidal h); never placed, the assumed home at
        the sensor's first height; None before either."""
        with self._lock:
            if self.geodetic:
                return self.geodetic[0]
            if self.unplaced:
                return (*self.assumed_home[:2], self._h[0])
            return None

    def fix_interval_s(self) -> float | None:
        """The usual interval between the recent sets (s), None before two."""
        with self._lock:
            return usual_interval(self.t)

    def ground(self) -> tuple[float, str] | None:
        """The assumed ground's ellipsoidal height (m) and where it comes from, None unknown."""
        if self.centre_h is None:
            return None
        return self.centre_h, "the KLV frame centre's height"

    def __len__(self) -> int:
        return len(self._h_t) if self.unplaced else len(self.t)

    def at(
        self,
        t: float,
        frame: LocalFrame,
        intrinsics: Intrinsics,
        far: float,
        own_fov: bool = True,
    ) -> LivePose:
        """The camera at media time t (s) in `frame` from the sets arrived so far: `intrinsics`'
        image (pixels) with the field of view of that moment where the sets give one (linear
        between two sets, the newest held past it; own_fov False: `intrinsics` as they are, a
        field of view the user gave)."""
        with self._lock:
            if not self.t and self.unplaced:
                return self._unplaced_at(t, frame, intrinsics, far)
            if not self.t:
                return LivePose(None, NONE, float("inf"))
            i = bisect.bisect_right(self.t, t)
            if i == 0:  # the frame precedes every set: the first one, marked stale
                k, w, age = 0, 0.0, self.t[0] - t
            elif i == len(self.t):
                k, w, age = i - 1, 0.0, t - self.t[-1]
            else:
                k, w, age = i - 1, (t - self.t[i - 1]) / (self.t[i] - self.t[i - 1]), 0.0
            a, fa = np.array(self.geodetic[k]), self.fov[k]
            if w > 0.0:
                b, fb = np.array(self.geodetic[k + 1]), self.fov[k + 1]
            else:
                b, fb = a, fa
            # across a jump believed (JUMP_RUN sets) the position no set gave is not drawn: the
            # one before it held until the jumped set's time (the attitude turns as it did)
            wp = 0.0 if w > 0.0 and impossible_step(self.t[k + 1] - self.t[k], a, b) else w
            q = self._attitude_at(t)  # (every placed set gave one: its attitude is there too)
        enu = frame.geodetic_to_enu(*(np.array([v]) for v in (1 - wp) * a + wp * b))[0]
        fov = fov_between(fa, fb, w)
        if own_fov and fov is not None:
            intrinsics = Intrinsics.from_fov(intrinsics.width, intrinsics.height, fov)
        camera = Camera.create(intrinsics, enu, q, far=far)
        return LivePose(camera, FRESH if age <= self.stale_after_s else STALE, age)

    def _unplaced_at(
        self, t: float, frame: LocalFrame, intrinsics: Intrinsics, far: float
    ) -> LivePose:
        """The camera at the assumed home, at the sensor's height and attitude of media time t
        (s), not fixed; under the lock."""
        h = float(value_at(self._h_t, self._h, t))
        lat, lon = self.assumed_home[:2]
        enu = frame.geodetic_to_enu(np.array([lat]), np.array([lon]), np.array([h]))[0]
        camera = Camera.create(intrinsics, enu, self._attitude_at(t), far=far)
        age = max(t - self._h_t[-1], self._h_t[0] - t, 0.0)
        return LivePose(camera, FRESH if age <= self.stale_after_s else STALE, age, False)

    def _attitude_at(self, t: float) -> np.ndarray:
        """The attitude at media time t (s) from every set that gave one (slerp between two,
        the nearest held beyond them); under the lock."""
        i = bisect.bisect_right(self._att_t, t)
        if i == 0 or i == len(self._att_t):
            return self._att_q[max(i - 1, 0)]
        ta, tb = self._att_t[i - 1], self._att_t[i]
        pair = np.stack([self._att_q[i - 1], self._att_q[i]])
        return rotations.slerp([0.0, 1.0], pair, [(t - ta) / (tb - ta)])[0]


class MavlinkPoses:
    """The camera of a video frame from MAVLink telemetry (app.io.mavlink) beside a video
    without KLV. A frame's media time t is put on the autopilot's boot clock through the arrival
    clock: boot = t + video_link - telemetry_link + offset_s, where the links are the fastest
    arrivals of each (the jitter buffer's and the telemetry's) and offset_s, the video's lag
    behind the telemetry with its sign turned (the video's pipeline is slower), is what the
    lag estimator (app.live.lag) finds from the rotation the video shows; 0 until then."""

    hfov_deg = None  # MAVLink does not say the camera's field of view

    def __init__(
        self,
        telemetry: MavlinkTelemetry,
        video_link: Callable[[], float | None],
        stale_after_s: float,
    ) -> None:
        self.telemetry = telemetry
        self.video_link = video_link
        self.stale_after_s = stale_after_s
        self.offset_s = 0.0
        self.without_pose = 0

    def __len__(self) -> int:
        return len(self.telemetry)

    def first(self) -> tuple[float, float, float] | None:
        return self.telemetry.first()

    def fix_interval_s(self) -> float | None:
        return self.telemetry.fix_interval_s()

    def utc_of(self, t: float) -> float | None:
        """None: the autopilot's boot clock is not UTC."""
        return None

    def accuracy_at(self, t: float) -> float | None:
        """The horizontal accuracy (m) GPS_RAW_INT states (h_acc) at media time t (s), None
        where it states none or before both clocks are linked."""
        c = self.boot_offset()
        return None if c is None else self.telemetry.accuracy_at(t + c + self.offset_s)

    def ground(self) -> tuple[float, str] | None:
        h = self.telemetry.home_h
        return None if h is None else (h, "the home (take-off) height the autopilot sends")

    def jumps_between(self, a: float, b: float) -> list[tuple[float, float]]:
        """(from, to) media times (s) of the steps no platform makes in the positions drawn
        over (a, b] (MavlinkTelemetry.jumps_between: drawn as a line between two messages,
        app.live.register holds them off); none before both clocks are linked."""
        c = self.boot_offset()
        if c is None:
            return []
        c += self.offset_s
        return [(t0 - c, t1 - c) for t0, t1 in self.telemetry.jumps_between(a + c, b + c)]

    def boot_offset(self) -> float | None:
        """boot - media (s) without the lag: None before both clocks are linked."""
        v, m = self.video_link(), self.telemetry.link_s
        return None if v is None or m is None else v - m

    def telemetry_at(self, t: float) -> TelemetryPose | None:
        """The telemetry's camera at media time t (s), None before both clocks are linked or
        before a position and an attitude have arrived."""
        c = self.boot_offset()
        return None if c is None else self.telemetry.at(t + c + self.offset_s)

    def at(
        self,
        t: float,
        frame: LocalFrame,
        intrinsics: Intrinsics,
        far: float,
        own_fov: bool = True,
    ) -> LivePose:
        """The camera at media time t (s) in `frame` from the messages arrived so far, with
        `intrinsics` as they are (MAVLink gives no field of view: own_fov has nothing to use)."""
        pose = self.telemetry_at(t)
        if pose is None:
            return LivePose(None, NONE, float("inf"))
        enu = frame.geodetic_to_enu(*(np.array([v]) for v in pose.geodetic))[0]
        camera = Camera.create(intrinsics, enu, pose.q, far=far)
        state = FRESH if pose.age_s <= self.stale_after_s else STALE
        return LivePose(camera, state, pose.age_s, pose.fixed, pose.fix_age_s)
