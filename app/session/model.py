"""A session: every input of one clip read, validated and placed on one clock, frozen. Built by
`app.session.assemble` (from a manifest) or `app.footage.clips` (straight from a camera's files), read by
everything downstream. `device_attitude` answers "the device's attitude under this source".

Names: a *filter* is one of our estimators (FILTERS); a *recorded* attitude is one the device or
the simulation wrote (phone, camera, telemetry, truth); a *source* is either, or the derived
`course` attitude of a drone clip without gimbal angles; the *reference* is the source that others
are compared with (app.playback.library).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from app.attitude import heading
from app.attitude.filters import estimate, resample
from app.attitude.heading import HeadingPolicy
from app.camera.intrinsics import Intrinsics, Zoom
from app.camera.lens import Lens
from app.camera.trajectory import PositionTrack, device_to_camera
from app.core.constants import COURSE, REGISTERED, TRUTH, UNIX_TIME_FLOOR_S
from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.streams import GnssTrack, OrientationStream, VectorStream, with_accuracy
from app.io.video import VideoInfo
from app.scene import Placement, load_scene
from app.scene.ground import ground_heights
from app.scene.mesh import MeshData
from app.session.start import PlatformHeights, StartArea

FILTERS = {
    "gd-ahrs": ("gd", True),
    "gd-imu": ("gd", False),
    "cf-ahrs": ("cf", True),
    "cf-imu": ("cf", False),
    "offline": ("offline", True),
}
__all__ = ["COURSE", "FILTERS", "REGISTERED", "TRUTH", "Session", "device_attitude"]


@dataclass(frozen=True)
class Session:
    """Everything a solve needs, read and validated; times on the session clock (seconds).

    frame_times: (F,) session seconds of each video frame (presentation time + start + offset, or
    the paper's Eq. 5); recorded: device -> ENU attitudes written by the device or the
    simulation; heading: where heading comes from (app.attitude.heading.HeadingPolicy);
    device_is_camera: action cameras and drones, whose device frame is the camera's;
    aircraft_yaw: a drone's own yaw (t s, deg) for the `course` source; mesh: the scene when it is
    generated (an assumed ground) or was loaded while assembling.
    """

    path: Path  # the manifest, or the clip opened directly
    frame: LocalFrame
    scene_path: Path | None
    placement: Placement
    video: VideoInfo
    frame_times: np.ndarray
    intrinsics: Intrinsics
    rotation_cw: int
    acc: VectorStream | None
    gyr: VectorStream | None
    mag: VectorStream | None
    gnss: GnssTrack
    recorded: dict[str, OrientationStream]
    declination_deg: float
    messages: Messages = field(default_factory=Messages)
    inputs: tuple[Path, ...] = ()
    truth_position: GnssTrack | None = None
    truth_frame_times: np.ndarray | None = None
    height_mode: str = "gnss"
    mount_height_m: float = 1.5
    heading: HeadingPolicy = HeadingPolicy()
    device_is_camera: bool = False
    aircraft_yaw: tuple[np.ndarray, np.ndarray] | None = None  # (t session s, yaw deg) for `course`
    lens: Lens | None = None  # of the displayed video; intrinsics then enclose it
    readout_s: float | None = (
        None  # rolling shutter: the sensor's readout time, seconds (None: unknown, off)
    )
    mesh: MeshData | None = None
    layers: tuple = ()  # app.scene.layers.Layer: the scene's layers as named ((): an assumed ground)
    utc_at_zero_s: float | None = None  # Unix time (UTC) of session time 0, when the camera says
    camera: str = ""  # the camera as its files name it (a GoPro's model, a DJI camera); "" unknown
    zoom: Zoom | None = None  # a field of view per time (FMV zoom); intrinsics: the median one
    further: tuple = ()  # app.session.config.ClipRef: further clips its manifest names ([[clips]])
    start: StartArea | None = None  # where a clip without any GNSS fix begins (cold start)
    # the heights its telemetry gives where it has no position (a cold start's)
    platform_heights: PlatformHeights | None = None
    # an accuracy stated for the fixes that state none (stating_accuracy): what stated it, and
    # the receiver's own accuracies before it did
    accuracy_by: str = ""
    own_accuracy: np.ndarray | None = None

    @property
    def heading_note(self) -> str:
        return self.heading.note

    @property
    def heading_from_course(self) -> bool:
        return self.heading.from_course

    @property
    def course_pitch_deg(self) -> float | None:
        return self.heading.course_pitch_deg

    def stating_accuracy(self, accuracy_m: float | None, given_by: str) -> Session:
        """This session with accuracy_m (m, 1 sigma per axis; None: as it is) as the stated
        horizontal accuracy of its GNSS fixes that state none (a DJI subtitle, a GPX file: the
        checks against the scene and the IMU assume CheckSettings.accuracy_m, 5 m, otherwise),
        said in its messages with what gave it (given_by: an option, a manifest key); a later
        statement (an option over the manifest's key) replaces an earlier one."""
        if accuracy_m is None or not len(self.gnss.t):
            return self
        own = self.own_accuracy if self.accuracy_by else self.gnss.h_acc
        gnss, filled = with_accuracy(replace(self.gnss, h_acc=own), accuracy_m)
        if not filled:
            self.messages.info(
                f"{given_by} {accuracy_m:g} m: every GNSS fix states its own accuracy, kept"
            )
            return self
        over = f", over {self.accuracy_by}" if self.accuracy_by else ""
        self.messages.info(
            f"GNSS accuracy {accuracy_m:g} m ({given_by}{over}) for the {filled} of {len(gnss.t)} fixes that state none: their tests against the scene and the IMU use it"
        )
        return replace(self, gnss=gnss, accuracy_by=given_by, own_accuracy=own)

    def camera_mount(self) -> np.ndarray:
        """Quaternion of the camera (of the displayed video) in the device frame: a phone's back
        camera turns with the display rotation (app.camera.trajectory.device_to_camera); an action
        camera's or drone's device frame is its camera's, turned only when the video is."""
        if self.device_is_camera:
            return rotations.about_z(
                -float(self.rotation_cw)
            )  # a clockwise display turn of the image
        return device_to_camera(self.rotation_cw)

    def scene(self) -> MeshData:
        """The scene's arrays in the session's ENU frame (loaded once)."""
        return self._scene

    @cached_property
    def _scene(self) -> MeshData:
        return (
            self.mesh
            if self.mesh is not None
            else load_scene(self.scene_path, self.frame, self.placement)
        )

    def positions(self) -> PositionTrack:
        """The GNSS position track, with heights from the model's ground when asked (cached)."""
        return self._positions

    @cached_property
    def _positions(self) -> PositionTrack:
        g = self.gnss
        if len(g.t) < 2:
            raise DataFormatError(
                g.path,
                f"GNSS: {len(g.t)} fix(es), a moving camera needs at least 2 fixes (a clip without GNSS"
                " starts from an area: the registered source with --near LAT,LON --radius M)",
            )
        h = g.h
        if self.height_mode == "ground":
            enu = self.frame.geodetic_to_enu(g.lat, g.lon, g.h)
            ground = ground_heights(self.scene(), enu[:, :2])
            if np.isnan(ground).any():
                self.messages.add_once(
                    "fixes-off-model",
                    f"{int(np.isnan(ground).sum())} GNSS fixes lie off the model: their GNSS height is kept",
                )
            enu[:, 2] = np.where(np.isnan(ground), enu[:, 2], ground + self.mount_height_m)
            h = self.frame.enu_to_geodetic(enu)[:, 2]
        try:
            return PositionTrack.from_fixes(g.t, g.lat, g.lon, h, g.vel_enu)
        except ValueError as exc:
            raise DataFormatError(g.path, f"GNSS: {exc}") from exc

    @property
    def sources(self) -> list[str]:
        """The attitude sources this session offers: our filters (AHRS ones only with a
        magnetometer; none without an IMU), the derived course, the recorded attitudes, then
        `registered` where there is a scene to register against and a source to correct, truth
        last."""
        own: list[str] = []
        if self.gyr is not None and self.acc is not None:
            own = [k for k, (_, ahrs) in FILTERS.items() if self.mag is not None or not ahrs]
            if self.mag is None:
                own.append("offline")
        if self.course_pitch_deg is not None:
            own.append(COURSE)
        recorded = [r for r in self.recorded if r != TRUTH]
        registered = (
            [REGISTERED] if (own or recorded) and self.registration_refusal() is None else []
        )
        out = own + recorded + registered + ([TRUTH] if TRUTH in self.recorded else [])
        prefer = self.heading.prefer
        return [prefer] + [s for s in out if s != prefer] if prefer in out else out

    def registration_refusal(self) -> str | None:
        """Why the video cannot be registered against this scene (None: it can): an assumed flat
        ground has nothing to register against. A scene without texture (a grey model, a city's
        LoD2 buildings, a bare DEM) is registered by its geometry (app.register.edges)."""
        return scene_refusal(self.scene() if self.layers else None, self.layers)

    def utc_of(self, session_s: float) -> float | None:
        """Unix seconds (UTC) at session time session_s: from the camera's own clock
        (`utc_at_zero_s`: a GoPro's GPS time, a DJI subtitle's dates), or the session clock itself
        where it already is Unix time (a GPX or Sensor Logger session); None where no clock is
        known."""
        if self.utc_at_zero_s is not None:
            return self.utc_at_zero_s + float(session_s)
        return float(session_s) if session_s > UNIX_TIME_FLOOR_S else None

    def check_source(self, source: str) -> None:
        """ValueError naming what the session offers, for a source it does not."""
        if source == REGISTERED and self.registration_refusal() is not None:
            raise ValueError(self.registration_refusal())
        if source not in self.sources:
            raise ValueError(
                f"unknown attitude source {source!r}; this session offers {', '.join(self.sources)}"
            )


def device_attitude(
    session: Session, source: str, course_pitch_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(t (N,) session s, device -> ENU quaternions (N, 4), true north) for one source.

    course_pitch_deg: the `course` source's pitch (default: the session's)."""
    session.check_source(source)
    if source == REGISTERED:
        raise ValueError(
            "the registered source is a whole pose track, not an attitude: solve it with app.solve.track.solve_track"
        )
    if source == COURSE:
        pos = session.positions()
        pitch = session.course_pitch_deg if course_pitch_deg is None else course_pitch_deg
        ref = heading.course_attitude(
            pos.t, pos.vel_enu, pitch, session.gnss.path, session.aircraft_yaw
        )
        return ref.t, ref.q  # the device is the camera (drones), unturned
    if source in session.recorded:
        ref = session.recorded[source]
        if source == "camera" and session.heading_from_course:
            pos = session.positions()
            return ref.t, heading.align_to_course(
                pos.t, pos.vel_enu, ref.t, ref.q, session.camera_mount(), session.messages
            )
        return ref.t, ref.q
    method, ahrs = FILTERS[source]
    use_mag = ahrs and session.mag is not None
    t = session.gyr.t
    acc = resample(t, session.acc.t, session.acc.values)
    mag = resample(t, session.mag.t, session.mag.values) if use_mag else None
    q = estimate(
        t,
        session.gyr.values,
        acc,
        mag,
        method=method,
        declination_deg=session.declination_deg if use_mag else 0.0,
    )
    if not use_mag and session.mag is not None:
        q = heading.anchor_heading(
            q, resample(t, session.mag.t, session.mag.values), session.declination_deg
        )
    elif not use_mag and session.heading_from_course:
        pos = session.positions()
        q = heading.align_to_course(
            pos.t, pos.vel_enu, t, q, session.camera_mount(), session.messages
        )
    return t, q


def scene_refusal(mesh, layers) -> str | None:
    """Why a video cannot be registered against this scene (mesh: its MeshData, None for an
    assumed flat ground; layers: what it was made of), None when it can (a session's, and a live
    feed's, app.live.register)."""
    if mesh is None or not layers:
        return "the scene is an assumed flat ground: there is nothing to register the video against (name a model, tileset or DEM)"
    return None
