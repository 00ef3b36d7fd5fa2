"""Sessions straight from a camera's own files, with no manifest: a GoPro MP4 (GPMF telemetry
inside) or a DJI clip with its .SRT subtitle beside it. The same Session as a manifest gives,
so everything downstream (solve, render, view) works unchanged.

Without a scene, the video is projected on an assumed flat ground: at the first GNSS height
minus a mount height (hand-held or body camera 1.5 m; a drone's heights are above take-off, so
its ground is the take-off height), large enough for every footprint in the clip, with a metric
grid. The viewer says that the ground is assumed.

Heading without a trustworthy magnetometer comes from the GNSS course: while the camera moves,
the one constant heading rotation that best aligns its forward direction with the direction of
travel (app.session.course_heading_turn).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app import rotations
from app.camera import Intrinsics
from app.errors import DataFormatError, GeofuseError
from app.geo import LocalFrame
from app.geomag import declination
from app.io.streams import GnssTrack, OrientationStream, Warnings
from app.io.video import probe
from app.scene import Placement
from app.scene.ground_plane import ground_plane
from app.session import Manifest, Session
from app.trajectory import estimate_velocity

HANDHELD_MOUNT_M = 1.5
DRONE_DEFAULT_PITCH_DEG = -30.0  # camera pitch assumed for a drone clip without gimbal attitude
DJI_DEFAULT_FOCAL_MM = 24.0  # 35 mm equivalent focal length of most DJI main cameras


def find_srt(video: Path) -> Path | None:
    """CLIP.SRT beside CLIP.MP4, in any letter case."""
    for p in video.parent.iterdir():
        if p.stem.lower() == video.stem.lower() and p.suffix.lower() == ".srt":
            return p
    return None


def open_clip(path: str | Path, srt: str | Path | None = None, hfov_deg: float | None = None, drone_pitch_deg: float = DRONE_DEFAULT_PITCH_DEG) -> Session:
    """A session from a GoPro MP4, or from a video with a DJI subtitle (`srt`, or found beside it)."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "video file does not exist")
    srt = Path(srt) if srt is not None else find_srt(path)
    if srt is not None:
        return _dji_session(path, srt, hfov_deg, drone_pitch_deg)
    return _gopro_session(path, hfov_deg)


def _frame_and_ground(gnss: GnssTrack, ground_h: float, margin_m: float) -> tuple[LocalFrame, object]:
    frame = LocalFrame(float(gnss.lat[0]), float(gnss.lon[0]), float(ground_h))
    enu = frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h)
    lo, hi = enu[:, :2].min(axis=0), enu[:, :2].max(axis=0)
    half = float(max(hi - lo) / 2 + margin_m)
    return frame, ground_plane((lo + hi) / 2, 0.0, half)


def _session(path: Path, frame: LocalFrame, mesh, video, times, intr, rotation, acc, gyr, mag, gnss, refs, decl, warnings, note) -> Session:
    s = Session(Manifest(path.resolve(), {}), frame, None, Placement(), video, times, intr, rotation, acc, gyr, mag, gnss, refs, decl, warnings)
    s.mesh = mesh
    s.heading_note = note
    s.heading_from_course = gyr is not None and mag is None
    s.device_is_camera = True
    warnings.add("no scene given: the video is projected on an assumed flat ground with a 1 m grid")
    return s


def _gopro_session(path: Path, hfov_deg: float | None) -> Session:
    from app.io.gopro import read_gopro

    warnings = Warnings()
    rec = read_gopro(path, warnings)
    if rec.gnss is None:
        raise DataFormatError(path, "the GoPro telemetry has no GPS fix: the camera cannot be placed (enable GPS, or use a manifest)")
    video = probe(path)
    when = rec.gps_utc_at_zero or video.creation_time or 0.0
    frame, mesh = _frame_and_ground(rec.gnss, float(rec.gnss.h[0]) - HANDHELD_MOUNT_M, 300.0)
    decl = declination(frame.lat_deg, frame.lon_deg, frame.h_m, when)
    mag = rec.mag  # already checked against the World Magnetic Model by the reader
    refs = {}
    if rec.camera is not None:
        refs["camera"] = rec.camera
    w, h = video.display_size
    intr = Intrinsics.from_fov(w, h, hfov_deg or rec.hfov_deg)
    note = "" if mag is not None else "heading from the GNSS course"
    return _session(path, frame, mesh, video, video.pts_s.copy(), intr, video.rotation_cw, rec.acc, rec.gyr, mag, rec.gnss, refs, decl, warnings, note)


