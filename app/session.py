"""One session = one TOML manifest naming the scene and its placement, the video, the sensor and
GNSS logs, the camera intrinsics, the time offset and optional reference attitudes.

    [origin]                      # optional: the session's ENU origin (default: the scene's)
    lat = 34.80                   # degrees
    lon = 113.53                  # degrees
    h = 110.0                     # ellipsoidal metres

    [scene]
    path = "scene.glb"            # glTF/GLB, OBJ, PLY
    origin = [34.80, 113.53, 110.0]
    up_axis = "Y"                 # optional: Y for glTF, Z otherwise
    heading_deg = 0.0             # optional
    scale = 1.0                   # optional

    [video]
    path = "clip.mp4"
    start_time = 1700000000.0     # optional: session-clock seconds of the first frame (default:
                                  # the video's creation time)
    time_offset_s = 0.0           # optional: added to every frame time (sync correction)
    timing = "pts"                # or "eq5": frame i at i / nominal fps (paper Eq. 5)

    [camera]
    hfov_deg = 66.0               # or focal_mm + sensor_width_mm
    rotation_cw = 90              # optional: override the video's display rotation

    [sensors]
    mag_calibration = "clip"      # or "none": fit hard-iron offset and scale on the clip
    format = "csv"                # "csv": acc, gyr, mag, orientation files below;
                                  # "gopro": the GPMF telemetry inside [video]'s MP4;
                                  # "none": no IMU (a drone clip with its .SRT as [gnss]);
    acc = "acc.csv"               # "sensorlogger": path = folder or zip
    gyr = "gyr.csv"
    mag = "mag.csv"               # optional: without it only IMU filters are offered
    orientation = "phone.csv"     # optional: the phone's own attitude (reference)

    [gnss]
    path = "gnss.csv"             # CSV (csvlog.py), GPX, or a DJI .SRT (times from the clip start)
    takeoff_height_m = 110.0      # optional, for heights above take-off: the take-off point's
                                  # ellipsoidal height (default: the scene's ground under the
                                  # first position)
    height_offset_m = 0.0         # optional: added to heights (e.g. geoid separation for GPX)
    height = "gnss"               # or "ground": the model's ground under each fix + mount height
    mount_height_m = 1.5          # with height = "ground": camera above the ground (hand-held 1.5)

    [truth]                       # optional, for simulated sessions
    orientation = "truth.csv"     # device -> ENU quaternions (t, qw, qx, qy, qz)
    position = "truth_pos.csv"    # optional: t, lat, lon, h
    frame_times = "frames.csv"    # optional: frame, t (each frame's true session time)

Relative paths resolve against the manifest's folder. Times of every log and of the video must be
on one clock (Unix seconds for phone apps). Every error names the manifest key.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.attitude import estimate, resample
from app.camera import Intrinsics
from app.errors import DataFormatError, ManifestError
from app.geomag import declination
from app.geo import LocalFrame
from app.io.streams import GnssTrack, OrientationStream, VectorStream, Warnings
from app.io.video import VideoInfo, probe
from app.scene import Placement
from app.scene.mesh import MeshData
from app.trajectory import PoseTrack, PositionTrack, device_to_camera

FILTERS = {
    "gd-ahrs": ("gd", True),
    "gd-imu": ("gd", False),
    "cf-ahrs": ("cf", True),
    "cf-imu": ("cf", False),
    "offline": ("offline", True),
}
REFERENCE_SOURCES = ("phone", "truth")


@dataclass(frozen=True)
class Manifest:
    path: Path
    data: dict[str, Any]

    def section(self, name: str, required: bool = True) -> dict[str, Any]:
        value = self.data.get(name)
        if value is None:
            if required:
                raise ManifestError(self.path, f"missing section [{name}]", field=name)
            return {}
        if not isinstance(value, dict):
            raise ManifestError(self.path, f"[{name}] must be a table", field=name)
        return value

    def get(self, section: str, key: str, kind: type | tuple[type, ...], default: Any = ..., required_section: bool = True) -> Any:
        sec = self.section(section, required_section)
        if key not in sec:
            if default is ...:
                raise ManifestError(self.path, f"missing key (expected {getattr(kind, '__name__', kind)})", field=f"{section}.{key}")
            return default
        value = sec[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kinds):
            raise ManifestError(self.path, f"got {value!r}, expected {' or '.join(k.__name__ for k in kinds)}", field=f"{section}.{key}")
        return value

    def file(self, section: str, key: str, required: bool = True, required_section: bool = True) -> Path | None:
        value = self.get(section, key, str, ... if required else None, required_section)
        if value is None:
            return None
        p = (self.path.parent / value).resolve()
        if not p.exists():
            raise ManifestError(self.path, f"names {value!r}, which does not exist ({p})", field=f"{section}.{key}")
        return p

    def triple(self, section: str, key: str, default: Any = ...) -> tuple[float, float, float] | None:
        value = self.get(section, key, list, default)
        if value is None:
            return None
        if len(value) != 3 or not all(isinstance(v, (int, float)) for v in value):
            raise ManifestError(self.path, f"got {value!r}, expected [latitude, longitude, height]", field=f"{section}.{key}")
        return tuple(float(v) for v in value)


def load_manifest(path: str | Path) -> Manifest:
    path = Path(path)
    if not path.is_file():
        raise ManifestError(path, "manifest does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ManifestError(path, f"not valid TOML ({exc})") from exc
    return Manifest(path.resolve(), data)


@dataclass
class Session:
    """Everything a solve needs, read and validated; times on the session clock (seconds)."""

    manifest: Manifest
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
    references: dict[str, OrientationStream]
    declination_deg: float
    warnings: Warnings = field(default_factory=Warnings)
    truth_position: GnssTrack | None = None
    truth_frame_times: np.ndarray | None = None
    height_mode: str = "gnss"
    mount_height_m: float = 1.5
    heading_note: str = ""  # how heading was obtained, when not from a magnetometer (for display)
    heading_from_course: bool = False  # IMU filters and the camera's own attitude: heading fitted to the course
    device_is_camera: bool = False  # action cameras and drones: the device frame is the camera's
    mesh: MeshData | None = None  # the scene, when it is generated rather than loaded
    _positions: PositionTrack | None = None

    def camera_mount(self) -> np.ndarray:
        """Quaternion of the camera (of the displayed video) in the device frame: a phone's back
        camera turns with the display rotation (app.trajectory.device_to_camera); an action
        camera's or drone's device frame is its camera's, turned only when the video is."""
        from app import rotations

        if self.device_is_camera:
            return rotations.about_z(-float(self.rotation_cw))  # a clockwise display turn of the image
        return device_to_camera(self.rotation_cw)

    def scene(self) -> MeshData:
        """The scene's arrays in the session's ENU frame (loaded once)."""
        if self.mesh is None:
            from app.scene import load_scene

            self.mesh = load_scene(self.scene_path, self.frame, self.placement)
        return self.mesh

    def positions(self) -> PositionTrack:
        """The GNSS position track, with heights from the model's ground when asked (cached)."""
        if self._positions is None:
            g = self.gnss
            h = g.h
            if self.height_mode == "ground":
                from app.scene.ground import ground_heights

                enu = self.frame.geodetic_to_enu(g.lat, g.lon, g.h)
                ground = ground_heights(self.scene(), enu[:, :2])
                if np.isnan(ground).any():
                    self.warnings.add(f"{int(np.isnan(ground).sum())} GNSS fixes lie off the model: their GNSS height is kept")
                enu[:, 2] = np.where(np.isnan(ground), enu[:, 2], ground + self.mount_height_m)
                h = self.frame.enu_to_geodetic(enu)[:, 2]
            try:
                self._positions = PositionTrack.from_fixes(g.t, g.lat, g.lon, h, g.vel_enu)
            except ValueError as exc:
                raise DataFormatError(g.source, f"GNSS: {exc}") from exc
        return self._positions

    @property
    def filters(self) -> list[str]:
        """The attitude sources this session offers (AHRS ones only with a magnetometer; none of
        the filters without an IMU), then its recorded attitudes (phone, camera, telemetry...)."""
        own: list[str] = []
        if self.gyr is not None and self.acc is not None:
            own = [k for k, (_, ahrs) in FILTERS.items() if self.mag is not None or not ahrs]
            if self.mag is None:
                own.append("offline")
        return own + [r for r in self.references if r != "truth"] + (["truth"] if "truth" in self.references else [])


