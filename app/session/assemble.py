"""Session assembly: a validated manifest (app.session.config) -> the readers -> one frozen
`Session`. Every value is final before the Session is made: take-off heights, heading policy,
magnetometer calibration, true frame times."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from app.attitude import magcal
from app.attitude.gopro import read_gopro
from app.attitude.heading import heading_policy
from app.camera.frame_time import corrected_times
from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens
from app.camera.profiles import video_camera
from app.core.errors import ManifestError, VideoError
from app.core.messages import Messages
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geomag import declination, field_enu
from app.io import csvlog
from app.io.dji_srt import SrtTrack, read_srt, srt_fixes, takeoff_heights
from app.io.gpx import read_gpx
from app.io.sensorlogger import read_sensorlogger
from app.io.streams import GnssTrack, OrientationStream, VectorStream
from app.io.video import VideoInfo, probe
from app.scene import Placement
from app.scene.ground import ellipsoidal_ground
from app.scene.ground_plane import ASSUMED_GROUND_MARGIN_M, ground_reach_m, ground_under_track
from app.scene.layers import load_layers
from app.scene.mesh import MeshData
from app.session.config import SessionConfig, read_config
from app.session.model import Session
from app.session.start import TAKEOFF, PlatformHeights
from app.sync import sync_session, synced_drift, synced_offset, timed_by
from app.world.build import deferring, resolve_worlds


def open_session(path: str | Path) -> Session:
    """Read and validate a manifest and every file it names; with video.time_offset_s = "auto",
    the offset stored by `geofuse sync --write`, or found now."""
    cfg = read_config(path)
    session = assemble(cfg)
    if not cfg.video.auto_offset:
        return session

    offset = synced_offset(cfg.path)
    if offset is not None:
        drift, pivot = synced_drift(cfg.path)
        session.messages.info(
            f"time offset {1000 * offset:+.1f} ms (drift {drift:+.0f} ppm) from {cfg.path.stem}.geofuse.toml (geofuse sync --write)"
        )
    else:
        result = sync_session(session)
        offset, drift, pivot = result.offset_s, result.drift_ppm, result.reference_s
        session.messages.info(
            f"time offset {1000 * offset:+.1f} ms (drift {drift:+.0f} ppm) found from the video against {timed_by(session)} (confidence {result.confidence:.2f}); geofuse sync --write keeps it"
        )
    return replace(session, frame_times=corrected_times(session.frame_times, offset, drift, pivot))


def _intrinsics(
    cfg: SessionConfig, width: int, height: int, rotation_cw: int, messages: Messages
) -> tuple[Intrinsics, Lens | None]:
    """(the pinhole the depth pass uses, the real lens or None), for the displayed video."""
    cam = cfg.camera
    if cam.lens is not None:
        try:
            intr, lens = video_camera(cam.lens, width, height, rotation_cw)
        except ValueError as exc:
            raise ManifestError(cfg.path, str(exc), field="camera.lens") from exc
        messages.info(f"lens: {lens.kind} model from {cam.lens.name}")
        return intr, lens
    return _pinhole(cfg, width, height), None


def _readout(cfg: SessionConfig, lens: Lens | None, messages: Messages) -> float | None:
    """The rolling shutter's readout time (s): the manifest's, else the lens profile's; says so."""
    if cfg.camera.readout_ms is not None:
        return cfg.camera.readout_ms / 1000.0 or None
    if lens is not None and lens.readout_s:
        messages.info(
            f"rolling shutter: readout {1000 * lens.readout_s:.1f} ms from the lens profile, corrected row by row"
        )
        return lens.readout_s
    messages.add("rolling shutter: readout time unknown (camera.readout_ms): not corrected")
    return None


def _pinhole(cfg: SessionConfig, width: int, height: int) -> Intrinsics:
    cam = cfg.camera
    try:
        if cam.hfov_deg is not None:
            return Intrinsics.from_fov(width, height, cam.hfov_deg)
        return Intrinsics.from_focal_length(width, height, cam.focal_mm, cam.sensor_width_mm)
    except ValueError as exc:
        raise ManifestError(cfg.path, str(exc), field="camera") from exc


