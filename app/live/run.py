"""A live feed drawn without a window (`geofuse live`, `bench live`): the viewer's pipeline, off
screen through EGL, with the same clock and the same figures.

The loop never waits on the network: it takes the newest frame due from the jitter buffer,
draws it projected with the pose of its own time (app.live.pose: stale or missing poses drawn
with the last one, counted) and records when the drawing was finished (the GPU waited for). It
ends after `seconds`, or once the stream has been silent for `silence_s` (said).

Poses come from the stream's own KLV, or, given `mavlink`, from MAVLink telemetry beside it
(app.live.mavlink), its lag behind the video estimated as it flies (app.live.lag).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_FAR_M
from app.core.messages import Messages
from app.footage.clips import ASSUMED_DRONE_HFOV_DEG, KLV_ASSUMED_HEIGHT_M, frame_and_ground
from app.geodesy.enu import LocalFrame
from app.io.mavlink import MavlinkTelemetry
from app.io.streams import GnssTrack
from app.live.buffer import DEFAULT_DELAY_S, JitterBuffer
from app.live.lag import LagEstimator
from app.live.mavlink import MavlinkReceiver
from app.live.pose import NONE, STALE, LivePoses, MavlinkPoses
from app.live.receiver import Receiver
from app.live.recorder import Recorder
from app.render.context import create_offscreen_context, wait_for_gpu
from app.render.offscreen import OffscreenTarget
from app.render.renderer import FusionRenderer
from app.render.still import window_camera

SILENCE_S = 10.0
GROUND_MARGIN_M = 3000.0
VIEW_HFOV_DEG = 60.0  # the off-screen view, third person behind the projector


@dataclass
class Drawn:
    """One frame drawn: its media time (s), when it arrived, when the jitter buffer made it due
    and when its drawing finished (monotonic s), and the pose's state (fresh, stale, none)."""

    pts_s: float
    arrival_s: float
    due_s: float
    drawn_s: float
    pose: str


@dataclass
class MavlinkSummary:
    """What a run took from MAVLink: messages used by type, the lag applied at the end and each
    window's estimate (s, the video behind the telemetry), and the gimbal's presence."""

    address: str
    used: dict[str, int] = field(default_factory=dict)
    lag_s: float | None = None
    estimates_s: list[float] = field(default_factory=list)
    gimbal: bool = False

    def line(self) -> str:
        used = ", ".join(f"{n} {k}" for k, n in sorted(self.used.items())) or "nothing"
        e = self.estimates_s
        lag = (
            f"the video lags the telemetry by {1000 * self.lag_s:.0f} ms (the median of {len(e)} estimates, "
            f"{1000 * min(e):.0f} to {1000 * max(e):.0f} ms)"
            if self.lag_s is not None
            else "no lag estimated (the camera did not turn enough, or too short)"
        )
        return f"MAVLink {self.address}: {used}; {lag}"


