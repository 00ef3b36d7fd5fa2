"""The lag of a live video behind its MAVLink telemetry, estimated while it flies by the sync
machinery (app.sync): the camera's rotation rate seen in the video (sparse optical flow between
consecutive frames, app.sync.flow.pair_rotation) against the rate of the camera attitude the
telemetry gives (app.sync.rates.attitude_rates), fitted by app.sync.fit.estimate_offset.

Forward only: every EVERY_S of video, once WINDOW_S has arrived, the newest WINDOW_S are fitted
(less the last MAX_LAG_S, whose telemetry has not all arrived); when the fit is confident and
the camera turned enough to time it, it joins the estimates, and once AGREEING of them lie within
AGREE_S of their median, that median applies to the frames drawn from then on
(MavlinkPoses.offset_s); frames already drawn are never redrawn. A hovering drone shows no timing: the offset stays where it
was, said once. How well a window times the video depends on how fast the turns change: a
6 s weave of +-30 deg within ~25 ms, a lazy 12 s weave within ~0.15 s (docs/PERFORMANCE.md).

Runs on a daemon thread; the receiver hands over each frame's luma plane (`feed`), never
waiting: frames the estimator has not caught up with are dropped from its queue (counted).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import cv2
import numpy as np

from app.camera.intrinsics import Intrinsics
from app.core.messages import Messages
from app.core.worker import Worker
from app.io.mavlink import MavlinkTelemetry
from app.live.pose import MavlinkPoses
from app.sync.fit import MAX_LAG_S, SyncResult, estimate_offset
from app.sync.flow import pair_rotation
from app.sync.rates import RateCurve, attitude_rates, pinhole_bearings

FLOW_WIDTH_PX = 240  # the luma plane reduced to this width for the flow
WINDOW_S = 10.0  # video kept for each estimate (s): the newest MAX_LAG_S wait for telemetry
MIN_SPAN_S = 6.0  # video a fit needs, covered by telemetry MAX_LAG_S either side
EVERY_S = 2.0  # an estimate every this much video (s)
AGREEING = 2  # estimates within AGREE_S of their median before it is applied
AGREE_S = 0.04
MIN_CONFIDENCE = 0.7  # mean correlation of the rate components at the fitted offset
MIN_TURN_DEG_S = 3.0  # the camera must turn faster than this ...
MIN_TURNING_S = 2.0  # ... for this long within the window to time it
QUEUE = 120
AXIS_DOMINANCE = 3.0  # rates about one axis this much larger than about any other: that axis


def _principal(reference: RateCurve) -> RateCurve:
    """The reference's rates about its principal axis (camera frame) where one axis carries
    nearly all of them (a drone turning about the vertical under a levelled gimbal): the video's
    rates are then compared about that axis only, which leaves out the apparent rotation the
    aircraft's travel puts on the others (as sync does for a course, app.sync.rates)."""
    _, s, vt = np.linalg.svd(reference.omega, full_matrices=False)
    if s[0] < AXIS_DOMINANCE * s[1]:
        return reference
    axis = vt[0]
    return RateCurve(reference.t, (reference.omega @ axis)[:, None], axis)


