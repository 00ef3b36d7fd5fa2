"""Finding the clips of an archive and indexing one (a Dask task): its telemetry, its pose,
footprints at a spacing in seconds, and the clip's facts.

A clip is a session manifest (`*.toml` with a `[video]` table; its video is then not indexed
again on its own), or a video (`.mp4`, `.mov`) that geofuse opens without one: a GoPro MP4
(GPMF telemetry), a DJI MP4 with its `.SRT` beside it. A clip's identity is its path, size and
modification time (what an incremental re-run compares), and a fingerprint of its content
(size, and a hash of its first and last MiB) that finds the same file stored twice.
"""

from __future__ import annotations

import hashlib
import resource
import time
import tomllib
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from shapely import wkb

from app.core.errors import GeofuseError
from app.export.footprint import plan_footprint
from app.export.records import frame_records
from app.footage.clips import open_any
from app.geodesy import rotations
from app.scene.layers import Layer

__all__ = ["ClipResult", "clip_key", "find_clips", "fingerprint", "index_clip", "walk_clips"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".ts")  # .ts: MPEG-TS with MISB KLV
SKIPPED_TOMLS = (".geofuse.toml",)  # settings geofuse writes beside a clip, not manifests
FINGERPRINT_BYTES = 1 << 20


def _manifest_video(path: Path) -> Path | None:
    """The video a manifest names (resolved), or None when the file is not a manifest."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    video = doc.get("video")
    if not isinstance(video, dict) or not isinstance(video.get("path"), str):
        return None
    return (path.parent / video["path"]).resolve()


NOT_A_CLIP = "not a clip (expected a video .mp4, .mov or .ts, or a session manifest .toml)"
NOT_A_MANIFEST = "a .toml that is not a session manifest (no [video] path)"


def walk_clips(roots: list[Path]) -> tuple[list[Path], list[tuple[Path, str]]]:
    """Every clip under the roots (files or folders, walked recursively), sorted; a manifest's
    video is indexed through the manifest only. And the files passed over, each with why (a
    .toml that is not a manifest, a file of another kind; settings geofuse writes and the
    videos of manifests are neither)."""
    manifests, videos, others = [], [], []
    for root in roots:
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        for p in files:
            name = p.name.lower()
            if name.endswith(".toml") and not name.endswith(SKIPPED_TOMLS):
                manifests.append(p.resolve())
            elif p.suffix.lower() in VIDEO_SUFFIXES:
                videos.append(p.resolve())
            elif not name.endswith(SKIPPED_TOMLS):
                others.append((p.resolve(), NOT_A_CLIP))
    named = {m: _manifest_video(m) for m in manifests}
    clips = [m for m, video in named.items() if video is not None]
    clips += [v for v in videos if v not in set(named.values())]
    others += [(m, NOT_A_MANIFEST) for m, video in named.items() if video is None]
    return sorted(set(clips)), sorted(set(others))


def find_clips(roots: list[Path]) -> list[Path]:
    """Every clip under the roots (see walk_clips); a .toml that is not a manifest is not a
    clip."""
    return walk_clips(roots)[0]


def fingerprint(path: Path) -> str:
    """The file's size and a SHA-256 of its first and last MiB: the same clip stored twice."""
    size = path.stat().st_size
    h = hashlib.sha256(str(size).encode())
    with path.open("rb") as f:
        h.update(f.read(FINGERPRINT_BYTES))
        if size > FINGERPRINT_BYTES:
            f.seek(max(FINGERPRINT_BYTES, size - FINGERPRINT_BYTES))
            h.update(f.read(FINGERPRINT_BYTES))
    return h.hexdigest()


def clip_key(path: Path) -> tuple[int, int]:
    """(size in bytes, modification time in ns): a clip unchanged since it was indexed."""
    st = path.stat()
    return st.st_size, st.st_mtime_ns