def _shifted(stream, dt: float):
    """A stream or track with its times moved by dt seconds (clip clock -> session clock)."""
    return None if stream is None else replace(stream, t=stream.t + dt)


def _sensors(cfg: SessionConfig, messages: Messages, clip_start: float):
    """(acc, gyr, mag, recorded attitudes, GNSS from the sensors or None)."""
    s = cfg.sensors
    recorded: dict[str, OrientationStream] = {}
    acc = gyr = mag = gnss = None
    if s.format == "gopro":
        rec = read_gopro(cfg.video.path, messages)
        # GPMF times count from the clip start; the session clock adds the video's start time.
        acc, gyr, mag, gnss = (
            _shifted(x, clip_start) for x in (rec.acc, rec.gyr, rec.mag, rec.gnss)
        )
        if rec.camera is not None:
            recorded["camera"] = _shifted(rec.camera, clip_start)
    elif s.format == "sensorlogger":
        rec = read_sensorlogger(s.path, s.standardised, messages)
        acc, gyr, mag, gnss = rec.acc, rec.gyr, rec.mag, rec.gnss
        if rec.orientation is not None:
            recorded["phone"] = rec.orientation
    elif s.format == "csv":
        acc = csvlog.read_vector(s.acc, "acc", messages)
        gyr = csvlog.read_vector(s.gyr, "gyr", messages)
        mag = csvlog.read_vector(s.mag, "mag", messages) if s.mag else None
        if s.orientation:
            recorded["phone"] = csvlog.read_orientation(s.orientation, messages)
    if cfg.truth.orientation:
        recorded["truth"] = csvlog.read_orientation(cfg.truth.orientation, messages)
    return acc, gyr, mag, recorded, gnss


def _gnss(
    cfg: SessionConfig,
    logged: GnssTrack | None,
    messages: Messages,
    clip_start: float,
    recorded: dict[str, OrientationStream],
) -> tuple[GnssTrack, bool, tuple | None, PlatformHeights | None]:
    """(the session's GNSS track, whether its heights are above take-off, a drone's own yaw
    (t session s, deg) when its subtitle has one and no gimbal attitude, a subtitle's heights
    above take-off where it has no position: Session.platform_heights)."""
    path = cfg.gnss.path
    if path is None and logged is None:
        raise ManifestError(
            cfg.path, "the sensors hold no GNSS track: give gnss.path", field="gnss.path"
        )
    if path is not None and path.suffix.lower() == ".srt":
        return _srt_gnss(path, messages, clip_start, recorded, cfg.origin is not None)
    track = logged
    if path is not None:
        track = (
            read_gpx(path, messages)
            if path.suffix.lower() == ".gpx"
            else csvlog.read_gnss(path, messages, allow_empty=cfg.origin is not None)
        )
    return replace(track, h=track.h + cfg.gnss.height_offset_m), False, None, None


def _srt_gnss(
    path: Path,
    messages: Messages,
    clip_start: float,
    recorded: dict[str, OrientationStream],
    unfixed: bool = False,
) -> tuple[GnssTrack, bool, tuple | None, PlatformHeights | None]:
    """A DJI subtitle as the session's GNSS (its times are the clip's, shifted to the session
    clock) and, with gimbal angles, its `telemetry` attitude, else the aircraft's yaw; unfixed
    (a manifest with an origin): one without any position is read (no fix, its heights above
    take-off kept for a cold start), as _gnss returns."""
    tr = read_srt(path, messages, positioned=not unfixed)
    yaw = None
    if tr.has_gimbal:
        recorded["telemetry"] = _shifted(gimbal_attitude(tr, path), clip_start)
    elif tr.aircraft_yaw() is not None:
        t, deg = tr.aircraft_yaw()
        yaw = (t + clip_start, deg)
    if not tr.has_position.any():
        empty = GnssTrack(*np.zeros((4, 0)), path=str(path))
        return empty, False, yaw, subtitle_heights(tr, clip_start)
    return srt_fixes(tr, messages, clip_start), bool(tr.height_relative), yaw, None


