"""Sessions straight from a camera's own files, with no manifest: a GoPro MP4 (GPMF telemetry
inside) or a DJI clip with its .SRT subtitle beside it. The same frozen Session as a manifest
gives, so everything downstream (solve, render, view) works unchanged.

Without a scene, the video is projected on an assumed flat ground: at the first GNSS height
minus a mount height (hand-held or body camera 1.5 m; a drone's heights are above take-off, so
its ground is the take-off height), large enough for every footprint in the clip, with a metric
grid. The viewer says that the ground is assumed.

Heading without a trustworthy magnetometer comes from the GNSS course (app.attitude.heading).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.attitude.gopro import read_gopro
from app.attitude.heading import heading_policy
from app.camera.intrinsics import Intrinsics, Zoom
from app.camera.lens import Lens
from app.camera.pinhole import Camera, camera_in_frame
from app.camera.profiles import LENS_MODES, choose_profile, video_camera
from app.core.constants import DRONE_DEFAULT_PITCH_DEG, FOV_RANGE_DEG
from app.core.errors import DataFormatError, GeofuseError, VideoError
from app.core.messages import Messages
from app.geodesy.enu import LocalFrame
from app.geodesy.geomag import declination
from app.io.dji_mp4 import read_dji_camera
from app.io.dji_srt import SrtTrack, check_duration, read_srt, srt_fixes
from app.io.gopro import global_settings
from app.io.klv_track import (
    CONSISTENCY_LIMIT_DEG,
    IMAGE_SOURCE_SENSOR_TAG,
    PLATFORM_DESIGNATION_TAG,
    RAW_KLV_SUFFIXES,
    KlvTrack,
    describe,
    has_klv,
    read_klv,
    read_raw_klv,
    starts_as_klv,
)
from app.io.streams import GnssTrack, OrientationStream
from app.io.video import VideoInfo, probe
from app.scene import Placement
from app.scene.ground import ellipsoidal_ground, ground_heights
from app.scene.ground_plane import ASSUMED_GROUND_MARGIN_M, ground_reach_m, ground_under_track
from app.scene.layers import Layer
from app.scene.mesh import MeshData
from app.session.assemble import (
    assemble,
    gimbal_attitude,
    load_scene_layers,
    open_session,
    subtitle_heights,
)
from app.session.config import HANDHELD_MOUNT_M, read_config
from app.session.model import Session
from app.session.start import ELLIPSOID, PlatformHeights, StartArea
from app.world.build import deferring, resolve_worlds
from app.world.settings import how_to_configure

DJI_DEFAULT_FOCAL_MM = 24.0  # 35 mm equivalent focal length of most DJI main cameras
# The pinhole assumed for a drone's camera that states no field of view (KLV without tag 16, a
# MAVLink feed): a 24 mm equivalent, 73.7 deg across.
ASSUMED_DRONE_HFOV_DEG = math.degrees(2 * math.atan(18.0 / DJI_DEFAULT_FOCAL_MM))
DJI_FOCAL_RANGE_MM = (8.0, 1200.0)  # 35 mm equivalent: a 132 deg to a 1.7 deg horizontal view
KLV_ASSUMED_HEIGHT_M = 100.0  # a KLV clip without a frame centre: the ground this far under it
CENTRE_SCENE_LIMIT_M = 20.0  # KLV frame centres this far (median) from the scene's ground: said
ZOOM_STEP_DEG = 0.01  # a KLV field of view that changes more than this (deg) is drawn per frame
ZOOM_STEP_MM = 0.05  # a DJI focal length that changes more than this (mm, 35 mm eq.): the same


def find_srt(video: Path) -> Path | None:
    """CLIP.SRT (a DJI subtitle) or CLIP.KLV (the video's raw KLV) beside CLIP.MP4, in any
    letter case."""
    for p in sorted(video.parent.iterdir()):
        if p.stem.lower() == video.stem.lower() and p.suffix.lower() in (".srt", *RAW_KLV_SUFFIXES):
            return p
    return None


def open_clip(
    path: str | Path,
    srt: str | Path | None = None,
    hfov_deg: float | None = None,
    pitch_deg: float = DRONE_DEFAULT_PITCH_DEG,
    lens: str | Path | None = None,
    layers: tuple[Layer, ...] = (),
    start: StartArea | None = None,
) -> Session:
    """A session from a GoPro MP4, a video with MISB ST 0601 KLV (an MPEG-TS from a drone or
    an FMV tool, or its KLV as a raw file: `srt`, or CLIP.KLV beside it), or from a video with
    a DJI subtitle (`srt`, or found beside it).
    lens: a gyroflow profile to use instead of the one chosen from the file (GoPro) or the pinhole
    field of view; hfov_deg: a pinhole field of view instead of any lens; pitch_deg: a drone
    clip's camera pitch (degrees above the horizon) when its subtitle has no gimbal attitude;
    layers: the scene (tilesets, DEMs, models placed by themselves) instead of an assumed ground;
    start: where a clip without GNSS is searched for (a DJI subtitle without a position is
    opened on it; the caller sets it on other clips)."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "video file does not exist")
    srt = Path(srt) if srt is not None else find_srt(path)
    if srt is not None and srt.is_file() and starts_as_klv(srt):  # --klv, or CLIP.KLV
        return _klv_session(path, hfov_deg, lens, layers, raw=srt, start=start)
    if srt is not None:
        return _dji_session(path, srt, hfov_deg, pitch_deg, lens, layers, start)
    if has_klv(path):
        return _klv_session(path, hfov_deg, lens, layers, start=start)
    return _gopro_session(path, hfov_deg, lens, layers)


def frame_and_ground(
    gnss: GnssTrack,
    ground_h: float,
    margin_m: float,
    layers: tuple[Layer, ...],
    messages: Messages,
    above_takeoff: bool = False,
) -> tuple[LocalFrame, MeshData, GnssTrack]:
    """(frame, scene, gnss with final heights): the layers around the track, else an assumed
    flat ground at ground_h (ellipsoidal m). Heights above take-off get the terrain's height
    under the first fix, where a layer has ground there. A world layer (app.world) is built over
    the track and the margin here, or dropped when none of its tiles could be had."""
    frame = LocalFrame(float(gnss.lat[0]), float(gnss.lon[0]), float(ground_h))
    background = deferring(layers)  # the viewer builds the world while the flat ground shows
    layers = resolve_worlds(
        layers, gnss.lat, gnss.lon, gnss.h, ground_h, margin_m, messages, above_takeoff
    )
    if not layers:
        if not background:
            messages.add(
                "no scene given: the video is projected on an assumed flat ground with a 1 m grid; "
                + how_to_configure()
            )
        return frame, ground_under_track(frame, gnss.lat, gnss.lon, ground_h, margin_m), gnss
    mesh = load_scene_layers(layers, frame, gnss, messages, ground_h, margin_m)
    if above_takeoff:
        takeoff = ellipsoidal_ground(mesh, frame, float(gnss.lat[0]), float(gnss.lon[0]))
        if takeoff is not None:
            gnss = replace(gnss, h=gnss.h + takeoff - ground_h)
            messages.info(
                f"heights above take-off: take-off height {takeoff:.2f} m from the terrain under the first position"
            )
        else:
            messages.add(
                "heights above take-off: no terrain under the first position, so heights stay above an assumed take-off at 0 m"
            )
    return frame, mesh, gnss


def _camera_model(
    video: VideoInfo,
    hfov_deg: float,
    lens_path: str | Path | None,
    choice: tuple[Path, str] | None,
    messages: Messages,
) -> tuple[Intrinsics, Lens | None, tuple[Path, ...]]:
    """(intrinsics, lens, lens files read): a given profile, else the chosen one, else a pinhole
    of hfov_deg; says which."""
    path = Path(lens_path) if lens_path is not None else choice[0] if choice else None
    if path is None:
        return Intrinsics.from_fov(*video.display_size, hfov_deg), None, ()
    intr, lens = video_camera(path, *video.display_size, video.rotation_cw)
    messages.info(
        f"lens: {lens.kind} model from {'--lens ' + path.name if lens_path is not None else choice[1]}"
    )
    return intr, lens, (path.resolve(),) if lens_path is not None else ()


def _clip_session(
    path: Path,
    inputs: tuple[Path, ...],
    frame: LocalFrame,
    mesh,
    video: VideoInfo,
    intr: Intrinsics,
    acc,
    gyr,
    mag,
    gnss: GnssTrack,
    recorded: dict[str, OrientationStream],
    decl: float,
    messages: Messages,
    pitch_deg: float = DRONE_DEFAULT_PITCH_DEG,
    aircraft_yaw: tuple | None = None,
    lens: Lens | None = None,
    readout_s: float | None = None,
    layers: tuple[Layer, ...] = (),
    utc_at_zero_s: float | None = None,
    camera: str = "",
    zoom: Zoom | None = None,
    start: StartArea | None = None,
    heights: PlatformHeights | None = None,
) -> Session:
    policy = heading_policy(
        gyr is not None, mag is not None, recorded, pitch_deg, aircraft_yaw is not None
    )
    if policy.note:
        messages.info(f"{path.name}: {policy.note}")
    return Session(
        path.resolve(), frame, Path(layers[0].location) if layers else None, Placement(), video, video.pts_s.copy(), intr, video.rotation_cw,
        acc, gyr, mag, gnss, recorded, decl, messages, inputs=(*inputs, *(f.resolve() for layer in layers for f in layer.files())), heading=policy, device_is_camera=True,
        aircraft_yaw=aircraft_yaw, mesh=mesh, lens=lens, readout_s=readout_s, layers=tuple(layers),
        utc_at_zero_s=utc_at_zero_s, camera=camera, zoom=zoom, start=start,
        platform_heights=heights,
    )  # fmt: skip


def _gopro_session(
    path: Path,
    hfov_deg: float | None,
    lens_path: str | Path | None = None,
    layers: tuple[Layer, ...] = (),
) -> Session:
    messages = Messages()
    rec = read_gopro(path, messages)
    if rec.gnss is None:
        raise DataFormatError(
            path,
            "the GoPro telemetry has no GPS fix: the camera cannot be placed (enable GPS, or use a manifest)",
        )
    video = probe(path)
    video.note_damage(messages)
    when = rec.gps_utc_at_zero or video.creation_time or 0.0
    frame, mesh, gnss = frame_and_ground(
        rec.gnss, float(rec.gnss.h[0]) - HANDHELD_MOUNT_M, ASSUMED_GROUND_MARGIN_M, layers, messages
    )
    decl = declination(frame.lat_deg, frame.lon_deg, frame.h_m, when)
    recorded = {"camera": rec.camera} if rec.camera is not None else {}
    settings = global_settings(path)
    if str(settings.get("EISE", "")).strip().upper() == "Y":
        messages.add(
            f"{path.name}: in-camera stabilisation was on ({str(settings.get('EISA', '')).strip() or 'EIS'}): the video no longer has the "
            "sensor's geometry, so its projection is approximate and `geofuse sync` cannot see the camera turn"
        )
    choice = None
    if hfov_deg is None and lens_path is None:
        mode = LENS_MODES.get(str(settings.get("VFOV", "")).strip()[:1].upper(), "")
        choice = _auto_profile(
            "GoPro",
            rec.raw.model,
            rec.raw.model,
            video,
            mode,
            f"{path.name}: ",
            f"a pinhole of {rec.hfov_deg:.1f} deg",
            messages,
        )
    intr, lens, lens_files = _camera_model(
        video, hfov_deg or rec.hfov_deg, lens_path, choice, messages
    )
    srot = settings.get("SROT")
    srot_s = (
        float(np.ravel(srot)[0]) / 1000.0
        if isinstance(srot, np.ndarray) and np.ravel(srot).size
        else None
    )
    readout = _readout(srot_s, lens, path, messages)
    return _clip_session(
        path,
        (path.resolve(), *lens_files),
        frame,
        mesh,
        video,
        intr,
        rec.acc,
        rec.gyr,
        rec.mag,
        gnss,
        recorded,
        decl,
        messages,
        lens=lens,
        readout_s=readout,
        layers=layers,
        utc_at_zero_s=rec.gps_utc_at_zero,
        camera=rec.raw.model or "GoPro",
    )


def _auto_profile(
    brand: str,
    model: str,
    named: str,
    video: VideoInfo,
    mode: str,
    where: str,
    fallback: str,
    messages: Messages,
) -> tuple[Path, str] | None:
    """The bundled profile for a camera model at the video's stored size, the reason prefixed
    with how the camera was named; without one, a warning that `fallback` is assumed."""
    stored = (video.height, video.width) if video.rotation_cw % 180 else (video.width, video.height)
    choice = choose_profile(brand, model, *stored, mode)
    if choice is None:
        messages.add(
            f"{where}no lens profile for {named} at {stored[0]}x{stored[1]}: {fallback} is assumed (give --lens PROFILE.json)"
        )
        return None
    return choice[0], f"{named}: {choice[1]}" if named != model else choice[1]


def _readout(
    recorded_s: float | None, lens: Lens | None, path: Path, messages: Messages
) -> float | None:
    """The sensor's readout time (s): the clip's own (GoPro's SROT), else the lens profile's;
    says which, or that the rolling shutter is not corrected."""
    value = recorded_s
    origin = "SROT in the clip's metadata"
    if not value and lens is not None and lens.readout_s:
        value, origin = lens.readout_s, "the lens profile"
    if value and 0.0 < value < 0.2:
        messages.info(
            f"{path.name}: rolling shutter: readout {1000 * value:.1f} ms from {origin}, corrected row by row"
        )
        return value
    messages.add(f"{path.name}: rolling shutter: readout time unknown: not corrected")
    return None


def _dji_session(
    path: Path,
    srt: Path,
    hfov_deg: float | None,
    pitch_deg: float,
    lens_path: str | Path | None = None,
    layers: tuple[Layer, ...] = (),
    start: StartArea | None = None,
) -> Session:
    """A video with its DJI subtitle; one whose subtitle has no position at all is opened for a
    search of `start` (app.register.coldstart), its scene gathered around the area."""
    messages = Messages()
    track = read_srt(srt, messages, positioned=start is None)
    video = probe(path)
    video.note_damage(messages)
    check_duration(track, video.duration_s + 1.0 / max(video.nominal_fps, 1.0))
    if track.has_position.any():
        gnss = srt_fixes(track, messages)
        around, start = gnss, None  # a GNSS: an area given is said unused by the search
    else:
        around = _unfixed_area(track, srt, start, layers)
        gnss = GnssTrack(*np.zeros((4, 0)), path=str(srt))
    heights = around.h
    if start is not None:  # the outline at the platform's height above an assumed 0 m ground
        ground = 0.0
    elif track.height_relative:
        if not layers:
            messages.info(
                f"{srt.name}: heights are relative to take-off; the assumed ground is the take-off height (0 m)"
            )
        ground = 0.0
    else:
        ground = float(np.nanmin(heights))
        if not layers:
            messages.info(
                f"{srt.name}: absolute heights; the assumed ground is the lowest height of the flight ({ground:.1f} m)"
            )
    frame, mesh, around = frame_and_ground(
        around,
        ground,
        ground_reach_m(heights - ground),
        layers,
        messages,
        track.height_relative and start is None,
    )
    gnss = around if start is None else gnss
    when = (
        float(np.nanmin(track.wall_clock))
        if np.isfinite(track.wall_clock).any()
        else (video.creation_time or 0.0)
    )
    decl = declination(frame.lat_deg, frame.lon_deg, frame.h_m, when)
    recorded: dict[str, OrientationStream] = {}
    yaw = None
    if track.has_gimbal:
        recorded["telemetry"] = gimbal_attitude(
            track, srt
        )  # the gimbal is the camera: device = camera
    else:
        yaw = track.aircraft_yaw()
    focal = track.focal_len[np.isfinite(track.focal_len)]
    focal_mm = float(np.median(focal)) if len(focal) else DJI_DEFAULT_FOCAL_MM
    if not DJI_FOCAL_RANGE_MM[0] <= focal_mm <= DJI_FOCAL_RANGE_MM[1]:
        raise DataFormatError(
            srt,
            f"a 35 mm equivalent focal length of {focal_mm:g} mm is outside what a camera has ({DJI_FOCAL_RANGE_MM[0]:g} to {DJI_FOCAL_RANGE_MM[1]:g} mm); give --fov or --lens",
            field="focal_len",
        )
    choice = None
    from_focal = hfov_deg is None
    effective, digital = effective_focal_mm(track)
    ok = np.isfinite(effective)
    if hfov_deg is None:
        eff_mm = float(np.median(effective[ok])) if ok.any() else focal_mm
        hfov_deg = float(
            np.degrees(2 * np.arctan(18.0 / min(eff_mm, DJI_FOCAL_RANGE_MM[1])))
        )  # 36 mm wide full frame equivalent
        told = f"the subtitle's {focal_mm:g} mm equivalent focal length" + (
            f" times its digital zoom, {eff_mm:.4g} mm" if digital else ""
        )
        if lens_path is None:
            choice = _dji_profile(
                path, video, f"a pinhole of {hfov_deg:.1f} deg ({told})", messages
            )
    intr, lens, lens_files = _camera_model(video, hfov_deg, lens_path, choice, messages)
    readout = _readout(None, lens, path, messages)
    zoom = None
    if from_focal and lens is not None and digital:
        messages.add(
            f"{srt.name}: the digital zoom (dzoom, up to {np.nanmax(track.dzoom):g}x) is not applied: the lens profile describes the whole picture (give --fov for a pinhole)"
        )
    if from_focal and lens is None and ok.any() and np.ptp(effective[ok]) > ZOOM_STEP_MM:
        fov = np.degrees(2 * np.arctan(18.0 / np.clip(effective[ok], *DJI_FOCAL_RANGE_MM)))
        zoom = Zoom(np.asarray(track.t, np.float64)[ok], fov)
        ratio = (
            f", with a digital zoom of {np.nanmin(track.dzoom):g} to {np.nanmax(track.dzoom):g}x"
            if digital
            else ""
        )
        messages.info(
            f"{srt.name}: the focal length changes ({effective[ok].min():.4g} to {effective[ok].max():.4g} mm equivalent{ratio}, a zoom): every frame is drawn with its own field of view"
        )
    return _clip_session(
        path,
        (path.resolve(), srt.resolve(), *lens_files),
        frame,
        mesh,
        video,
        intr,
        None,
        None,
        None,
        gnss,
        recorded,
        decl,
        messages,
        pitch_deg,
        yaw,
        lens,
        readout,
        layers,
        _subtitle_clock(track, srt, messages),
        _dji_name(path),
        zoom,
        start,
        None if start is None else subtitle_heights(track, 0.0),
    )


def _unfixed_area(
    track: SrtTrack, srt: Path, start: StartArea, layers: tuple[Layer, ...]
) -> GnssTrack:
    """A track over the area's outline, at the platform's height (--height, else the subtitle's
    greatest above take-off) for the scene to be gathered around, for a subtitle without a
    position. DataFormatError where the clip cannot be searched for: no scene, no gimbal
    attitude."""
    if not layers:
        raise DataFormatError(
            srt,
            "no entry has a position and no scene is given: a clip without GNSS is searched for on a scene (give --scene, --dem or --world with --near)",
        )
    if not track.has_gimbal:
        raise DataFormatError(
            srt,
            "no entry has a position nor the gimbal's angles (gb_yaw, gb_pitch, gb_roll or G.PRY): a clip without GNSS is searched for with the camera's attitude",
        )
    high = np.nanmax(track.height) if np.isfinite(track.height).any() else 0.0
    return start.outline_track(start.height_m if start.height_m is not None else high, str(srt))


def effective_focal_mm(track: SrtTrack) -> tuple[np.ndarray, bool]:
    """((N,) each subtitle entry's effective 35 mm equivalent focal length (mm), whether any
    entry's digital zoom is other than 1): its focal_len (DJI_DEFAULT_FOCAL_MM throughout where
    the subtitle gives none) times its digital zoom ratio (1 where the subtitle gives none);
    NaN where the entry lacks a focal length or, in a subtitle that gives a zoom, its zoom."""
    focal = np.asarray(track.focal_len, np.float64)
    if not np.isfinite(focal).any():
        focal = np.full(len(track.t), DJI_DEFAULT_FOCAL_MM)
    dzoom = track.dzoom if track.dzoom is not None else np.full(len(track.t), np.nan)
    given = np.isfinite(dzoom)
    ratio = dzoom if given.any() else np.ones(len(track.t))
    return focal * ratio, bool(given.any() and np.any(dzoom[given] != 1.0))


def _klv_session(
    path: Path,
    hfov_deg: float | None,
    lens_path: str | Path | None = None,
    layers: tuple[Layer, ...] = (),
    raw: Path | None = None,
    start: StartArea | None = None,
) -> Session:
    """A video with MISB ST 0601 KLV (in it, or `raw`: a file of Local Sets beside it, placed
    by their time stamps and the video's creation time): positions from the sensor's latitude,
    longitude and height, the camera's attitude from the platform's then the sensor's angles
    (pose source `telemetry`), the field of view from tag 16, UTC from the Precision Time
    Stamps. Where no set places the sensor, `start` (an area) is searched for it, at the
    sensor's height (tag 75, or 15 through the geoid at the area's centre) over the scene's
    ground where no --height is given (app.register.coldstart)."""
    messages = Messages()
    video = probe(path)
    video.note_damage(messages)
    track = read_raw_klv(raw, messages, video) if raw else read_klv(path, video, messages)
    messages.info(f"{path.name}: {describe(track, video.pts_s)}")
    gnss = track.gnss(messages)
    heights = None
    if gnss is None and start is not None:
        gnss, heights = _klv_unplaced(track, path, start, layers, messages)
    elif gnss is None:
        raise DataFormatError(
            path,
            "no KLV set places the sensor (tags 13, 14 and 75 or 15 missing or in error): the camera cannot be placed (give --near LAT,LON and a scene to search for it)",
            field="KLV",
        )
    else:
        start = None  # a GNSS: an area given is said unused by the search
    attitude = track.attitude()
    if attitude is None:
        raise DataFormatError(
            path,
            f"no KLV set gives the camera's attitude: {track.angle_faults() or 'no set has two distinct times'}",
            field="KLV",
        )
    if len(attitude.t) < len(track.t):
        messages.add(
            f"{path.name}: {len(track.t) - len(attitude.t)} of {len(track.t)} KLV sets give no attitude ({track.angle_faults() or 'a time repeated'}): their times are interpolated"
        )
    if len(gnss.t) < len(track.t) and start is None:
        messages.add(
            f"{path.name}: {len(track.t) - len(gnss.t)} of {len(track.t)} KLV sets have no valid position: their times are interpolated"
        )
    # A gap between positions is said once, by the solve (app.solve.track.say_outages: its span
    # in clip time and what carries the track through it), and marked on every frame in it.
    off = track.centre_offsets_deg()  # each set's frame centre from its own axis, deg
    if start is None:
        ground = _klv_ground(track, off, gnss, path, messages, bool(layers))
    else:  # the outline at the sensor's height, its ground the scene's
        ground = float(np.min(gnss.h)) - KLV_ASSUMED_HEIGHT_M
    frame, mesh, gnss = frame_and_ground(
        gnss,
        ground,
        ground_reach_m(gnss.h - ground),
        layers,
        messages,
    )
    if start is not None:
        gnss = GnssTrack(*np.zeros((4, 0)), path=str(raw or path))
    utc = track.utc_at_zero()
    decl = declination(frame.lat_deg, frame.lon_deg, frame.h_m, utc or video.creation_time or 0.0)
    if start is None:
        _check_centre(off, path, messages)
    if layers and start is None:
        _check_centre_on_scene(track, frame, mesh, path, messages)
    zoom = None
    if hfov_deg is None and lens_path is None:
        fov = track.values("hfov_deg")
        ok = np.isfinite(fov) & (fov >= FOV_RANGE_DEG[0])  # 0: not given
        if ok.any():
            hfov_deg = float(np.median(fov[ok]))
            if np.ptp(fov[ok]) > ZOOM_STEP_DEG:
                zoom = Zoom(track.times()[ok], fov[ok])
                messages.info(
                    f"{path.name}: the KLV field of view changes ({fov[ok].min():.2f} to {fov[ok].max():.2f} deg, a zoom): every frame is drawn with its own"
                )
        else:
            hfov_deg = ASSUMED_DRONE_HFOV_DEG
            messages.add(
                f"{path.name}: the KLV gives no field of view (tag 16): a pinhole of {hfov_deg:.1f} deg is assumed (give --fov or --lens)"
            )
    intr, lens, lens_files = _camera_model(video, hfov_deg or 0.0, lens_path, None, messages)
    platform = track.text(PLATFORM_DESIGNATION_TAG)
    sensor = track.text(IMAGE_SOURCE_SENSOR_TAG)
    camera = " / ".join(x for x in (platform, sensor) if x) or "MISB KLV platform"
    return _clip_session(
        path,
        (path.resolve(), *((raw.resolve(),) if raw else ()), *lens_files),
        frame,
        mesh,
        video,
        intr,
        None,
        None,
        None,
        gnss,
        {"telemetry": attitude},
        decl,
        messages,
        lens=lens,
        readout_s=_readout(None, lens, path, messages),
        layers=layers,
        utc_at_zero_s=utc,
        camera=camera,
        zoom=zoom,
        start=start,
        heights=heights,
    )


def _klv_unplaced(
    track: KlvTrack, path: Path, start: StartArea, layers: tuple[Layer, ...], messages: Messages
) -> tuple[GnssTrack, PlatformHeights | None]:
    """(a track over the area's outline at the sensor's height, for the scene to be gathered
    around; the sensor's ellipsoidal heights as the platform's, None where no set gives one)
    for KLV that never places the sensor, searched for from `start`. DataFormatError without a
    scene, or without a height where --height is not given."""
    if not layers:
        raise DataFormatError(
            path,
            "no KLV set places the sensor and no scene is given: a clip without a position is searched for on a scene (give --scene, --dem or --world with --near)",
            field="KLV",
        )
    clat, clon = start.centre
    h = track.heights(
        "sensor_ellipsoid_m",
        "sensor_msl_m",
        np.full(len(track.t), clat),
        np.full(len(track.t), clon),
    )
    ok = np.isfinite(h)
    if not ok.any() and start.height_m is None:
        raise DataFormatError(
            path,
            "no KLV set places the sensor nor gives its height (tag 75 or 15): give --height M",
            field="KLV",
        )
    messages.add(
        f"{path.name}: no KLV set places the sensor (tags 13, 14 and 75 or 15): searched for within {start.said}"
    )
    heights = PlatformHeights(track.times()[ok], h[ok], ELLIPSOID, "the KLV's sensor height") if ok.any() else None  # fmt: skip
    level = float(np.median(h[ok])) if ok.any() else KLV_ASSUMED_HEIGHT_M
    return start.outline_track(level, str(path)), heights


def _klv_ground(
    track: KlvTrack,
    off: np.ndarray,
    gnss: GnssTrack,
    path: Path,
    messages: Messages,
    has_scene: bool,
) -> float:
    """The assumed ground's ellipsoidal height (m): the median frame-centre height where the
    KLV gives one below the sensor (a drone), a hand-held camera's mount height under the lowest
    position where the centre lies level with it or above, else 100 m under the lowest position.
    Centres more than CONSISTENCY_LIMIT_DEG off their own axis (off: KlvTrack.
    centre_offsets_deg) are left out. Said unless a scene replaces it."""
    centre = track.centre_heights()
    astray = np.isfinite(centre) & (off > CONSISTENCY_LIMIT_DEG)  # NaN (no pose): kept
    if astray.any():
        messages.add(
            f"{path.name}: {int(astray.sum())} of {int(np.isfinite(centre).sum())} KLV frame centres lie more than {CONSISTENCY_LIMIT_DEG:g} deg off their own optical axis: their heights are not taken for the ground"
        )
    centre = centre[np.isfinite(centre) & ~astray]
    lowest = float(np.min(gnss.h))
    if len(centre):
        ground = min(float(np.median(centre)), lowest - HANDHELD_MOUNT_M)
        how = (
            "the KLV frame centre's median height"
            if ground < lowest - HANDHELD_MOUNT_M
            else f"{HANDHELD_MOUNT_M:g} m under the lowest position (the KLV frame centre lies level with the camera: held by hand)"
        )
        if not has_scene:
            messages.info(
                f"{path.name}: the assumed ground is {how} ({ground:.1f} m above the ellipsoid)"
            )
        return ground
    if not has_scene:
        messages.add(
            f"{path.name}: the KLV gives no frame centre: the ground is assumed {KLV_ASSUMED_HEIGHT_M:g} m under the lowest position (give --scene or --dem)"
        )
    return lowest - KLV_ASSUMED_HEIGHT_M


def _check_centre(off: np.ndarray, path: Path, messages: Messages) -> None:
    """Says when the frame centres the KLV gives (tags 23-25) lie off the optical axis their
    sets' angles give (off: KlvTrack.centre_offsets_deg, deg; median over the sets), a sign of
    angles or centres computed another way."""
    off = off[np.isfinite(off)]
    if len(off) and float(np.median(off)) > CONSISTENCY_LIMIT_DEG:
        messages.add(
            f"{path.name}: KLV consistency: the frame centre (tags 23-25) lies {np.median(off):.1f} deg (median, up to {off.max():.1f}) from the optical axis the platform and sensor angles give: the pose or the centre is wrong"
        )
    elif len(off):
        messages.info(
            f"{path.name}: KLV consistency: the frame centre lies {np.median(off):.2f} deg (median) from the optical axis"
        )


def _check_centre_on_scene(
    track: KlvTrack, frame: LocalFrame, mesh, path: Path, messages: Messages
) -> None:
    """Says when the frame centres' heights (tags 25/78) lie off the scene's ground under them
    by more than CENTRE_SCENE_LIMIT_M (median): another ground than the scene's, or a centre
    computed on a coarse terrain model; the scene is what the video is draped on."""
    lat, lon = track.values("centre_latitude_deg"), track.values("centre_longitude_deg")
    h = track.centre_heights()
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(h)
    if not ok.any():
        return
    enu = frame.geodetic_to_enu(lat[ok], lon[ok], h[ok])
    d = enu[:, 2] - ground_heights(mesh, enu[:, :2])
    d = d[np.isfinite(d)]
    if len(d) and float(np.median(np.abs(d))) > CENTRE_SCENE_LIMIT_M:
        messages.add(
            f"{path.name}: KLV consistency: the frame centres' heights (tags 25/78) lie {np.median(d):+.0f} m (median) from the scene's ground under them: the scene is draped on, the KLV's ground is not used"
        )


def _dji_name(path: Path) -> str:
    """The DJI camera the MP4 names ('DJI Mavic Air 2 (camera code FC3170 in the MP4)'), or
    'DJI drone' where it names none."""
    try:
        cam = read_dji_camera(path)
    except OSError:
        cam = None
    return cam.described if cam is not None and cam.model else "DJI drone"


def _subtitle_clock(track: SrtTrack, srt: Path, messages: Messages) -> float | None:
    """Unix time at the clip's time 0 from a DJI subtitle's dated entries (the median of date
    minus entry time), or None where it has no dates. DJI writes the aircraft's local time with
    no zone: taken as UTC, and said so."""
    ok = np.isfinite(track.wall_clock)
    if not ok.any():
        return None
    messages.add(
        f"{srt.name}: the subtitle's dates carry no time zone (DJI writes the aircraft's local time); the exports' UTC times take them as UTC"
    )
    return float(np.median(track.wall_clock[ok] - track.t[ok]))


def _dji_profile(
    path: Path, video: VideoInfo, fallback: str, messages: Messages
) -> tuple[Path, str] | None:
    """The bundled profile of the DJI camera the MP4's metadata names (DJI subtitles name none)."""
    try:
        cam = read_dji_camera(path)
    except OSError as exc:
        raise VideoError(path, f"cannot read the file's metadata ({exc})") from exc
    if cam is None:
        messages.add(
            f"{path.name}: the video's metadata names no DJI camera (no camera code, no DJI encoder): {fallback} is assumed (give --lens PROFILE.json)"
        )
        return None
    if not cam.model:
        messages.add(
            f"{path.name}: DJI camera code {cam.code} is not one geofuse knows: {fallback} is assumed (give --lens PROFILE.json)"
        )
        return None
    return _auto_profile(
        "DJI", cam.model, cam.described, video, "", f"{path.name}: ", fallback, messages
    )


def open_any(
    path: str | Path,
    srt: str | Path | None = None,
    hfov_deg: float | None = None,
    pitch_deg: float = DRONE_DEFAULT_PITCH_DEG,
    lens: str | Path | None = None,
    layers: tuple[Layer, ...] = (),
    start: StartArea | None = None,
    accuracy_m: float | None = None,
) -> Session:
    """A manifest (.toml) or a clip (pitch_deg: a drone clip's camera pitch when its subtitle has
    no gimbal attitude; layers: its scene; start: an area to search, see open_clip, the
    session's own where it names none; accuracy_m: --gnss-accuracy, m, for the fixes that state
    none: Session.stating_accuracy)."""
    session = _opened(Path(path), srt, hfov_deg, pitch_deg, lens, layers, start)
    if start is not None and session.start is None:  # a clip with no GNSS fix: from the area
        session = replace(session, start=start)
    return session.stating_accuracy(accuracy_m, "--gnss-accuracy")


def _opened(
    path: Path,
    srt: str | Path | None,
    hfov_deg: float | None,
    pitch_deg: float,
    lens: str | Path | None,
    layers: tuple[Layer, ...],
    start: StartArea | None,
) -> Session:
    """open_any's session as the manifest or the clip gives it."""
    if path.suffix.lower() == ".toml":
        given = (
            "--srt"
            if srt is not None
            else "--lens"
            if lens is not None
            else "--scene/--dem/--buildings"
            if layers
            else None
        )
        if given:
            raise GeofuseError(
                f"{given} goes with a clip, not with a manifest (a manifest names its subtitle in [gnss], its lens as camera.lens, its scene in [scene], [[layers]] and [dem])"
            )
        return open_session(path)
    return open_clip(path, srt, hfov_deg, pitch_deg, lens, layers, start)


def open_for_sync(path: str | Path, lens: str | Path | None = None) -> tuple[Session, float]:
    """(the session as its own clock times it, the offset already in that timing, s) for
    `geofuse sync`: a manifest's own video.time_offset_s, never an "auto" offset read from an
    earlier sync (the new offset is added to this one); a clip's is 0."""
    path = Path(path)
    if path.suffix.lower() == ".toml":
        cfg = read_config(path)
        return assemble(cfg), cfg.video.time_offset_s
    return open_any(path, lens=lens), 0.0


def ground_lift(clip: Session, scene_of: Session) -> float:
    """Metres to raise `clip`'s cameras by, once moved into `scene_of`'s local frame, so that
    they stand over that session's scene as over their own: a clip without a scene of its own
    (heights above take-off, an assumed ground) is seated on `scene_of`'s ground under its
    first position; a clip with a georeferenced scene needs none (0)."""
    if clip.layers or clip.scene_path is not None:
        return 0.0
    g = clip.gnss
    start = clip.frame.geodetic_to_enu(g.lat[:1], g.lon[:1], g.h[:1])[0]
    own = float(clip.scene().bounds()[0, 2])  # the assumed ground plane's height
    here = scene_of.frame.ecef_to_enu(clip.frame.enu_to_ecef([start[0], start[1], own]))
    under = ground_heights(scene_of.scene(), [here[:2]])[0]
    return float(under - here[2]) if np.isfinite(under) else 0.0


def onto(clip: Session, scene_of: Session) -> Callable[[Camera], Camera]:
    """How `clip`'s cameras are drawn on `scene_of`'s scene: moved into its local frame and
    raised by ground_lift (computed once)."""
    lift = ground_lift(clip, scene_of)
    return lambda camera: camera_in_frame(camera, clip.frame, scene_of.frame, lift)
