"""`geofuse solve`: one CSV row per video frame with the camera's pose at the frame's time."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from app.camera.fixes import outage_said
from app.core.outputs import CSV_SUFFIXES, check_output, write_atomically
from app.core.progress import ProgressBar
from app.register import registered_track
from app.session.camera_track import CameraTrack, FramePoses, camera_track
from app.session.model import REGISTERED, Session

COLUMNS = (
    "frame",
    "time_s",
    "latitude",
    "longitude",
    "height",
    "E",
    "N",
    "U",
    "heading",
    "pitch",
    "roll",
    "qw",
    "qx",
    "qy",
    "qz",
    "gnss",
)
PROGRESS_MIN_SAMPLES = 100_000


def solve_track(
    session: Session,
    source: str,
    progress: Callable[[float], None] | None = None,
    stop: Callable[[], bool] | None = None,
    background: bool = False,
    **options: object,
) -> CameraTrack:
    """One source of a session solved into its camera track: the one entry point for every
    command and the viewer's solver. The `registered` source renders the scene (app.register);
    the others are app.session.camera_track.camera_track (options: course_pitch_deg, true_timing,
    time_offset_s). progress(fraction) is called where solving takes long (registration), and
    there stop() is asked between steps: True cancels (app.register.solve.Cancelled);
    background: solved beside a playing viewer, at a lower priority."""
    if source == REGISTERED:
        track = registered_track(
            session, progress=progress, stop=stop, background=background, **options
        )
    else:
        track = camera_track(session, source, **options)
    say_outages(session, track)
    return track


def say_outages(session: Session, track: CameraTrack) -> None:
    """Each stretch of the video with no GNSS fix (app.camera.fixes.FixStatus.outages) said once
    in the session's messages, in clip time, with what carries the track through it."""
    if track.fixes is None or len(session.frame_times) == 0:
        return
    t0, t1 = float(session.frame_times[0]), float(session.frame_times[-1])
    carried = (
        "the registered keyframes carry the track"
        if track.registration is not None
        else "positions there run straight between the fixes around it"
    )
    if getattr(getattr(track.registration, "carried", None), "felt", False):
        carried = "the registered keyframes and the IMU's motion carry the track"
    for a, b in track.fixes.outages(t0, t1):
        session.messages.add_once(f"gnss-outage-{a:.1f}", f"{outage_said(a, b, t0)}: {carried}")


def solve_frames(session: Session, source: str) -> FramePoses:
    """The camera's pose at every video frame under one source (app.session.camera_track.FramePoses):
    time in session seconds; lat/lon deg, height m ellipsoidal; ENU m; heading/pitch/roll of the
    optical axis in degrees; camera -> ENU quaternion."""
    return solve_track(session, source).frame_poses()


def csv_rows(poses: FramePoses):
    """FramePoses as text rows in COLUMNS order (fixed precision per column; gnss: what posed the
    frame, app.camera.fixes: used, rejected, missing; empty where the track is not GNSS's)."""
    for i in range(len(poses)):
        yield [
            int(poses.index[i]), f"{poses.time_s[i]:.6f}", f"{poses.geodetic[i, 0]:.9f}", f"{poses.geodetic[i, 1]:.9f}",
            *(f"{v:.4f}" for v in (poses.geodetic[i, 2], *poses.enu[i], *poses.hpr[i])), *(f"{v:.8f}" for v in poses.q[i]),
            "" if poses.gnss is None else str(poses.gnss[i]),
        ]  # fmt: skip


def solve_to_csv(
    session: Session, source: str, out: str | Path, progress: TextIO | None = None
) -> int:
    """Write the rows of `solve_frames` to `out` (never to an input file: checked before solving);
    returns the row count."""
    out = check_output(
        out,
        "--out",
        CSV_SUFFIXES,
        list(session.inputs) + [session.path, session.video.path, session.gnss.path],
    )
    long_input = session.gyr is not None and len(session.gyr.t) >= PROGRESS_MIN_SAMPLES
    bar = ProgressBar(f"solving {source}", progress if long_input or source == REGISTERED else None)
    bar(0.0)
    track = solve_track(session, source, progress=bar)
    poses = track.frame_poses()
    bar(1.0)
    if track.registration is not None and progress is not None:
        print(track.registration.summary(), file=progress)

    def write(f) -> None:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(csv_rows(poses))

    write_atomically(out, "--out", write)
    return len(poses)