def subtitle_heights(track: SrtTrack, offset_s: float) -> PlatformHeights | None:
    """A DJI subtitle's heights above take-off (times + offset_s s) as the platform's
    (Session.platform_heights), None where it gives none."""
    heights = takeoff_heights(track, offset_s)
    if heights is None:
        return None
    return PlatformHeights(*heights, TAKEOFF, "the subtitle's height above take-off")


def gimbal_attitude(track, path: Path) -> OrientationStream:
    """A DJI subtitle's gimbal pitch, roll, yaw as camera -> ENU quaternions (clip seconds)."""
    g = np.isfinite(track.gimbal_pry).all(axis=1)
    p, r, y = track.gimbal_pry[g].T
    return OrientationStream(
        track.t[g],
        rotations.camera_quat_from_hpr(y % 360.0, p, r),
        str(path),
        "DJI gimbal pitch, roll, yaw (G.PRY)",
    )


def _takeoff_height(
    cfg: SessionConfig, frame: LocalFrame, gnss: GnssTrack, mesh, messages: Messages
) -> float:
    """The take-off point's ellipsoidal height: the manifest's, else the scene's ground under the
    first position; says which."""
    value = cfg.gnss.takeoff_height_m
    if value is not None:
        messages.info(
            f"heights above take-off: take-off height {value:.2f} m from gnss.takeoff_height_m"
        )
        return value
    value = ellipsoidal_ground(mesh, frame, float(gnss.lat[0]), float(gnss.lon[0]))
    if value is None:
        raise ManifestError(
            cfg.path,
            "heights are above take-off and the scene has no ground under the first position: give gnss.takeoff_height_m",
            field="gnss.takeoff_height_m",
        )
    messages.info(
        f"heights above take-off: take-off height {value:.2f} m from the scene's ground under the first position"
    )
    return value


def load_scene_layers(
    layers,
    frame: LocalFrame,
    gnss: GnssTrack,
    messages: Messages,
    ground_h: float | None = None,
    margin_m: float = ASSUMED_GROUND_MARGIN_M,
) -> MeshData:
    """Every layer in `frame`, read around the track (app.scene.layers.load_layers), with what
    reading them found said, and a warning with the distance for each layer that lies away from
    the camera's track (a wrong origin, up axis or ECEF reading places a model thousands of
    kilometres off: LoadedLayers.warn_far). ground_h, margin_m: the assumed ground (ellipsoidal
    m) building footprints stand on where no other layer has ground, and its reach (m)."""
    loaded = load_layers(layers, frame, np.column_stack([gnss.lat, gnss.lon]), ground_h, margin_m)
    loaded.warn_far(frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h), "the camera's track")
    messages.extend(loaded.notes)
    return loaded.mesh


def _frame_times(cfg: SessionConfig, video: VideoInfo) -> tuple[float, np.ndarray]:
    """(the session time of media time 0, every frame's session time)."""
    start = cfg.video.start_time if cfg.video.start_time is not None else video.creation_time
    if start is None:
        raise ManifestError(
            cfg.path,
            "the video has no creation time: give video.start_time (session-clock seconds)",
            field="video.start_time",
        )
    clip_start = float(start) + cfg.video.time_offset_s
    return clip_start, clip_start + (
        video.pts_s if cfg.video.timing == "pts" else video.eq5_times()
    )


def _check_coverage(
    cfg: SessionConfig, frame_times: np.ndarray, log_t: np.ndarray, messages: Messages
) -> None:
    covered = (frame_times >= log_t[0]) & (frame_times <= log_t[-1])
    if not covered.any():
        raise ManifestError(
            cfg.path,
            f"no video frame lies within the sensor log (frames {frame_times[0]:.3f}..{frame_times[-1]:.3f} s, "
            f"log {log_t[0]:.3f}..{log_t[-1]:.3f} s): check video.start_time and the logs' clocks",
            field="video.start_time",
        )
    if not covered.all():
        messages.add(
            f"{int((~covered).sum())} video frames lie outside the sensor log; their attitude is held"
        )


