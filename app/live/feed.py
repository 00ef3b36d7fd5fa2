"""A live feed as the viewer and `geofuse live` draw it (no GL here): the receiver thread, the
jitter buffer, the poses (the stream's KLV, or MAVLink beside it with its lag estimated), the
recorder, the restream (app.live.restream), and the scene around the first position;
`take(now)` hands the drawing loop the frame due with the camera of its own time, never waiting
on the network.

Poses come from the stream's own KLV, or, given `mavlink`, from MAVLink telemetry beside it
(app.live.mavlink), its lag behind the video estimated as it flies (app.live.lag). A frame
whose pose is stale or missing is drawn with the last camera (counted, said once). Over a
textured scene, keyframes are registered in the background and their correction applied
forward (app.live.register), and the feed's GNSS is tested against them as it arrives
(app.live.gnss_watch: a lie said once and not followed, each frame `used`, `rejected` or
`missing`); over an assumed ground or a grey model, it says why not, once.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import av
import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_FAR_M, DEFAULT_START_RADIUS_M
from app.core.messages import Messages
from app.footage.clips import ASSUMED_DRONE_HFOV_DEG, KLV_ASSUMED_HEIGHT_M, frame_and_ground
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.mavlink import MavlinkTelemetry
from app.io.misb import camera_set
from app.io.streams import GnssTrack
from app.io.video import decode_at, media_seconds
from app.live.buffer import DEFAULT_DELAY_S, Arrival, JitterBuffer
from app.live.gnss_watch import GnssWatch
from app.live.lag import LagEstimator
from app.live.mavlink import MavlinkReceiver
from app.live.pose import FRESH, NONE, STALE, LivePoses, MavlinkPoses
from app.live.probe import Heard
from app.live.receiver import READ_TIMEOUT_S, Receiver
from app.live.recorder import Recorder, SegmentRecorder
from app.live.register import (
    CARRIED_FROM,
    HELD_INTERVALS,
    HELD_S,
    LiveCorrection,
    LiveRegistration,
)
from app.live.restream import RestreamCounts, Restreamer, Tee
from app.playback.decoder import yuv_planes
from app.scene.mesh import MeshData
from app.session.model import scene_refusal

REVIEW_TOLERANCE_S = 0.02  # a reviewed frame is the first at or after the time asked, less this

SILENCE_S = 10.0
GROUND_MARGIN_M = 3000.0
MISSING_AFTER = 50  # MAVLink messages used (2 s of ATTITUDE) before a missing kind is said


@dataclass
class Drawn:
    """One frame drawn: its media time (s), when it arrived, when the jitter buffer made it due
    and when its drawing finished (monotonic s), the pose's state (fresh, stale, none),
    whether live registration corrected the pose, and its GNSS status (app.camera.fixes:
    used, rejected, missing; None where the fixes are not tested against the scene)."""

    pts_s: float
    arrival_s: float
    due_s: float
    drawn_s: float
    pose: str
    registered: bool = False
    gnss: str | None = None


@dataclass
class MavlinkSummary:
    """What a run took from MAVLink: messages used by type, those dropped by reason and those
    without a fix, the bytes that arrived and those unreadable, what the camera lacks (see
    MavlinkTelemetry.missing), the lag applied at the end and each window's estimate (s, the
    video behind the telemetry), and the gimbal's presence."""

    address: str
    used: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    no_fix: int = 0
    bytes_received: int = 0
    readable: int = 0  # messages of a known type, used or not
    unreadable_bytes: int = 0
    missing: str | None = None
    lag_s: float | None = None
    estimates_s: list[float] = field(default_factory=list)
    gimbal: bool = False

    def line(self) -> str:
        parts = [", ".join(f"{n} {k}" for k, n in sorted(self.used.items())) or "nothing used"]
        if not self.bytes_received:
            parts = ["nothing arrived"]
        elif not self.readable:
            parts.append(
                f"{self.bytes_received} bytes arrived but none was readable as MAVLink (expected MAVLink 1 or 2 messages)"
            )
        elif self.unreadable_bytes:
            parts.append(
                f"{self.unreadable_bytes} of {self.bytes_received} bytes unreadable (not MAVLink, of no known type, or failing its checksum)"
            )
        if self.dropped:
            parts.append(
                "dropped: " + ", ".join(f"{n} {why}" for why, n in sorted(self.dropped.items()))
            )
        if self.no_fix:
            parts.append(f"{self.no_fix} positions without a fix")
        if self.missing and self.bytes_received:
            parts.append(self.missing)
        e = self.estimates_s
        parts.append(
            f"the video lags the telemetry by {1000 * self.lag_s:.0f} ms (the median of {len(e)} estimates, "
            f"{1000 * min(e):.0f} to {1000 * max(e):.0f} ms)"
            if self.lag_s is not None
            else "no lag estimated (the camera did not turn enough, or too short)"
        )
        return f"MAVLink {self.address}: " + "; ".join(parts)