def _intrinsics(m: Manifest, width: int, height: int) -> Intrinsics:
    cam = m.section("camera")
    try:
        if "hfov_deg" in cam:
            return Intrinsics.from_fov(width, height, m.get("camera", "hfov_deg", float))
        if "focal_mm" in cam:
            return Intrinsics.from_focal_length(width, height, m.get("camera", "focal_mm", float), m.get("camera", "sensor_width_mm", float))
    except ValueError as exc:
        raise ManifestError(m.path, str(exc), field="camera") from exc
    raise ManifestError(m.path, "expected hfov_deg, or focal_mm and sensor_width_mm", field="camera")


def _shifted(stream, dt: float):
    """A stream or track with its times moved by dt seconds (clip clock -> session clock)."""
    from dataclasses import replace as _replace

    return None if stream is None else _replace(stream, t=stream.t + dt)


def _sensors(m: Manifest, warnings: Warnings, video_start: float = 0.0) -> tuple[VectorStream, VectorStream, VectorStream | None, dict[str, OrientationStream], GnssTrack | None]:
    from app.io import csvlog

    fmt = m.get("sensors", "format", str, "csv")
    refs: dict[str, OrientationStream] = {}
    gnss = None
    if fmt == "none":
        acc = gyr = mag = None
    elif fmt == "gopro":
        from app.io.gopro import read_gopro

        rec = read_gopro(m.file("video", "path"), warnings)
        # GPMF times count from the clip start; the session clock adds the video's start time.
        acc, gyr, mag, gnss = (_shifted(x, video_start) for x in (rec.acc, rec.gyr, rec.mag, rec.gnss))
        if rec.camera is not None:
            refs["camera"] = _shifted(rec.camera, video_start)
    elif fmt == "sensorlogger":
        from app.io.sensorlogger import read_sensorlogger

        rec = read_sensorlogger(m.file("sensors", "path"), bool(m.get("sensors", "standardised", bool, False)), warnings)
        acc, gyr, mag, gnss = rec.acc, rec.gyr, rec.mag, rec.gnss
        if rec.orientation is not None:
            refs["phone"] = rec.orientation
    elif fmt == "csv":
        acc = csvlog.read_vector(m.file("sensors", "acc"), "acc", warnings)
        gyr = csvlog.read_vector(m.file("sensors", "gyr"), "gyr", warnings)
        mag_path = m.file("sensors", "mag", required=False)
        mag = csvlog.read_vector(mag_path, "mag", warnings) if mag_path else None
        ori = m.file("sensors", "orientation", required=False)
        if ori:
            refs["phone"] = csvlog.read_orientation(ori, warnings)
    else:
        raise ManifestError(m.path, f"got {fmt!r}, expected 'csv', 'sensorlogger', 'gopro' or 'none'", field="sensors.format")
    truth = m.file("truth", "orientation", required=False, required_section=False)
    if truth:
        refs["truth"] = csvlog.read_orientation(truth, warnings)
    return acc, gyr, mag, refs, gnss


