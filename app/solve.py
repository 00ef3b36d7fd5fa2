"""`geofuse solve`: one CSV row per video frame with the camera's pose at the frame's time."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import TextIO

import numpy as np

from app import rotations
from app.errors import refuse_overwriting_inputs
from app.session import Session, pose_track

COLUMNS = ("frame", "time_s", "latitude", "longitude", "height", "E", "N", "U", "heading", "pitch", "roll", "qw", "qx", "qy", "qz")
PROGRESS_MIN_SAMPLES = 100_000


def _bar(out: TextIO | None, label: str, fraction: float) -> None:
    if out is not None:
        filled = int(30 * fraction)
        out.write(f"\r{label:<28} [{'#' * filled}{'.' * (30 - filled)}] {100 * fraction:5.1f}%")
        if fraction >= 1.0:
            out.write("\n")
        out.flush()


def solve_frames(session: Session, source: str) -> np.ndarray:
    """(F, 15) rows in COLUMNS order: time in session seconds; lat/lon deg, height m ellipsoidal;
    ENU m; heading/pitch/roll of the optical axis in degrees; camera -> ENU quaternion."""
    track = pose_track(session, source)
    enu, geo, q = track.at(session.frame_times)
    hpr = rotations.hpr_from_camera_quat(q)
    idx = np.arange(len(session.frame_times))
    return np.column_stack([idx, session.frame_times, geo, enu, hpr, q])


def solve_to_csv(session: Session, source: str, out: str | Path, progress: TextIO | None = None) -> int:
    """Write the rows of `solve_frames` to `out` (never to an input file: checked before solving);
    returns the row count."""
    out = Path(out)
    refuse_overwriting_inputs(out, [session.manifest.path, session.video.path, session.gnss.source] + [s.source for s in (session.gyr, session.acc, session.mag) if s is not None])
    long_input = session.gyr is not None and len(session.gyr.t) >= PROGRESS_MIN_SAMPLES
    bar = progress if long_input else None
    _bar(bar, f"solving {source}", 0.0)
    rows = solve_frames(session, source)
    _bar(bar, f"solving {source}", 1.0)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([int(r[0]), f"{r[1]:.6f}", f"{r[2]:.9f}", f"{r[3]:.9f}", *(f"{v:.4f}" for v in r[4:11]), *(f"{v:.8f}" for v in r[11:])])
    return len(rows)
