"""`geofuse telemetry FILE [--csv OUT]`: what a file holds, for every format geofuse reads
(GoPro MP4, DJI SRT, GPX, Sensor Logger exports, geofuse CSV logs): each stream with its sample
count, rate, time range and gaps, the GNSS fixes, and every warning. `--csv` writes the position
track: one row per position sample, `time_s,latitude,longitude,height` (seconds from the start of
the clip or log, degrees, metres) and any attitude columns after them."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from app.attitude.gopro import read_gopro
from app.camera.trajectory import gaps_said
from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.core.outputs import CSV_SUFFIXES, check_output, write_atomically
from app.geodesy.rotations import hpr_from_camera_quat, slerp
from app.io import csvlog
from app.io.dji_mp4 import read_dji_camera
from app.io.dji_srt import read_srt, srt_fixes
from app.io.gopro import global_settings
from app.io.gpmf import Counts, chunks, parse
from app.io.gpx import read_gpx
from app.io.klv_track import (
    IMAGE_SOURCE_SENSOR_TAG,
    PLATFORM_DESIGNATION_TAG,
    RAW_KLV_SUFFIXES,
    KlvTrack,
    has_klv,
    read_klv,
    read_raw_klv,
    starts_as_klv,
)
from app.io.klv_track import describe as describe_klv
from app.io.sensorlogger import read_sensorlogger
from app.io.streams import GAP_FACTOR
from app.io.video import probe


@dataclass
class Stream:
    name: str
    t: np.ndarray
    unit: str = ""


@dataclass
class Telemetry:
    """Streams and a position track (t s from the start, lat, lon, height, extra named columns)."""

    path: Path
    kind: str
    streams: list[Stream] = field(default_factory=list)
    position: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    height_note: str = ""
    attitude: dict[str, np.ndarray] = field(default_factory=dict)
    messages: Messages = field(default_factory=Messages)
    info: list[str] = field(default_factory=list)


def inspect(path: str | Path) -> Telemetry:
    """Read any supported telemetry file. Raises DataFormatError naming the file otherwise."""
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "file does not exist")
    suffix = path.suffix.lower()
    if suffix == ".srt":
        return _srt(path)
    if suffix == ".gpx":
        return _gpx(path)
    if suffix in KLV_SUFFIXES or (suffix in (".mp4", ".mov") and has_klv(path)):
        return _klv(path)
    if suffix in RAW_KLV_SUFFIXES or (suffix in RAW_GPMF_SUFFIXES and starts_as_klv(path)):
        return _klv_raw(path)
    if suffix in (".mp4", ".mov", ".360"):
        _refuse_dji_video(path)
        return _gopro(path)
    if suffix in RAW_GPMF_SUFFIXES:
        return _gpmf_payload(path)
    if path.is_dir() or suffix == ".zip":
        return _sensorlogger(path)
    if suffix == ".csv":
        return _csv(path)
    raise DataFormatError(
        path,
        f"unknown telemetry format {suffix!r} (expected .MP4 from a GoPro, .TS with MISB KLV, raw KLV .klv/.bin, raw GPMF .bin/.gpmd/.raw, .SRT, .GPX, .CSV, or a Sensor Logger folder or zip)",
    )


KLV_SUFFIXES = (".ts", ".m2ts", ".mpg")  # MPEG transport streams, where MISB KLV travels
RAW_GPMF_SUFFIXES = (".bin", ".gpmd", ".raw", ".gpmf")  # GPMF extracted from an MP4 by other tools


def _gpmf_payload(path: Path) -> Telemetry:
    """GPMF bytes extracted from a GoPro MP4 (one payload or several back to back): its streams
    and sample counts. Without the MP4's sample table there is no time span: the streams are
    listed by count, and positions (GPS5/GPS9) by order."""
    out = Telemetry(path, "GoPro GPMF telemetry, raw (no MP4 timing)")
    counts = Counts()
    tree = parse(path.read_bytes(), str(path), counts)
    by_key: dict[str, list] = {}
    device = ""
    for c in chunks(tree, 0.0, 1.0):
        device = device or c.device
        by_key.setdefault(c.key, []).append(c)
    if not by_key:
        raise DataFormatError(path, "no GPMF stream with samples (expected DEVC > STRM entries)")
    out.info.append(f"camera: {device or 'unnamed'}; streams: {', '.join(sorted(by_key))}")
    for key, parts in sorted(by_key.items()):
        n = sum(len(c.samples) for c in parts)
        out.info.append(
            f"{key}: {n} samples in {len(parts)} chunk(s)"
            + (f", ORIN {parts[0].modifiers['ORIN']}" if "ORIN" in parts[0].modifiers else "")
        )
    if counts.skipped:
        out.messages.add(f"{path.name}: telemetry keys skipped (undecodable): {counts.skipped}")
    return out


def _srt(path: Path) -> Telemetry:
    out = Telemetry(path, "DJI subtitle telemetry")
    tr = read_srt(path, out.messages)
    out.streams.append(Stream("entries", tr.t))
    fixes = srt_fixes(tr, out.messages)
    ok = np.isin(tr.t, fixes.t)
    out.position = (fixes.t, fixes.lat, fixes.lon, fixes.h)
    out.height_note = (
        "above take-off" if tr.height_relative else "absolute (as the aircraft reports it)"
    )
    if tr.has_gimbal:
        out.attitude = {
            "gimbal_pitch": tr.gimbal_pry[ok, 0],
            "gimbal_roll": tr.gimbal_pry[ok, 1],
            "gimbal_yaw": tr.gimbal_pry[ok, 2],
        }
    out.info.append(f"layouts: {', '.join(tr.layouts)}")
    return out


def _klv_raw(path: Path) -> Telemetry:
    """A file of KLV Local Sets with no video around them: their times from their Precision
    Time Stamps (tag 2), the first set at 0 s; then as a video's KLV (_klv)."""
    out = Telemetry(path, "MISB ST 0601 KLV, raw (no video: times from the Precision Time Stamps)")
    return _klv_report(out, read_raw_klv(path, out.messages), np.zeros(0))