def _gnss(m: Manifest, fallback: GnssTrack | None, warnings: Warnings, video_start: float, refs: dict[str, OrientationStream]) -> GnssTrack:
    from app.io import csvlog
    from app.io.gpx import read_gpx

    path = m.file("gnss", "path", required=fallback is None, required_section=fallback is None)
    track = fallback
    if path is not None and path.suffix.lower() == ".srt":
        return _srt_gnss(m, path, warnings, video_start, refs)
    if path is not None:
        track = read_gpx(path, warnings) if path.suffix.lower() == ".gpx" else csvlog.read_gnss(path, warnings)
    offset = m.get("gnss", "height_offset_m", float, 0.0, required_section=False)
    return GnssTrack(track.t, track.lat, track.lon, track.h + offset, track.vel_enu, track.h_acc, track.source)


def _srt_gnss(m: Manifest, path: Path, warnings: Warnings, video_start: float, refs: dict[str, OrientationStream]) -> GnssTrack:
    """A DJI subtitle as the session's GNSS (its times are the clip's, shifted to the session
    clock) and, with gimbal angles, its `telemetry` attitude. Heights above take-off get the
    take-off height later (`_takeoff_heights`), when the scene is at hand."""
    from app import rotations
    from app.io.dji_srt import read_srt

    tr = read_srt(path, warnings)
    ok = tr.has_position
    h = np.where(np.isfinite(tr.height), tr.height, 0.0)[ok]
    if tr.has_gimbal:
        g = np.isfinite(tr.gimbal_pry).all(axis=1)
        p, r, y = tr.gimbal_pry[g].T
        refs["telemetry"] = OrientationStream(video_start + tr.t[g], rotations.camera_quat_from_hpr(y % 360.0, p, r), str(path), "DJI gimbal (G.PRY)")
    source = f"{path}#relative" if tr.height_relative else str(path)
    return GnssTrack(video_start + tr.t[ok], tr.lat[ok], tr.lon[ok], h, None, None, source)