@dataclass
class LiveRun:
    """What a run received, drew and lost, with the messages it said."""

    url: str
    drawn: list[Drawn] = field(default_factory=list)
    received: int = 0
    missing: int = 0
    skipped: int = 0
    late: int = 0
    overflow: int = 0
    undecodable: int = 0
    bad_klv: int = 0
    stale: int = 0
    without_pose: int = 0
    reconnects: int = 0
    ended: str = ""
    delay_s: float = DEFAULT_DELAY_S
    origin_s: float | None = None  # the stream-clock seconds of media time 0
    frame: LocalFrame | None = None  # the local ENU frame the cameras are in
    mavlink: MavlinkSummary | None = None
    messages: Messages = field(default_factory=Messages)

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
        return (
            f"{self.url}: {self.received} frames received ({self.missing} lost on the way), "
            f"{len(self.drawn)} drawn, "
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
    horizontal field of view where the feed does not say it (None: the KLV's, else 73.7 deg)."""

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


def _scene(poses: LivePoses | MavlinkPoses, options: LiveOptions, messages: Messages):
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


def run_live(
    url: str,
    options: LiveOptions = LiveOptions(),
    clock: Callable[[], float] = time.monotonic,
    on_drawn: Callable[[Drawn, Camera], None] | None = None,
) -> LiveRun:
    """Receive `url` and draw it off screen until `options.seconds` or silence; see the module
    docstring. on_drawn(d, projector): called after each frame is drawn."""
    run = LiveRun(url, delay_s=options.delay_s)
    messages = run.messages
    buffer = JitterBuffer(options.delay_s)
    klv_poses = LivePoses(stale_after_s=options.delay_s)
    poses: LivePoses | MavlinkPoses = klv_poses
    mav = lag = None
    if options.mavlink is not None:
        telemetry = MavlinkTelemetry()
        poses = MavlinkPoses(telemetry, lambda: buffer.link_s, options.delay_s)
        mav = MavlinkReceiver(options.mavlink, telemetry, messages, clock).start()
        mav.wait_ready()
        run.mavlink = MavlinkSummary(options.mavlink)
    recorder = Recorder(options.record) if options.record is not None else None

    def on_frame(t: float, luma) -> None:
        if lag is not None:
            lag.feed(t, luma)

    receiver = Receiver(
        url, buffer, klv_poses, messages, recorder, clock, on_frame, mav is not None
    ).start()
    start = clock()
    ctx = renderer = target = None
    frame = intr = None
    view_intr = Intrinsics.from_fov(*options.size, VIEW_HFOV_DEG)
    last_camera: Camera | None = None
    try:
        while True:
            now = clock()
            if options.seconds is not None and now - start >= options.seconds:
                run.ended = f"ended after {options.seconds:g} s"
                break
            heard = receiver.last_arrival_s if receiver.last_arrival_s is not None else start
            if now - heard >= options.silence_s:
                run.ended = f"ended: the stream was silent for {options.silence_s:g} s"
                messages.add(run.ended)
                break
            if renderer is None:
                if receiver.size is None or (not len(poses) and options.origin is None):
                    time.sleep(0.005)
                    continue
                frame, mesh = _scene(poses, options, messages)
                run.frame = frame
                hfov = options.hfov_deg or poses.hfov_deg or ASSUMED_DRONE_HFOV_DEG
                if options.hfov_deg is None and poses.hfov_deg is None:
                    messages.add(
                        f"the feed gives no field of view: {hfov:.1f} deg assumed (give --fov)"
                    )
                intr = Intrinsics.from_fov(*receiver.size, hfov)
                if mav is not None:
                    if not poses.telemetry.has_gimbal:
                        messages.add(
                            "MAVLink: no gimbal attitude (GIMBAL_DEVICE_ATTITUDE_STATUS, MOUNT_STATUS): the camera is taken to look along the vehicle's nose"
                        )
                    lag = LagEstimator(poses, intr, messages).start()
                ctx = create_offscreen_context()
                renderer = FusionRenderer(ctx, mesh)
                target = OffscreenTarget(ctx, *options.size)
            with receiver.lock:
                item = buffer.take(now)
                due = buffer.due_at(item) if item is not None else now
                wake = buffer.next_due()
            if item is None:
                time.sleep(min(max((wake or now + 0.005) - clock(), 0.0005), 0.005))
                continue
            pose = poses.at(item.pts_s, frame, intr, options.far_m)
            camera = pose.camera or last_camera
            if pose.state == STALE:
                run.stale += 1
                feed = "MAVLink telemetry" if mav is not None else "KLV"
                messages.add_once(
                    "stale",
                    f"frames drawn with a stale pose (the {feed} lags behind the video by more than the buffer): counted",
                )
            elif pose.state == NONE:
                run.without_pose += 1
            if camera is None:
                continue  # no pose has arrived yet: nothing to project from
            last_camera = camera
            y, u, v = item.payload
            renderer.set_video_yuv(y, u, v, 0, y.shape[0] >= 720)
            renderer.set_projector(camera)
            view = window_camera(camera, view_intr, None, None, options.far_m)
            renderer.draw(view, target.fbo)
            wait_for_gpu(ctx)
            d = Drawn(item.pts_s, item.arrival_s, due, clock(), pose.state)
            run.drawn.append(d)
            if on_drawn is not None:
                on_drawn(d, camera)
    finally:
        receiver.stop()
        if lag is not None:
            lag.stop()
        if mav is not None:
            mav.stop()
        if recorder is not None:
            recorder.close()
        if renderer is not None:
            target.release()
            renderer.release()
            ctx.release()
    c = receiver.counts
    run.received, run.undecodable, run.missing = c.frames, c.undecodable, c.missing
    run.skipped, run.late, run.overflow = buffer.skipped, buffer.late, buffer.overflow
    run.bad_klv, run.reconnects = receiver.track.counts.bad, max(c.connects - 1, 0)
    run.origin_s = receiver.origin_s
    if run.mavlink is not None:
        run.mavlink.used = dict(poses.telemetry.counts.used)
        run.mavlink.gimbal = poses.telemetry.has_gimbal
        if lag is not None:
            run.mavlink.lag_s = lag.lag_s
            run.mavlink.estimates_s = [-e.offset_s for e in lag.estimates]
    return run