@dataclass
class LiveRun:
    """What a run received, drew and lost, with the messages it said."""

    url: str
    drawn: list[Drawn] | deque[Drawn] = field(default_factory=list)  # (the viewer keeps the last)
    frames_drawn: int = 0
    received: int = 0
    missing: int = 0
    skipped: int = 0
    late: int = 0
    overflow: int = 0
    undecodable: int = 0
    bad_klv: int = 0
    unreadable: Heard = field(default_factory=Heard)  # datagrams that were not MPEG-TS
    stale: int = 0
    without_pose: int = 0
    reconnects: int = 0
    ended: str = ""
    delay_s: float = DEFAULT_DELAY_S
    origin_s: float | None = None  # the stream-clock seconds of media time 0
    frame: LocalFrame | None = None  # the local ENU frame the cameras are in
    mavlink: MavlinkSummary | None = None
    registration: LiveCorrection | None = None
    gnss: GnssWatch | None = None  # the fixes tested against the registered keyframes
    restream: RestreamCounts | None = None
    messages: Messages = field(default_factory=Messages)

    def add_drawn(self, d: Drawn) -> None:
        self.drawn.append(d)
        self.frames_drawn += 1

    def latency_ms(self, q: float) -> float:
        """The q-th percentile of arrival -> drawn (ms), NaN before any frame is drawn."""
        lat = [1000.0 * (d.drawn_s - d.arrival_s) for d in self.drawn]
        return float(np.percentile(lat, q)) if lat else math.nan

    def added_ms(self, q: float) -> float:
        """The q-th percentile of due -> drawn (ms): what geofuse adds past the jitter buffer
        (waiting for the draw loop, decoding behind, drawing)."""
        lat = [1000.0 * (d.drawn_s - max(d.due_s, d.arrival_s)) for d in self.drawn]
        return float(np.percentile(lat, q)) if lat else math.nan

    def summary(self) -> str:
        """The one line `geofuse live` prints at the end."""
        mavlink = f"; {self.mavlink.line()}" if self.mavlink is not None else ""
        heard = self.unreadable
        if heard.datagrams and not self.received:
            mavlink = f"; {heard.unreadable()}{mavlink}"
        elif heard.datagrams:
            mavlink = f"; {heard.datagrams} datagrams before it opened were not MPEG-TS{mavlink}"
        if self.registration is not None:
            mavlink += f"; {self.registration.line()}"
        if self.gnss is not None:
            mavlink += f"; {self.gnss.line()}"
        if self.restream is not None:
            mavlink += f"; {self.restream.line()}"
        return (
            f"{self.url}: {self.received} frames received ({self.missing} lost on the way), "
            f"{self.frames_drawn} drawn, "
            f"{self.skipped + self.late + self.overflow} dropped by geofuse "
            f"({self.skipped} behind, {self.late} late, {self.overflow} overflow), "
            f"{self.undecodable} undecodable packets, latency arrival->drawn p50 "
            f"{self.latency_ms(50):.1f} ms p95 {self.latency_ms(95):.1f} ms (past the "
            f"{1000 * self.delay_s:.0f} ms buffer: p50 {self.added_ms(50):.1f} p95 {self.added_ms(95):.1f} ms); "
            f"{self.stale} drawn with a stale pose, {self.without_pose} without one{mavlink}; {self.ended}"
        )