def _calibrate_magnetometer(
    mag: VectorStream | None,
    origin: tuple[float, float, float],
    when: float,
    mode: str,
    messages: Messages,
) -> VectorStream | None:
    """The magnetometer calibrated on the clip (app.attitude.magcal), unless mode is "none"."""
    if mag is None or mode == "none":
        return mag
    cal = magcal.fit(mag.values, float(np.linalg.norm(field_enu(*origin, when))))
    if isinstance(cal, str):
        messages.add(f"magnetometer not calibrated: {cal}")
        return mag
    messages.info(f"magnetometer calibrated on the clip: {cal.describe()}")
    return replace(mag, values=cal.apply(mag.values))


def _true_frame_times(cfg: SessionConfig, count: int, messages: Messages) -> np.ndarray | None:
    path = cfg.truth.frame_times
    if path is None:
        return None
    columns, _, rows, first = csvlog.read_table(path)
    values, _ = csvlog.numeric(path, rows, columns, ["frame", "t"], first, messages)
    if len(values) != count:
        raise ManifestError(
            cfg.path,
            f"{len(values)} true frame times for {count} video frames",
            field="truth.frame_times",
        )
    return values[np.argsort(values[:, 0]), 1]


def _place(cfg: SessionConfig, gnss: GnssTrack, above_takeoff: bool, messages: Messages):
    """(frame, mesh, gnss with final heights): the session's ENU frame and scene. Without any
    layer, an assumed flat ground under the track (the first fix's height less the mount height,
    or the take-off height for heights above take-off), as for clips opened directly. A
    [world] is built around the track first (app.world.build.resolve_worlds; dropped, and said,
    where none of its tiles could be had). Both reach as far beyond the track as the camera
    sees the ground: a track whose heights are above take-off is flown, and they are its
    heights over the ground (app.scene.ground_plane.ground_reach_m, as a drone clip's); any
    other is taken to be held at the mount height over a ground that follows it."""
    if not len(gnss.t) and not any(layer.kind != "world" for layer in cfg.layers):
        raise ManifestError(
            cfg.path,
            "no GNSS fix at all and no scene: a clip without GNSS is searched for on a scene ([scene] or [[layers]]; a [world] is built around a track)",
            field="gnss.path",
        )
    background = deferring(cfg.layers)  # the viewer builds the world while the flat ground shows
    reach = ground_reach_m(gnss.h) if above_takeoff else ASSUMED_GROUND_MARGIN_M
    if any(layer.kind == "world" for layer in cfg.layers):
        takeoff = cfg.gnss.takeoff_height_m or 0.0
        ground = takeoff if above_takeoff else float(gnss.h[0]) - cfg.gnss.mount_height_m
        h = gnss.h + takeoff if above_takeoff else gnss.h
        layers = resolve_worlds(
            cfg.layers, gnss.lat, gnss.lon, h, ground, reach, messages,
            above_takeoff and cfg.gnss.takeoff_height_m is None,
        )  # fmt: skip
        cfg = replace(cfg, layers=layers)
    if not cfg.layers:
        takeoff = cfg.gnss.takeoff_height_m or 0.0
        if above_takeoff:
            gnss = replace(gnss, h=gnss.h + takeoff)
        ground = takeoff if above_takeoff else float(gnss.h[0]) - cfg.gnss.mount_height_m
        frame = (
            LocalFrame(*cfg.origin)
            if cfg.origin is not None
            else LocalFrame(float(gnss.lat[0]), float(gnss.lon[0]), ground)
        )
        if not background:
            messages.add(
                "no scene given: the video is projected on an assumed flat ground with a 1 m grid"
            )
        return (
            frame,
            ground_under_track(frame, gnss.lat, gnss.lon, ground, reach),
            gnss,
        )
    try:
        origin = cfg.origin or (
            float(gnss.lat[0]),
            float(gnss.lon[0]),
            0.0 if above_takeoff else float(gnss.h[0]),
        )
        frame = LocalFrame(*origin)
    except ValueError as exc:
        raise ManifestError(cfg.path, str(exc), field="origin") from exc
    ground = (
        (cfg.gnss.takeoff_height_m or 0.0)
        if above_takeoff
        else float(gnss.h[0]) - cfg.gnss.mount_height_m
        if len(gnss.h)
        else frame.h_m  # no fix at all (a cold start): the origin's height
    )
    mesh = load_scene_layers(cfg.layers, frame, gnss, messages, ground, reach)
    if above_takeoff:
        gnss = replace(gnss, h=gnss.h + _takeoff_height(cfg, frame, gnss, mesh, messages))
    return frame, mesh, gnss