class LagEstimator(Worker):
    """See the module docstring. intrinsics: the video's assumed pinhole (display pixels)."""

    def __init__(
        self,
        poses: MavlinkPoses,
        intrinsics: Intrinsics,
        messages: Messages,
        on_estimate: Callable[[SyncResult], None] | None = None,
    ) -> None:
        self.poses = poses
        self.bearings = pinhole_bearings(intrinsics)
        self.scale = FLOW_WIDTH_PX / intrinsics.width
        self.size = (FLOW_WIDTH_PX, max(2, round(intrinsics.height * self.scale)))
        self.messages = messages
        self.on_estimate = on_estimate
        self.estimates: list[SyncResult] = []
        self.applied = False
        self.dropped = 0
        self._queue: deque[tuple[float, np.ndarray]] = deque()
        self._rates: deque[tuple[float, np.ndarray]] = deque()
        self._last_fit_t: float | None = None
        super().__init__("geofuse-lag")

    @property
    def lag_s(self) -> float | None:
        """The lag applied now (s, the video behind the telemetry), None before any."""
        return -self.poses.offset_s if self.applied else None

    def feed(self, t: float, luma: np.ndarray) -> None:
        """A decoded frame's media time (s) and luma plane (h, w uint8); never blocks."""
        if len(self._queue) >= QUEUE:
            self._queue.popleft()
            self.dropped += 1
        small = cv2.resize(luma, self.size, interpolation=cv2.INTER_AREA)
        self._queue.append((t, small))
        self._wake.set()

    def _run(self) -> None:
        prev: tuple[float, np.ndarray] | None = None
        while not self._stop.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            while self._queue and not self._stop.is_set():
                t, grey = self._queue.popleft()
                if prev is not None and t > prev[0]:
                    rv = pair_rotation(prev[1], grey, self.scale, self.bearings)
                    if rv is not None:
                        self._rates.append(((t + prev[0]) / 2, rv / (t - prev[0])))
                prev = (t, grey) if prev is None or t > prev[0] else prev
                while self._rates and self._rates[0][0] < t - WINDOW_S:
                    self._rates.popleft()
                if self._due(t):
                    self._fit(t)

    def _due(self, t: float) -> bool:
        if not self._rates or self._rates[-1][0] - self._rates[0][0] < WINDOW_S - 1.0:
            return False
        return self._last_fit_t is None or t - self._last_fit_t >= EVERY_S

    def _fit(self, t: float) -> None:
        self._last_fit_t = t
        c = self.poses.boot_offset()
        if c is None:
            return
        video = RateCurve(
            np.array([r[0] for r in self._rates]), np.array([r[1] for r in self._rates])
        )
        result = fit_window(video, self.poses.telemetry, c)
        if result == STILL:
            self.messages.add_once(
                "lag-still",
                "MAVLink: the camera hardly turns, so the video's lag behind the telemetry cannot be timed yet (kept at "
                f"{1000 * -self.poses.offset_s:.0f} ms)",
            )
            return
        if result is None:
            return
        self.estimates.append(result)
        offsets = np.array([e.offset_s for e in self.estimates])
        median = float(np.median(offsets))
        if np.sum(np.abs(offsets - median) <= AGREE_S) < AGREEING:
            return  # one window alone can be fooled (the aircraft's travel seen as a turn)
        first = not self.applied
        self.applied = True
        self.poses.offset_s = median
        if first:
            self.messages.info(
                f"MAVLink: the video lags the telemetry by {1000 * -median:.0f} ms "
                f"(estimated from the camera's turns in {len(offsets)} windows); applied from now on"
            )
        if self.on_estimate is not None:
            self.on_estimate(result)


STILL = "still"


def fit_window(video: RateCurve, telemetry: MavlinkTelemetry, c: float) -> SyncResult | str | None:
    """One window's fit: the video's rates (media s) against the rates of the camera attitude the
    telemetry gives over the window and MAX_LAG_S either side (boot s = media s + c + offset);
    STILL when the camera turned too little to time, None when the fit is not confident."""
    times = telemetry.attitude_times(video.t[0] + c - MAX_LAG_S - 1.0)
    times = times[times <= video.t[-1] + c + MAX_LAG_S + 1.0]
    if len(times) < 20:
        return None
    # only video whose every candidate lag the telemetry covers: a lag searched into telemetry
    # that has not arrived yet (the live edge) would compare the video with nothing
    keep = (video.t + c - MAX_LAG_S >= times[0]) & (video.t + c + MAX_LAG_S <= times[-1])
    if keep.sum() < 10 or np.ptp(video.t[keep]) < MIN_SPAN_S:
        return None
    video = RateCurve(video.t[keep], video.omega[keep])
    q = np.array([telemetry.at(b).q for b in times])
    reference = attitude_rates(times, q)
    turning = np.degrees(np.linalg.norm(reference.omega, axis=1)) > MIN_TURN_DEG_S
    if turning.sum() * float(np.median(np.diff(reference.t))) < MIN_TURNING_S:
        return STILL
    result = estimate_offset(video, _principal(reference), c)
    return result if result.confidence >= MIN_CONFIDENCE else None