@dataclass(frozen=True)
class LiveOptions:
    """seconds: stop after this long (None: until silence); record: keep what arrives as
    MPEG-TS; delay_s: the jitter buffer; size: the drawing's (w, h); layers: the scene (else an
    assumed ground); origin: (lat, lon, ellipsoidal h) of the ground's origin; mavlink: a
    pymavlink connection (udp:HOST:PORT) whose telemetry poses the video; hfov_deg: the camera's
    horizontal field of view where the feed does not say it (None: the KLV's, else 73.7 deg);
    gnss_accuracy_m: the fixes' accuracy (m, 1 sigma per axis) where the feed states none
    (None: app.register.gnss.CheckSettings.accuracy_m, 5 m)."""

    seconds: float | None = None
    record: Path | None = None
    delay_s: float = DEFAULT_DELAY_S
    size: tuple[int, int] = (1280, 720)
    layers: tuple = ()
    origin: tuple[float, float, float] | None = None
    silence_s: float = SILENCE_S
    far_m: float = DEFAULT_FAR_M
    mavlink: str | None = None
    hfov_deg: float | None = None
    segments: Path | None = None  # the viewer's rolling recording: a folder of segments
    register: bool = True  # register keyframes against a textured scene, forward only
    restream: str | None = None  # udp://HOST:PORT: the video sent on with geofuse's poses as KLV
    # where the drawn frames are shared (issue 53): makers of app.share.hub.Sink, each called
    # with the run's Messages once the scene is built
    sinks: tuple = ()
    gnss_accuracy_m: float | None = None
    read_timeout_s: float = READ_TIMEOUT_S  # a read waiting longer: the stream is opened again
    search_radius_m: float = DEFAULT_START_RADIUS_M  # no fix at all: searched this far from home


def scene_for(poses: LivePoses | MavlinkPoses, options: LiveOptions, messages: Messages):
    """(frame, mesh) once the first position is known: the layers around it, else a flat
    ground at the origin's height, the KLV frame centre's or MAVLink's home height, or 100 m
    under the sensor (said)."""
    lat, lon, h = options.origin or poses.first()
    known = poses.ground()
    if options.origin is not None:
        ground = options.origin[2]
    elif known is not None and known[0] < h:
        ground = known[0]
        messages.info(f"the assumed ground is {known[1]} ({ground:.1f} m)")
    else:
        ground = h - KLV_ASSUMED_HEIGHT_M
        messages.add(
            f"no ground height in the telemetry: the ground is assumed {KLV_ASSUMED_HEIGHT_M:g} m under the sensor (give --scene, --dem or --origin)"
        )
    track = GnssTrack(np.zeros(1), np.array([lat]), np.array([lon]), np.array([h]))
    frame, mesh, _ = frame_and_ground(track, ground, GROUND_MARGIN_M, options.layers, messages)
    return frame, mesh