def _takeoff_heights(m: Manifest, session: "Session") -> None:
    """Heights above take-off + the take-off point's height: the manifest's value, else the
    scene's ground under the first position; says which."""
    g = session.gnss
    if not g.source.endswith("#relative"):
        return
    value = m.get("gnss", "takeoff_height_m", float, None, required_section=False)
    if value is None:
        from app.scene.ground import ground_heights

        first = session.frame.geodetic_to_enu(g.lat[0], g.lon[0], 0.0)
        ground = ground_heights(session.scene(), np.atleast_2d(first)[:, :2])[0]
        if not np.isfinite(ground):
            raise ManifestError(m.path, "heights are above take-off and the scene has no ground under the first position: give gnss.takeoff_height_m", field="gnss.takeoff_height_m")
        value = float(session.frame.enu_to_geodetic(np.array([first[0], first[1], ground]))[2])
        session.warnings.add(f"heights above take-off: take-off height {value:.2f} m from the scene's ground under the first position")
    else:
        session.warnings.add(f"heights above take-off: take-off height {value:.2f} m from gnss.takeoff_height_m")
    session.gnss = GnssTrack(g.t, g.lat, g.lon, g.h + value, g.vel_enu, g.h_acc, g.source.removesuffix("#relative"))


def open_session(path: str | Path) -> Session:
    """Read and validate a manifest and every file it names."""
    m = load_manifest(path)
    warnings = Warnings()
    scene_path = m.file("scene", "path")
    scene_origin = m.triple("scene", "origin", None)
    placement = Placement(scene_origin, m.get("scene", "up_axis", str, None), m.get("scene", "heading_deg", float, 0.0), m.get("scene", "scale", float, 1.0))
    origin_sec = m.section("origin", required=False)
    if origin_sec:
        origin = (m.get("origin", "lat", float), m.get("origin", "lon", float), m.get("origin", "h", float))
    elif scene_origin is not None:
        origin = scene_origin
    else:
        raise ManifestError(m.path, "give [origin] or scene.origin: the session needs a geographic origin", field="origin")
    try:
        frame = LocalFrame(*origin)
    except ValueError as exc:
        raise ManifestError(m.path, str(exc), field="origin") from exc

    video = probe(m.file("video", "path"))
    start = m.get("video", "start_time", float, video.creation_time)
    if start is None:
        raise ManifestError(m.path, "the video has no creation time: give video.start_time (session-clock seconds)", field="video.start_time")
    timing = m.get("video", "timing", str, "pts")
    if timing not in ("pts", "eq5"):
        raise ManifestError(m.path, f"got {timing!r}, expected 'pts' or 'eq5'", field="video.timing")
    clip_start = float(start) + m.get("video", "time_offset_s", float, 0.0)  # session-clock seconds
    frame_times = clip_start + (video.pts_s if timing == "pts" else video.eq5_times())
    rotation = int(m.get("camera", "rotation_cw", int, video.rotation_cw))
    if rotation % 90:
        raise ManifestError(m.path, f"got {rotation}, expected 0, 90, 180 or 270", field="camera.rotation_cw")
    w, h = (video.height, video.width) if rotation % 180 else (video.width, video.height)
    intr = _intrinsics(m, w, h)

    acc, gyr, mag, refs, logged_gnss = _sensors(m, warnings, clip_start)
    gnss = _gnss(m, logged_gnss, warnings, clip_start, refs)
    log = gyr if gyr is not None else gnss
    covered = (frame_times >= log.t[0]) & (frame_times <= log.t[-1])
    if not covered.any():
        raise ManifestError(
            m.path,
            f"no video frame lies within the sensor log (frames {frame_times[0]:.3f}..{frame_times[-1]:.3f} s, "
            f"log {log.t[0]:.3f}..{log.t[-1]:.3f} s): check video.start_time and the logs' clocks",
            field="video.start_time",
        )
    if not covered.all():
        warnings.add(f"{int((~covered).sum())} video frames lie outside the sensor log; their attitude is held")
    decl = declination(*origin, float(frame_times[0]))
    mag = _calibrate_magnetometer(m, mag, origin, float(frame_times[0]), warnings)
    session = Session(m, frame, scene_path, placement, video, frame_times, intr, rotation, acc, gyr, mag, gnss, refs, decl, warnings)
    _truth_extras(m, session, warnings)
    session.height_mode = m.get("gnss", "height", str, "gnss", required_section=False)
    if session.height_mode not in ("gnss", "ground"):
        raise ManifestError(m.path, f"got {session.height_mode!r}, expected 'gnss' or 'ground'", field="gnss.height")
    session.mount_height_m = m.get("gnss", "mount_height_m", float, 1.5, required_section=False)
    _takeoff_heights(m, session)
    if m.get("sensors", "format", str, "csv") in ("gopro", "none"):
        session.device_is_camera = True  # action cameras and drones: the video is the device's view
        if session.mag is None and session.gyr is not None:
            session.heading_from_course = True
            session.heading_note = "heading from the GNSS course"
    return session


