"""Registration of a live feed, forward only: keyframes registered in the background against the
scene (app.register's render-and-compare, from the pose the telemetry gives), and the correction
they find applied to the frames drawn from then on, never to frames already drawn.

The correction is a bias, as a GNSS position and a gimbal's angles carry one: a shift (ENU m,
the position's) and a rotation in the camera's own frame (the angles': a gimbal's heading, pitch
or mounting bias stays the same turn of the camera while the aircraft turns, which a rotation
fixed in the world would not) between the telemetry's camera and the registered one. The applied
correction is the median of the last KEEP registered keyframes' (position componentwise, rotation
by its rotation vector); a keyframe farther than GATE_M or GATE_DEG from it, once GATED have been
kept, is set aside (counted) as a mismatch. A keyframe is offered every `every_s` of video while
the thread is free (never queued: the newest frame is what matters live); the display never waits.

One thread with its own off-screen GL context renders the scene for the matcher.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import cv2
import numpy as np

from app.camera.pinhole import Camera
from app.core.messages import Messages
from app.core.worker import Worker
from app.geodesy import rotations
from app.playback.decoder import planes_to_rgb
from app.register.solve import Registrar, RegistrationSettings
from app.scene.mesh import MeshData

EVERY_S = 1.0  # a keyframe offered every this much video (s)
KEEP = 5
GATE_M, GATE_DEG, GATED = 2.0, 1.5, 3
LIVE_SETTINGS = RegistrationSettings(long_side=640, max_iterations=5)


@dataclass
class LiveCorrection:
    """What registration has found so far: keyframes tried, registered, set aside; the applied
    shift (ENU m) and rotation (rotation vector, rad, camera frame); the first media time it
    applied from."""

    tried: int = 0
    registered: int = 0
    mismatched: int = 0
    shift_m: np.ndarray | None = None
    rotvec: np.ndarray | None = None
    since_s: float | None = None
    last_failure: str = ""
    kept: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

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
    """See the module docstring. mesh: the scene (textured: app.session.model.scene_refusal)."""

    def __init__(
        self,
        mesh: MeshData,
        messages: Messages,
        every_s: float = EVERY_S,
        settings: RegistrationSettings = LIVE_SETTINGS,
    ) -> None:
        self.mesh, self.messages, self.every_s, self.settings = mesh, messages, every_s, settings
        self.state = LiveCorrection()
        self._lock = threading.Lock()
        self._offer: tuple[float, tuple, Camera] | None = None
        self._last_offered: float | None = None
        self._busy = False
        super().__init__("geofuse-register")

    def offer(self, t: float, planes, prior: Camera) -> None:
        """A frame drawn (media time t s, its yuv planes, the telemetry's camera): taken as the
        next keyframe when every_s has passed since the last and the thread is free."""
        if self._busy or (self._last_offered is not None and t - self._last_offered < self.every_s):
            return
        self._last_offered = t
        with self._lock:
            self._offer = (t, tuple(np.array(p, copy=True) for p in planes), prior)
        self._busy = True
        self._wake.set()

    def correct(self, camera: Camera) -> Camera:
        """The telemetry's camera moved by the correction in force (itself before any)."""
        with self._lock:
            shift, rotvec = self.state.shift_m, self.state.rotvec
        if shift is None:
            return camera
        q = rotations.multiply(
            np.asarray(camera.orientation, np.float64), rotations.from_rotvec(rotvec)
        )
        return Camera.create(
            camera.intrinsics,
            np.asarray(camera.position) + shift,
            q,
            camera.near,
            camera.far,
            camera.lens,
        )

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
        fix, solved, _ = registrar.keyframe(rgb, prior)
        s = self.state
        s.tried += 1
        if solved is None:
            s.last_failure = fix.reason
            return
        shift = np.asarray(solved.position) - np.asarray(prior.position)
        delta = rotations.multiply(
            rotations.conjugate(np.asarray(prior.orientation)), np.asarray(solved.orientation)
        )
        rotvec = rotations.to_scipy(delta).as_rotvec()
        if (
            len(s.kept) >= GATED
            and s.shift_m is not None
            and (
                np.linalg.norm(shift - s.shift_m) > GATE_M
                or np.degrees(np.linalg.norm(rotvec - s.rotvec)) > GATE_DEG
            )
        ):
            s.mismatched += 1
            return
        s.registered += 1
        s.kept = (s.kept + [(shift, rotvec)])[-KEEP:]
        first = s.shift_m is None
        with self._lock:
            s.shift_m = np.median([k[0] for k in s.kept], axis=0)
            s.rotvec = np.median([k[1] for k in s.kept], axis=0)
            if first:
                s.since_s = t
        if first:
            self.messages.info(
                f"registered live from {t:.1f} s: the telemetry's pose was {np.linalg.norm(shift):.1f} m and "
                f"{np.degrees(np.linalg.norm(rotvec)):.1f} deg off; corrected from then on"
            )
