"""Window-camera navigation, pure numpy: free roam (WASD/QE + mouse look, speed on the wheel),
orbit around a picked point, "through the phone" (riding the video's camera), and follow (a chase
view behind and above the projector, looking where its optical axis meets the ground: a drone's
live feed). Moving or looking while following goes on in free roam from the chase view."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.constants import VIEW_FAR_M, VIEW_NEAR_M
from app.geodesy import rotations

MODES = ("free", "orbit", "phone", "follow")


def chase(projector: Camera, ground_u: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(eye, target) ENU m of the follow view: the target where the projector's optical axis
    meets the height ground_u (35 m ahead at least, 3 km at most), the eye 0.6 of that distance
    behind the projector (along its heading) and 0.35 of it above."""
    forward = rotations.rotate(projector.orientation, [0.0, 0.0, -1.0])
    pos = np.asarray(projector.position, np.float64)
    ahead = float(np.clip((pos[2] - ground_u) / max(-forward[2], 0.05), 35.0, 3000.0))
    flat = np.array([forward[0], forward[1], 0.0])
    flat = flat / max(np.linalg.norm(flat), 1e-9)
    return pos - flat * 0.6 * ahead + [0.0, 0.0, 0.35 * ahead], pos + forward * ahead


@dataclass
class Navigator:
    """yaw: degrees clockwise from north of the view direction; pitch: degrees above the horizon;
    speed: m/s of free roam; orbit target and distance in ENU metres."""

    position: np.ndarray = field(default_factory=lambda: np.array([35.0, -160.0, 40.0]))
    yaw: float = -12.0
    pitch: float = -12.0
    speed: float = 10.0
    mode: str = "free"
    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distance: float = 60.0
    home: tuple | None = None
    chased: tuple | None = None  # the follow view's last (eye, target)

    def __post_init__(self) -> None:
        self.home = (self.position.copy(), self.yaw, self.pitch)

    def look_at(self, eye: np.ndarray, target: np.ndarray) -> None:
        """Free roam from `eye` looking at `target` (ENU m)."""
        d = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
        self.mode = "free"
        self.position = np.asarray(eye, np.float64).copy()
        self.yaw = float(np.degrees(np.arctan2(d[0], d[1])))
        self.pitch = float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1]))))

    def forward(self) -> np.ndarray:
        y, p = np.radians(self.yaw), np.radians(self.pitch)
        return np.array([np.sin(y) * np.cos(p), np.cos(y) * np.cos(p), np.sin(p)])

    def _leave_follow(self) -> None:
        if self.mode == "follow" and self.chased is not None:
            self.look_at(*self.chased)

    def move(self, dt: float, forward: float, right: float, up: float) -> None:
        """Free roam by key axes in [-1, 1] for dt seconds (W/S, D/A, E/Q)."""
        if self.mode == "phone" or not (forward or right or up):
            return
        self._leave_follow()
        f = self.forward()
        r = np.array([np.cos(np.radians(self.yaw)), -np.sin(np.radians(self.yaw)), 0.0])
        step = (f * forward + r * right + np.array([0.0, 0.0, 1.0]) * up) * self.speed * dt
        if self.mode == "orbit":
            self.target = self.target + step
        else:
            self.position = self.position + step

    def look(self, dx_px: float, dy_px: float, deg_per_px: float = 0.15) -> None:
        """Mouse look (free) or orbit drag (orbit): pixels of mouse motion."""
        if self.mode == "phone" or not (dx_px or dy_px):
            return
        self._leave_follow()
        self.yaw = (self.yaw + dx_px * deg_per_px + 180.0) % 360.0 - 180.0
        self.pitch = float(np.clip(self.pitch - dy_px * deg_per_px, -89.0, 89.0))

    def wheel(self, steps: float) -> None:
        """Wheel: free roam speed (x1.25 per step) or orbit distance."""
        if self.mode == "orbit":
            self.distance = float(np.clip(self.distance * 0.85**steps, 2.0, 5000.0))
        else:
            self.speed = float(np.clip(self.speed * 1.25**steps, 0.5, 500.0))

    def orbit_around(self, point: np.ndarray) -> None:
        """Orbit the picked point, keeping the current view direction and position."""
        self.target = np.asarray(point, np.float64)
        self.distance = float(max(2.0, np.linalg.norm(self.position - self.target)))
        d = self.target - self.position
        self.yaw = float(np.degrees(np.arctan2(d[0], d[1])))
        self.pitch = float(
            np.degrees(np.arcsin(np.clip(d[2] / max(np.linalg.norm(d), 1e-9), -1, 1)))
        )
        self.mode = "orbit"

    def reset(self) -> None:
        self.position, self.yaw, self.pitch = self.home[0].copy(), self.home[1], self.home[2]
        self.mode = "free"

    def camera(
        self,
        intrinsics: Intrinsics,
        phone: Camera | None,
        near: float = VIEW_NEAR_M,
        far: float = VIEW_FAR_M,
    ) -> Camera:
        """The window camera for the current mode."""
        if self.mode == "phone" and phone is not None:
            return Camera.create(intrinsics, phone.position, phone.orientation, near, far)
        if self.mode == "follow" and phone is not None:
            eye, target = self.chased = chase(phone)
            return Camera.create(intrinsics, eye, look_at_quat(eye, target), near, far)
        if self.mode == "orbit":
            eye = self.target - self.forward() * self.distance
            return Camera.create(intrinsics, eye, look_at_quat(eye, self.target), near, far)
        q = rotations.camera_quat_from_hpr(self.yaw % 360.0, self.pitch, 0.0)
        return Camera.create(intrinsics, self.position, q, near, far)