@dataclass
class ClipResult:
    """One clip's outcome. status: 'indexed' or 'failed' (error says why; 'duplicate' is set by
    the index, which compares fingerprints); facts: camera, lens, source, time span, UTC start,
    track length, messages; rows: one dict per footprint (see app.archive.store)."""

    path: str
    size: int
    mtime_ns: int
    fingerprint: str
    status: str
    error: str = ""
    facts: dict = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)
    seconds: float = 0.0  # the work it took (the worker's wall clock)
    worker_peak_mb: float = 0.0  # the worker process's peak resident memory after it, MiB


def _optical_axis(hpr: tuple[float, float, float]) -> np.ndarray:
    """The optical axis (ENU unit vector) of a camera at heading, pitch, roll (degrees)."""
    q = rotations.camera_quat_from_hpr(*hpr)
    return rotations.rotate(q, [0.0, 0.0, -1.0])


def index_clip(
    path: str,
    every_s: float = 1.0,
    scene: tuple[str, ...] = (),
    source: str | None = None,
    digest: str | None = None,
) -> ClipResult:
    """Index one clip (runs on a Dask worker: its own EGL context for the footprints); digest:
    its fingerprint when already taken. A clip that cannot be read is a 'failed' result with the
    reason, never an exception."""
    started = time.perf_counter()
    p = Path(path)
    try:
        size, mtime = clip_key(p)
        digest = digest or fingerprint(p)
    except OSError as exc:
        return ClipResult(path, 0, 0, "", "failed", f"{path}: {exc.strerror or exc}")
    result = ClipResult(path, size, mtime, digest, "indexed")
    try:
        layers = tuple(Layer.of(s) for s in scene)
        session = open_any(p, layers=layers)
        name = source or session.sources[0]
        session.check_source(name)
        pts = session.video.pts_s
        step = max(1, int(round(every_s / max(float(np.median(np.diff(pts))), 1e-3))))
        records = list(frame_records(session, name, step))
        if not records:
            raise GeofuseError(f"{path}: no frame to index")
        for r in records:
            axis = _optical_axis(r.hpr)
            shape = plan_footprint(r.ground)
            result.rows.append(
                {
                    "clip": path,
                    "frame": r.index,
                    "clip_s": r.media_s,
                    "utc": None if r.utc_s is None else datetime.fromtimestamp(r.utc_s, UTC),
                    "sensor_lat": r.sensor[0],
                    "sensor_lon": r.sensor[1],
                    "sensor_h": r.sensor[2],
                    "heading_deg": r.hpr[0],
                    "pitch_deg": r.hpr[1],
                    "roll_deg": r.hpr[2],
                    "axis_e": float(axis[0]),
                    "axis_n": float(axis[1]),
                    "axis_u": float(axis[2]),
                    "hfov_deg": r.hfov_deg,
                    "centre_h": r.centre[2],
                    "geometry": None if shape is None else wkb.dumps(shape),
                }
            )
        g = session.gnss
        enu = session.frame.geodetic_to_enu(g.lat, g.lon, g.h)
        utc0 = session.utc_of(float(session.frame_times[0]))
        result.facts = {
            "camera": session.camera or "unknown",
            "lens": None if session.lens is None else session.lens.name,
            "source": name,
            "duration_s": float(pts[-1] - pts[0]),
            "utc_start": None if utc0 is None else datetime.fromtimestamp(utc0, UTC),
            "track_length_m": float(np.linalg.norm(np.diff(enu, axis=0), axis=1).sum()),
            "footprints": len(result.rows),
            "messages": "\n".join(m.text for m in session.messages.since(0)),
        }
    except (GeofuseError, ValueError, OSError) as exc:
        result.status, result.error, result.rows = "failed", str(exc), []
    except Exception as exc:  # a task boundary: one clip's failure never stops the others
        result.status, result.rows = "failed", []
        result.error = f"{path}: {type(exc).__name__}: {exc}"
    result.seconds = time.perf_counter() - started
    result.worker_peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return result