def _klv(path: Path) -> Telemetry:
    """A video's MISB ST 0601 KLV: sets, the sensor's positions and the camera's angles (the
    platform's and the sensor's, and the composed optical axis's heading, pitch and roll)."""
    out = Telemetry(path, "MISB ST 0601 KLV in a video")
    video = probe(path)
    video.note_damage(out.messages)
    return _klv_report(out, read_klv(path, video, out.messages), video.pts_s)


def _klv_report(out: Telemetry, track: KlvTrack, frame_pts_s: np.ndarray) -> Telemetry:
    """The sets' streams, positions and angles into `out` (see _klv)."""
    path = out.path
    out.info.append(describe_klv(track, frame_pts_s))
    platform, sensor = track.text(PLATFORM_DESIGNATION_TAG), track.text(IMAGE_SOURCE_SENSOR_TAG)
    if platform or sensor:
        out.info.append(f"platform: {platform or 'unnamed'}; sensor: {sensor or 'unnamed'}")
    out.streams.append(Stream("Local Sets", track.times()))
    g = track.gnss(out.messages)
    if g is None:
        out.messages.add(
            f"{path.name}: no KLV set places the sensor (tags 13 and 14, and 75 or 15, are missing or the error code in all {len(track.sets)} sets): no positions"
        )
    else:
        out.streams.append(Stream("sensor positions (tags 13, 14, 75/15)", g.t))
        out.position = (g.t, g.lat, g.lon, g.h)
        out.height_note = "ellipsoidal (tag 75, or tag 15 above sea level through EGM2008)"
        if gaps := gaps_said(g.t):
            out.messages.add(f"{path.name}: KLV: {gaps}")
    att = track.attitude()
    if att is not None:
        out.streams.append(Stream("camera attitude (platform then sensor angles)", att.t))
        if g is not None:
            hpr = hpr_from_camera_quat(slerp(att.t, att.q, g.t))
            out.attitude = {"heading": hpr[:, 0], "pitch": hpr[:, 1], "roll": hpr[:, 2]}
    return out


def _gpx(path: Path) -> Telemetry:
    out = Telemetry(path, "GPX track")
    g = read_gpx(path, out.messages)
    t = g.t - g.t[0]
    out.streams.append(Stream("track points", g.t))
    out.position = (t, g.lat, g.lon, g.h)
    out.height_note = "<ele> (usually above mean sea level)"
    return out


def _refuse_dji_video(path: Path) -> None:
    """A DJI video keeps its telemetry in the subtitle beside it: say so, naming the camera."""
    try:
        cam = read_dji_camera(path)
    except OSError:
        return  # the GoPro reader names the file's fault
    if cam is not None:
        raise DataFormatError(
            path,
            f"a video from {cam.described}: DJI keeps the telemetry in the subtitle beside it: give the .SRT to geofuse telemetry",
        )