def _calibrate_magnetometer(m: Manifest, mag: VectorStream | None, origin: tuple[float, float, float], when: float, warnings: Warnings) -> VectorStream | None:
    """The magnetometer calibrated on the clip (app.attitude.magcal), unless switched off."""
    from app.attitude import magcal
    from app.geomag import field_enu

    mode = m.get("sensors", "mag_calibration", str, "clip")
    if mode not in ("clip", "none"):
        raise ManifestError(m.path, f"got {mode!r}, expected 'clip' or 'none'", field="sensors.mag_calibration")
    if mag is None or mode == "none":
        return mag
    cal = magcal.fit(mag.values, float(np.linalg.norm(field_enu(*origin, when))))
    if isinstance(cal, str):
        warnings.add(f"magnetometer not calibrated: {cal}")
        return mag
    warnings.add(f"magnetometer calibrated on the clip: {cal.describe()}")
    return VectorStream(mag.name, mag.t, cal.apply(mag.values), mag.unit, mag.source)


def _truth_extras(m: Manifest, session: Session, warnings: Warnings) -> None:
    """Optional true positions and true frame times of a simulated session."""
    from app.io import csvlog

    pos = m.file("truth", "position", required=False, required_section=False)
    if pos:
        session.truth_position = csvlog.read_gnss(pos, warnings)
    frames = m.file("truth", "frame_times", required=False, required_section=False)
    if frames:
        columns, _, rows, first = csvlog.read_table(frames)
        values, _ = csvlog.numeric(frames, rows, columns, ["frame", "t"], first, warnings)
        if len(values) != len(session.frame_times):
            raise ManifestError(m.path, f"{len(values)} true frame times for {len(session.frame_times)} video frames", field="truth.frame_times")
        session.truth_frame_times = values[np.argsort(values[:, 0]), 1]


COURSE_MIN_SPEED = 0.7  # m/s: slower, the direction of travel is too noisy to give a heading