class LiveFeed:
    """One stream received (see the module docstring); `run` holds its figures and messages."""

    def __init__(
        self,
        url: str,
        options: LiveOptions = LiveOptions(),
        run: LiveRun | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url, self.options, self.clock = url, options, clock
        self.run = run or LiveRun(url, delay_s=options.delay_s)
        self.buffer = JitterBuffer(options.delay_s)
        self.klv_poses = LivePoses(options.delay_s, options.origin)  # (where never placed)
        self.poses: LivePoses | MavlinkPoses = self.klv_poses
        self.mav: MavlinkReceiver | None = None
        self.lag: LagEstimator | None = None
        self.recorder: Recorder | SegmentRecorder | None = None
        self.receiver: Receiver | None = None
        self.frame: LocalFrame | None = None
        self.intrinsics: Intrinsics | None = None
        self.last_camera: Camera | None = None
        self.registration: LiveRegistration | None = None
        self.restream: Restreamer | None = None
        self.registered = False  # the last frame taken was drawn with the registered pose
        self.gnss: GnssWatch | None = None
        self.gnss_now: str | None = None  # the last frame taken: its GNSS status
        self._unfixed_said = False  # a camera without any fix, said (_say_unfixed)

    def start(self) -> LiveFeed:
        o, messages = self.options, self.run.messages
        if o.mavlink is not None:
            telemetry = MavlinkTelemetry(o.origin)  # (home, where no HOME_POSITION says)
            self.poses = MavlinkPoses(telemetry, lambda: self.buffer.link_s, o.delay_s)
            self.mav = MavlinkReceiver(o.mavlink, telemetry, messages, self.clock).start()
            self.mav.wait_ready()
            self.run.mavlink = MavlinkSummary(o.mavlink)
        if o.record is not None:
            self.recorder = Recorder(o.record)
        elif o.segments is not None:
            self.recorder = SegmentRecorder(o.segments)
        sink = self.recorder
        if o.restream is not None:  # (app.live.restream.restream_refusal checked it)
            self.restream = Restreamer(o.restream, messages).start()
            self.run.restream = self.restream.counts
            sink = Tee(self.recorder, self.restream)
        self.receiver = Receiver(
            self.url,
            self.buffer,
            self.klv_poses,
            messages,
            sink,
            self.clock,
            self._on_frame,
            self.mav is not None,
            o.read_timeout_s,
        ).start()
        return self

    def _on_frame(self, t: float, luma) -> None:
        """Each decoded frame, on the receiver's thread: the lag estimator's feed, and for a
        MAVLink flight its pose written into the recording as a Local Set (the lag as estimated
        then: forward only), so that the recording is a clip with poses."""
        if self.lag is not None:
            self.lag.feed(t, luma)
        if self.mav is not None and self.recorder is not None:
            self._record_pose(t)

    def _record_pose(self, t: float) -> None:
        origin = self.receiver.origin_s
        pose = self.poses.telemetry_at(t)
        if pose is None or origin is None or not pose.fixed:  # a home point is no position
            return
        heading, pitch, roll = rotations.hpr_from_camera_quat(pose.q[None])[0]
        payload = camera_set(
            time.time(),
            pose.geodetic,
            (heading, pitch, roll),
            self._hfov_deg(),
            self.poses.telemetry.home_h,
        )
        self.recorder.write_set(payload, t + origin)

    @property
    def refused(self) -> str | None:
        """Why the stream's or the MAVLink's address was refused at start (said), else None."""
        if self.mav is not None and self.mav.refused is not None:
            return self.mav.refused
        return self.receiver.counts.refused

    def silence(self, seconds: float) -> str:
        """How a run that heard nothing readable for `seconds` (s) ends: silence, or only
        datagrams that were not MPEG-TS (app.live.probe)."""
        if self.receiver.counts.unreadable.datagrams:
            return f"ended: nothing readable arrived for {seconds:g} s"
        return f"ended: the stream was silent for {seconds:g} s"

    def silent_for(self, now: float, since: float) -> float:
        """Seconds since anything arrived (since `since` when nothing has yet)."""
        heard = self.receiver.last_arrival_s
        return now - (heard if heard is not None else since)

    def ready(self) -> bool:
        """Whether the video's size and a first position (or the given origin) are known."""
        return self.receiver.size is not None and (
            len(self.poses) > 0 or self.options.origin is not None
        )

    def _hfov_deg(self) -> float:
        """The camera's horizontal field of view: given, else the KLV's, else assumed (deg)."""
        return self.options.hfov_deg or self.poses.hfov_deg or ASSUMED_DRONE_HFOV_DEG

    def build_scene(self) -> MeshData:
        """The scene around the first position and the video's pinhole (once `ready`)."""
        o, messages = self.options, self.run.messages
        self.frame, mesh = scene_for(self.poses, o, messages)
        self.run.frame = self.frame
        hfov = self._hfov_deg()
        if o.hfov_deg is None and self.poses.hfov_deg is None:
            messages.add(f"the feed gives no field of view: {hfov:.1f} deg assumed (give --fov)")
        self.intrinsics = Intrinsics.from_fov(*self.receiver.size, hfov)
        if self.mav is not None:
            if not self.poses.telemetry.has_gimbal:
                messages.add(
                    "MAVLink: no gimbal attitude (GIMBAL_DEVICE_ATTITUDE_STATUS, MOUNT_STATUS): the camera is taken to look along the vehicle's nose"
                )
            self.lag = LagEstimator(self.poses, self.intrinsics, messages).start()
        if o.register:
            refusal = scene_refusal(mesh if o.layers else None, o.layers)
            if refusal is None:
                self.gnss = GnssWatch(messages, o.gnss_accuracy_m, utc_of=self.poses.utc_of)
                self.registration = LiveRegistration(
                    mesh,
                    messages,
                    watch=self.gnss,
                    accuracy_at=self.poses.accuracy_at,
                    fix_at=self._fix_at,
                    jumps_between=self.poses.jumps_between,
                    unfixed=self._unfixed,
                    search_radius_m=o.search_radius_m,
                    settled=lambda: self.lag is None or self.lag.applied,
                    around=self._around,
                ).start()
                self.run.registration = self.registration.state
                self.run.gnss = self.gnss
            else:
                messages.info(f"live registration off: {refusal}")
        self._say_unfixed()
        return mesh

    def _say_unfixed(self) -> None:
        """Said once, as soon as it shows (the scene built, or later, when the first set or
        message without a fix arrives): a camera with no fix at all, and where it is searched."""
        if self._unfixed_said:
            return
        o, searched = self.options, self.registration is not None
        if self.mav is None and self.poses.unplaced:
            lat, lon, _ = o.origin
            text = (
                f"no KLV set places the sensor (tags 13, 14 and 75 or 15): the camera is searched for on the scene within {o.search_radius_m:g} m of --origin {lat:.5f}, {lon:.5f}, at the sensor's height; frames are drawn once it is found"
                if searched
                else "no KLV set places the sensor: nothing can be drawn (give --origin and a textured --scene to search for it)"
            )
        elif self.mav is not None and self.poses.telemetry.unfixed:
            lat, lon, _ = self.poses.telemetry.home
            named = self.poses.telemetry.home_from
            text = "MAVLink: no GNSS fix (GLOBAL_POSITION_INT at 0, 0): " + (
                f"the camera is searched for on the scene within {o.search_radius_m:g} m of the home point {lat:.5f}, {lon:.5f} ({named}), at the barometer's height above it; frames are drawn once it is found"
                if searched
                else f"nothing can be drawn: the camera is searched for around the home point ({named}) on a textured scene (give --scene)"
            )
        else:
            return
        self.run.messages.add(text)
        self._unfixed_said = True

    def _around(self) -> str:
        """What a camera without a current fix stands on, for messages."""
        if self.mav is not None and self.poses.telemetry.unfixed:
            return f"the home point ({self.poses.telemetry.home_from})"
        if self.mav is None and self.poses.unplaced:
            return "--origin"
        return "the last fix, held"

    def _unfixed(self, t: float) -> bool:
        """Whether no current fix places the telemetry's camera at media time t (`_held`)."""
        return self._held(self._telemetry_camera(t))

    def _held(self, raw: tuple[Camera, str, float, bool] | None) -> bool:
        """Whether no current fix places the telemetry's camera `raw` (_telemetry_camera's):
        none ever (a home point), or the newest older than HELD_S and HELD_INTERVALS of the
        feed's usual interval between fixes (an outage: the last fix held). False without one."""
        if raw is None or not raw[3]:
            return raw is not None
        usual = self.poses.fix_interval_s()
        return raw[2] > max(HELD_S, HELD_INTERVALS * usual if usual is not None else 0.0)

    def camera_at(self, t: float) -> tuple[Camera | None, str]:
        """The camera of media time t (s) from what has arrived, corrected by the registration
        in force, and its state (fresh, stale, none): the last camera drawn stands in for a
        missing one."""
        return self._corrected(self._telemetry_camera(t), t)[:2]

    @property
    def pose_source(self) -> str:
        """What poses the frames drawn now: "registered" once live registration's correction is
        in force, else the telemetry's own ("mavlink" or "klv")."""
        reg = self.registration
        if reg is not None and reg.state.shift_m is not None:
            return "registered"
        return "mavlink" if self.mav is not None else "klv"

    def _corrected(
        self, raw: tuple[Camera, str, float, bool] | None, t: float, held: bool | None = None
    ) -> tuple[Camera | None, str, float]:
        """(the camera drawn at media time t (s), its state, how far (m) the telemetry's jumps
        held off in it are: LiveRegistration.corrected); held: `_held(raw)` where the caller
        has it."""
        if raw is None:
            return self.last_camera, NONE, 0.0
        reg = self.registration
        if not raw[3] and (reg is None or len(reg.state.kept) < CARRIED_FROM):
            return None, NONE, 0.0  # no fix, not yet carried by the scene: nothing to draw
        if reg is None:
            return raw[0], raw[1], 0.0
        camera, held_m = reg.corrected(raw[0], t, self._held(raw) if held is None else held)
        return camera, raw[1], held_m

    def _fix_at(self, t: float) -> np.ndarray | None:
        """The telemetry's position at media time t (ENU m), None before any."""
        raw = self._telemetry_camera(t)
        return None if raw is None or not raw[3] else np.asarray(raw[0].position, np.float64)

    def _telemetry_camera(self, t: float) -> tuple[Camera, str, float, bool] | None:
        """The telemetry's camera of media time t (s), its state, how much older than t the
        newest position behind it is (s) and whether a fix placed it; None before any."""
        pose = self.poses.at(  # each frame with its own moment's field of view, unless given
            t, self.frame, self.intrinsics, self.options.far_m, self.options.hfov_deg is None
        )
        if pose.camera is None:
            return None
        age = pose.age_s if pose.fix_age_s is None else pose.fix_age_s
        return pose.camera, pose.state, age, pose.fixed

    def take(self, now: float) -> tuple[Arrival, float, Camera, str] | None:
        """The frame due at now with when it was due, its camera and the pose's state; None
        when none is due, or no pose has arrived yet (nothing to project from)."""
        with self.receiver.lock:
            item = self.buffer.take(now)
            due = self.buffer.due_at(item) if item is not None else now
        if item is None:
            return None
        raw = self._telemetry_camera(item.pts_s)
        held = self._held(raw)  # (once a frame: the registration is told it, not asked)
        camera, state, held_m = self._corrected(raw, item.pts_s, held)
        if raw is not None and not raw[3]:
            self._say_unfixed()
        if raw is not None:
            self.registered = camera is not raw[0]  # (a correction makes a new camera)
            if held and self.registered and state == STALE:
                state = FRESH  # a fix held, the pose the scene's keyframes carry: not stale
        if raw is not None and self.registration is not None:
            self.registration.offer(item.pts_s, item.payload, raw[0], held)
        run = self.run
        if state == STALE:
            run.stale += 1
            feed = "MAVLink telemetry" if self.mav is not None else "KLV"
            run.messages.add_once(
                "stale",
                f"frames drawn with a stale pose (the {feed}'s newest older than the buffer: it lags behind the video, or stopped): counted",
            )
        elif state == NONE:
            run.without_pose += 1
        if camera is None:
            return None
        self.last_camera = camera
        if self.gnss is not None:  # the frame's GNSS status (a pose held: as old as it is)
            age = raw[2] if raw is not None and raw[3] else math.inf
            self.gnss_now = self.gnss.frame(item.pts_s, age, held_m, held)
        return item, due, camera, state

    def restream_frame(self, pts_s: float, camera: Camera) -> None:
        """The pose a frame of media time pts_s (s) was drawn with, handed to the restream
        (never waits; nothing without one)."""
        origin = self.receiver.origin_s
        if self.restream is not None and origin is not None:
            self.restream.pose(pts_s + origin, self.frame, camera, self.registered)

    def discard_due(self, now: float) -> int:
        """Frames due now taken away unshown and uncounted (JitterBuffer.discard_due)."""
        with self.receiver.lock:
            return self.buffer.discard_due(now)

    def recorded_frame(self, t: float) -> Arrival | None:
        """The frame of media time t (s), decoded from the rolling recording (scrubbing back);
        None when nothing recorded holds it or it cannot be read (a segment being written can
        end in half a packet)."""
        rec, origin = self.recorder, self.receiver.origin_s
        if not isinstance(rec, SegmentRecorder) or origin is None:
            return None
        segment = rec.holding(t + origin)
        if segment is None:
            return None
        try:
            with av.open(str(segment.path)) as c:
                stream = c.streams.video[0]
                frame = decode_at(c, stream, t + origin, REVIEW_TOLERANCE_S)
                if frame is None:
                    return None
                pts = media_seconds(frame.pts, stream.time_base, origin)
                return Arrival(pts, math.nan, yuv_planes(frame))
        except (av.FFmpegError, OSError, IndexError):
            return None

    def next_wake(self, now: float) -> float:
        """When the next pending frame is due (clock s); a little after now when none waits."""
        with self.receiver.lock:
            wake = self.buffer.next_due()
        return wake if wake is not None else now + 0.005

    def update_counts(self, final: bool = False) -> LiveRun:
        """The run's counts brought up to date (any time, from the drawing thread); final:
        the feed has stopped (what MAVLink lacked is said now whatever came)."""
        run, c = self.run, self.receiver.counts
        run.received, run.undecodable, run.missing = c.frames, c.undecodable, c.missing
        b = self.buffer
        run.skipped, run.late, run.overflow = b.skipped, b.late, b.overflow
        run.bad_klv = self.receiver.track.counts.bad
        run.unreadable = c.unreadable
        run.reconnects = max(c.connects - 1, 0)
        run.origin_s = self.receiver.origin_s
        if run.mavlink is not None:
            self._mavlink_counts(run.mavlink, final)
            run.mavlink.gimbal = self.poses.telemetry.has_gimbal
            if self.lag is not None:
                run.mavlink.lag_s = self.lag.lag_s
                run.mavlink.estimates_s = [-e.offset_s for e in self.lag.estimates]
        return run

    def _mavlink_counts(self, summary: MavlinkSummary, final: bool) -> None:
        """The MAVLink's counts into `summary`; what the camera lacks said once, after
        MISSING_AFTER messages used or at the end (nothing at all arrived, at the end)."""
        counts, mav = self.poses.telemetry.counts, self.mav
        summary.used, summary.dropped = dict(counts.used), dict(counts.dropped)
        summary.no_fix = counts.no_fix
        summary.bytes_received, summary.unreadable_bytes = mav.bytes_received, mav.unreadable_bytes
        summary.readable = mav.readable
        summary.missing = self.poses.telemetry.missing()
        said = self.run.messages
        if summary.missing and (final or sum(summary.used.values()) >= MISSING_AFTER):
            said.add_once("mavlink-missing", f"MAVLink {mav.address}: {summary.missing}")
        if final and not summary.bytes_received and mav.refused is None:
            said.add_once(
                "mavlink-nothing",
                f"MAVLink {mav.address}: nothing arrived (is the autopilot sending there?): the camera cannot be placed",
            )

    def stop(self) -> LiveRun:
        """Everything stopped and closed (the recording kept); the final counts."""
        self.receiver.stop()
        if self.restream is not None:
            self.restream.stop()
        if self.registration is not None:
            self.registration.stop()
        if self.lag is not None:
            self.lag.stop()
        if self.mav is not None:
            self.mav.stop()
        if self.recorder is not None:
            self.recorder.close()
        return self.update_counts(final=True)