def _gopro(path: Path) -> Telemetry:
    out = Telemetry(path, "GoPro MP4 (GPMF telemetry)")
    r = read_gopro(path, out.messages)
    settings = global_settings(path)
    mode = settings.get("VFOV", "?")
    out.info.append(f"camera: {r.raw.model}; lens mode {mode}, horizontal FOV {r.hfov_deg:.1f} deg")
    for s in (r.acc, r.gyr, r.mag):
        if s is not None:
            out.streams.append(
                Stream(
                    {
                        "acc": "ACCL accelerometer",
                        "gyr": "GYRO gyroscope",
                        "mag": "MAGN magnetometer",
                    }[s.name],
                    s.t,
                    s.unit,
                )
            )
    if r.camera is not None:
        out.streams.append(Stream("CORI camera orientation", r.camera.t))
    if r.gnss is not None:
        out.streams.append(
            Stream(
                f"GPS (averaged to {1 / 0.5:g} Hz; {r.raw.dropped_no_fix} samples without fix dropped)",
                r.gnss.t,
            )
        )
        out.position = (r.gnss.t, r.gnss.lat, r.gnss.lon, r.gnss.h)
        out.height_note = "GPS altitude (WGS84)"
    if r.raw.gps_precision is not None and len(r.raw.gps_precision):
        out.info.append(f"GPS precision (DOP): median {np.median(r.raw.gps_precision[:, 1]):.2f}")
    if r.gps_utc_at_zero:
        out.info.append(
            f"clip start (GPSU): {datetime.fromtimestamp(r.gps_utc_at_zero, UTC).isoformat()}"
        )
    return out


def _sensorlogger(path: Path) -> Telemetry:
    out = Telemetry(path, "Sensor Logger recording")
    rec = read_sensorlogger(path, messages=out.messages)
    t0 = min(s.t[0] for s in (rec.acc, rec.gyr) if s is not None)
    for s in (rec.acc, rec.gyr, rec.mag):
        if s is not None:
            out.streams.append(Stream(s.name, s.t, s.unit))
    if rec.orientation is not None:
        out.streams.append(Stream(f"orientation ({rec.orientation.note})", rec.orientation.t))
    if rec.gnss is not None:
        g = rec.gnss
        out.streams.append(Stream("location", g.t))
        out.position = (g.t - t0, g.lat, g.lon, g.h)
        out.height_note = "ellipsoidal (the app's altitude)"
    return out


def _csv(path: Path) -> Telemetry:
    out = Telemetry(path, "geofuse CSV log")
    columns, _, _, _ = csvlog.read_table(path)
    if {"lat", "lon", "h"} <= set(columns):
        g = csvlog.read_gnss(path, out.messages)
        out.streams.append(Stream("GNSS", g.t))
        out.position = (g.t - g.t[0], g.lat, g.lon, g.h)
        out.height_note = "ellipsoidal"
    elif {"qw", "qx", "qy", "qz"} <= set(columns):
        o = csvlog.read_orientation(path, out.messages)
        out.streams.append(Stream("orientation", o.t))
    else:
        kind = (
            "gyr" if "gyr" in path.stem.lower() else "mag" if "mag" in path.stem.lower() else "acc"
        )
        s = csvlog.read_vector(path, kind, out.messages)
        out.streams.append(Stream(kind, s.t, s.unit))
    return out


def describe(tel: Telemetry) -> str:
    """A human-readable report."""
    lines = [f"{tel.path}: {tel.kind}"]
    lines += [f"  {i}" for i in tel.info]
    for s in tel.streams:
        n = len(s.t)
        if n > 1:
            dt = np.diff(s.t)
            med = float(np.median(dt))
            gaps = int((dt > GAP_FACTOR * med).sum()) if med > 0 else 0
            lines.append(
                f"  {s.name}: {n} samples, {1 / med if med > 0 else 0:.2f} Hz, {s.t[0]:.3f}..{s.t[-1]:.3f} s, {gaps} gaps"
                + (f" [{s.unit}]" if s.unit else "")
            )
        else:
            lines.append(f"  {s.name}: {n} sample(s)")
    if tel.position is not None:
        t, lat, lon, h = tel.position
        lines.append(
            f"  positions: {len(t)} fixes, first ({lat[0]:.6f}, {lon[0]:.6f}, {h[0]:.1f} m), last ({lat[-1]:.6f}, {lon[-1]:.6f}, {h[-1]:.1f} m); heights {tel.height_note}"
        )
    for w in tel.messages.items:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)


def write_csv(tel: Telemetry, out: str | Path) -> int:
    """The position track as CSV (never onto the input); returns the number of rows."""
    out = Path(out)
    if tel.position is None:
        raise DataFormatError(tel.path, "holds no positions to write")
    out = check_output(out, "--csv", CSV_SUFFIXES, [tel.path])
    t, lat, lon, h = tel.position
    extra = list(tel.attitude)

    def rows(f) -> None:
        w = csv.writer(f)
        w.writerow(["time_s", "latitude", "longitude", "height", *extra])
        for i in range(len(t)):
            w.writerow(
                [
                    f"{t[i]:.3f}",
                    f"{lat[i]:.9f}",
                    f"{lon[i]:.9f}",
                    f"{h[i]:.3f}",
                    *(f"{tel.attitude[k][i]:.2f}" for k in extra),
                ]
            )

    write_atomically(out, "--csv", rows)
    return len(t)