def course_heading_turn(session: Session, t: np.ndarray, q_device: np.ndarray) -> np.ndarray | None:
    """The one constant turn about Up that best aligns the camera's forward direction with the
    direction of travel while the camera moves (circular mean of the differences), as a
    quaternion; None when the clip never moves fast enough."""
    from app import rotations

    pos = session.positions()
    speed = np.hypot(pos.vel_enu[:, 0], pos.vel_enu[:, 1])
    moving = (speed > COURSE_MIN_SPEED) & (pos.t >= t[0]) & (pos.t <= t[-1])
    if moving.sum() < 3:
        return None
    course = np.arctan2(pos.vel_enu[moving, 0], pos.vel_enu[moving, 1])
    q_cam = rotations.multiply(rotations.slerp(t, q_device, pos.t[moving]), session.camera_mount())
    heading = np.radians(rotations.hpr_from_camera_quat(q_cam)[:, 0])
    offset = rotations.circular_mean(course - heading)
    return rotations.about_z(-np.degrees(offset))  # a clockwise (heading-increasing) turn


def _course_aligned(session: Session, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    from app import rotations

    turn = course_heading_turn(session, t, q)
    if turn is None:
        if not any("never moves fast enough" in w for w in session.warnings.items):
            session.warnings.add(f"the camera never moves faster than {COURSE_MIN_SPEED} m/s: heading cannot come from the course and stays arbitrary")
        return q
    return rotations.canonical(rotations.multiply(turn, q))


def device_attitude(session: Session, source: str) -> tuple[np.ndarray, np.ndarray]:
    """(t, device -> ENU quaternions, true north) for a filter name or reference source."""
    course = session.heading_from_course
    if source in session.references:
        ref = session.references[source]
        if source == "camera" and course:
            return ref.t, _course_aligned(session, ref.t, ref.q)
        return ref.t, ref.q
    if source not in FILTERS:
        raise ValueError(f"unknown attitude source {source!r}; this session offers {session.filters}")
    method, ahrs = FILTERS[source]
    use_mag = ahrs and session.mag is not None
    if ahrs and session.mag is None and method != "offline":
        raise ValueError(f"{source} needs a magnetometer, which this session lacks; use one of {session.filters}")
    if session.gyr is None or session.acc is None:
        raise ValueError(f"{source} needs the camera's IMU, which this clip lacks; use one of {session.filters}")
    t = session.gyr.t
    acc = resample(t, session.acc.t, session.acc.values)
    mag = resample(t, session.mag.t, session.mag.values) if use_mag else None
    q = estimate(t, session.gyr.values, acc, mag, method=method, declination_deg=session.declination_deg if use_mag else 0.0)
    if not use_mag and session.mag is not None:
        q = anchor_heading(q, resample(t, session.mag.t, session.mag.values), session.declination_deg)
    elif not use_mag and course:
        q = _course_aligned(session, t, q)
    return t, q


def anchor_heading(q: np.ndarray, mag: np.ndarray, declination_deg: float) -> np.ndarray:
    """An IMU (6D) track's arbitrary heading fixed once: the constant turn about Up that makes the
    magnetometer point to magnetic north on average (circular mean over the clip), then to true
    north. The track's dynamics stay those of the IMU filter; transient magnetic disturbances
    cannot steer it."""
    from app import rotations

    h = rotations.rotate(q, mag)
    mean = rotations.circular_mean(np.arctan2(h[:, 0], h[:, 1]))  # the field's angle east of north
    turn = rotations.about_z(np.degrees(mean) - declination_deg)
    return rotations.canonical(rotations.multiply(turn, q))


def pose_track(session: Session, source: str) -> PoseTrack:
    """The camera pose track of one attitude source (for "truth": true positions too, if known)."""
    t_att, q = device_attitude(session, source)
    if source == "truth" and session.truth_position is not None:
        g = session.truth_position
        positions = PositionTrack.from_fixes(g.t, g.lat, g.lon, g.h, g.vel_enu)
    else:
        positions = session.positions()
    return PoseTrack(session.frame, positions, t_att, q, session.camera_mount())