def _dji_session(path: Path, srt: Path, hfov_deg: float | None, pitch_deg: float) -> Session:
    from app.io.dji_srt import check_duration, read_srt

    warnings = Warnings()
    track = read_srt(srt, warnings)
    video = probe(path)
    check_duration(track, video.duration_s + 1.0 / max(video.nominal_fps, 1.0))
    ok = track.has_position
    heights = np.where(np.isfinite(track.height), track.height, 0.0)[ok]
    if track.height_relative:
        warnings.add(f"{srt.name}: heights are relative to take-off; the assumed ground is the take-off height (0 m)")
        ground = 0.0
    else:
        ground = float(np.nanmin(heights))
        warnings.add(f"{srt.name}: absolute heights; the assumed ground is the lowest height of the flight ({ground:.1f} m)")
    gnss = GnssTrack(track.t[ok], track.lat[ok], track.lon[ok], heights, None, None, str(srt))
    frame, mesh = _frame_and_ground(gnss, ground, 500.0 + 10.0 * float(np.max(heights - ground)))
    when = float(np.nanmin(track.wall_clock)) if np.isfinite(track.wall_clock).any() else (video.creation_time or 0.0)
    decl = declination(frame.lat_deg, frame.lon_deg, frame.h_m, when)
    refs: dict[str, OrientationStream] = {}
    note = ""
    if track.has_gimbal:
        g = np.isfinite(track.gimbal_pry).all(axis=1)
        p, r, y = track.gimbal_pry[g].T
        q = rotations.camera_quat_from_hpr(y % 360.0, p, r)  # the gimbal is the camera: device = camera
        refs["telemetry"] = OrientationStream(track.t[g], q, str(srt), "DJI gimbal pitch, roll, yaw (G.PRY)")
    else:
        refs["course"] = course_reference(frame, gnss, pitch_deg)
        note = f"no camera attitude in the subtitle: heading from the track, pitch {pitch_deg:g} deg assumed"
        warnings.add(f"{srt.name}: {note}")
    focal = track.focal_len[np.isfinite(track.focal_len)]
    focal_mm = float(np.median(focal)) / 10.0 if len(focal) else DJI_DEFAULT_FOCAL_MM
    w, h = video.display_size
    if hfov_deg is None:
        hfov_deg = float(np.degrees(2 * np.arctan(18.0 / focal_mm)))  # 36 mm wide full frame equivalent
    intr = Intrinsics.from_fov(w, h, hfov_deg)
    return _session(path, frame, mesh, video, video.pts_s.copy(), intr, video.rotation_cw, None, None, None, gnss, refs, decl, warnings, note)


def course_reference(frame: LocalFrame, gnss: GnssTrack, pitch_deg: float) -> OrientationStream:
    """The `course` pose source: heading along the direction of travel, pitch a setting (deg)."""
    heading = _course_headings(frame, gnss)
    q = rotations.camera_quat_from_hpr(heading, np.full(len(heading), pitch_deg), np.zeros(len(heading)))
    return OrientationStream(gnss.t, q, gnss.source, f"heading from the direction of travel, pitch {pitch_deg:g} deg (a setting)")


def set_course_pitch(session: Session, pitch_deg: float) -> None:
    """Change the assumed camera pitch of a session's `course` source (the viewer's slider)."""
    session.references["course"] = course_reference(session.frame, session.gnss, pitch_deg)
    session.heading_note = f"no camera attitude in the subtitle: heading from the track, pitch {pitch_deg:g} deg assumed"


def _course_headings(frame: LocalFrame, gnss: GnssTrack) -> np.ndarray:
    """Direction of travel (deg from north) at each fix; held through stops."""
    v = estimate_velocity(gnss.t, frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h))
    speed = np.hypot(v[:, 0], v[:, 1])
    heading = np.degrees(np.arctan2(v[:, 0], v[:, 1])) % 360.0
    moving = speed > 0.5
    if not moving.any():
        return np.zeros(len(heading))
    idx = np.where(moving, np.arange(len(heading)), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.flatnonzero(moving)[0])
    idx[idx < 0] = first
    return heading[idx]


def open_any(path: str | Path, srt: str | Path | None = None, hfov_deg: float | None = None, pitch_deg: float = DRONE_DEFAULT_PITCH_DEG) -> Session:
    """A manifest (.toml) or a clip (pitch_deg: a drone clip's camera pitch when its subtitle has
    no gimbal attitude)."""
    from app.session import open_session

    path = Path(path)
    if path.suffix.lower() == ".toml":
        if srt is not None:
            raise GeofuseError("--srt goes with a clip, not with a manifest")
        return open_session(path)
    return open_clip(path, srt, hfov_deg, pitch_deg)