def assemble(cfg: SessionConfig) -> Session:
    """Every reader the config names, on one clock, into one frozen Session."""
    messages = Messages()
    try:
        video = probe(cfg.video.path)
    except VideoError as exc:  # name the manifest's key, as every manifest error does
        raise ManifestError(
            cfg.path, f"{cfg.video.path.name}: {exc.detail}", field="video.path"
        ) from exc
    video.note_damage(messages)
    clip_start, frame_times = _frame_times(cfg, video)
    if cfg.video.start_time is None:
        messages.add(
            f"video.start_time not given: the video's creation time {video.creation_time:.3f} s is the first frame's session time "
            "(a file timestamp can be off by a second; `geofuse sync` finds the offset)"
        )
    rotation = video.rotation_cw if cfg.camera.rotation_cw is None else cfg.camera.rotation_cw
    w, h = (video.height, video.width) if rotation % 180 else (video.width, video.height)
    intr, lens = _intrinsics(cfg, w, h, rotation, messages)

    acc, gyr, mag, recorded, logged_gnss = _sensors(cfg, messages, clip_start)
    gnss, above_takeoff, yaw, heights = _gnss(cfg, logged_gnss, messages, clip_start, recorded)
    timed = gyr if gyr is not None else gnss if len(gnss.t) else recorded.get("telemetry")
    if timed is not None:  # else a cold start with no attitude either: said when it searches
        _check_coverage(cfg, frame_times, timed.t, messages)
    frame, mesh, gnss = _place(cfg, gnss, above_takeoff, messages)
    origin = (frame.lat_deg, frame.lon_deg, frame.h_m)
    mag = _calibrate_magnetometer(
        mag, origin, float(frame_times[0]), cfg.sensors.mag_calibration, messages
    )
    truth_position = csvlog.read_gnss(cfg.truth.position, messages) if cfg.truth.position else None
    policy = heading_policy(
        gyr is not None, mag is not None, recorded, cfg.gnss.pitch_deg, yaw is not None
    )
    if policy.note:
        messages.info(policy.note)
    return Session(
        cfg.path, frame, Path(cfg.layers[0].location) if cfg.layers else None, cfg.scene.placement if cfg.scene else Placement(), video, frame_times, intr, rotation,
        acc, gyr, mag, gnss, recorded, declination(*origin, float(frame_times[0])), messages,
        inputs=tuple(cfg.inputs()), truth_position=truth_position,
        truth_frame_times=_true_frame_times(cfg, len(frame_times), messages),
        height_mode=cfg.gnss.height if cfg.layers else "gnss", mount_height_m=cfg.gnss.mount_height_m, heading=policy,
        device_is_camera=cfg.sensors.format in ("gopro", "none"),  # action cameras and drones
        aircraft_yaw=yaw, mesh=mesh, lens=lens, readout_s=_readout(cfg, lens, messages), layers=cfg.layers,
        further=cfg.clips, platform_heights=heights,
    ).stating_accuracy(cfg.gnss.accuracy_m, "[gnss] accuracy_m")  # fmt: skip
