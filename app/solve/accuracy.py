"""Accuracy of a session's poses against its truth: attitude RMS per source (the paper's Table 2)
and the projection error in metres on the model (paper section 3, measured there by hand).

For every Nth frame and a grid of image pixels, the model point a pixel lands on under the
estimated pose is compared with the one under the true pose. Errors are split by what causes
them, swapping one input at a time for the truth: attitude, position, frame time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from app.attitude.filters import estimate, resample
from app.attitude.metrics import hpr_rms
from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import VIEW_FAR_M, VIEW_NEAR_M
from app.geodesy import rotations
from app.render.probe import SurfaceProbe
from app.session import Session
from app.session.camera_track import CameraTrack, camera_track, frame_clock
from app.solve.track import solve_track

EDGE_FRACTION = 0.1  # the outer 10 % of columns on each side count as the image's edges


@dataclass(frozen=True)
class Poses:
    """Camera poses at the analysed frames: ENU (F, 3) m and camera -> ENU quaternions (F, 4)."""

    enu: np.ndarray
    q: np.ndarray


@dataclass(frozen=True)
class Stats:
    """Projection error in metres: median and 95th percentile at the centre column and the edges."""

    centre_median: float
    centre_p95: float
    edge_median: float
    edge_p95: float


def true_frame_times(session: Session) -> np.ndarray:
    if session.truth_frame_times is None:
        raise ValueError("the session has no [truth] frame_times")
    return session.truth_frame_times


def true_track(session: Session) -> CameraTrack:
    """The session's true camera track on the frames' true clock (the moments the frames show,
    not the file's late timestamps): the reference every figure here is measured against."""
    return replace(camera_track(session, "truth"), clock=frame_clock(session, true_timing=True))


def poses_at(track: CameraTrack, frames: np.ndarray) -> Poses:
    """The track's camera poses at video frames `frames` (on the track's own frame clock)."""
    p = track.poses_at(track.clock.media_s[frames], frames)
    return Poses(p.enu, p.q)


def paper_track(session: Session) -> tuple[Callable[[np.ndarray], Poses], np.ndarray]:
    """The paper's pipeline: gradient descent AHRS without declination, Euler angles interpolated
    linearly between attitude samples (not quaternions), frame times from Eq. 5."""
    t = session.gyr.t
    acc = resample(t, session.acc.t, session.acc.values)
    mag = resample(t, session.mag.t, session.mag.values)
    q_dev = estimate(t, session.gyr.values, acc, mag, method="gd")
    q_cam = rotations.multiply(q_dev, session.camera_mount())
    hpr = rotations.hpr_from_camera_quat(q_cam)
    positions = session.positions()
    eq5 = session.frame_times[0] + session.video.eq5_times()

    def at(times: np.ndarray) -> Poses:
        h, p, r = resample(times, t, hpr).T  # Euler angles, linearly: the paper's way
        geo = positions.geodetic_at(times)
        return Poses(
            session.frame.geodetic_to_enu(geo[:, 0], geo[:, 1], geo[:, 2]),
            rotations.camera_quat_from_hpr(h, p, r),
        )

    return at, eq5


def attitude_rms(est: Poses, truth: Poses) -> tuple[float, float, float, float]:
    """Heading, pitch, roll RMS and total-angle RMS (deg) of the optical axis."""
    return hpr_rms(est.q, truth.q)


def split_stats(errors: np.ndarray, columns: np.ndarray, width: int) -> Stats:
    """Stats of per-pixel errors (m) by image column: centre = the middle column(s), edges = the
    outer EDGE_FRACTION on each side. NaN (a pixel on the sky under either pose) is left out."""
    centre = np.abs(columns + 0.5 - width / 2) <= 0.5
    edge = (columns < EDGE_FRACTION * width) | (columns >= (1 - EDGE_FRACTION) * width)

    def q(mask: np.ndarray, p: float) -> float:
        v = errors[mask & np.isfinite(errors)]
        return float(np.percentile(v, p)) if len(v) else float("nan")

    return Stats(q(centre, 50), q(centre, 95), q(edge, 50), q(edge, 95))


class ProjectionProbe:
    """Model points seen at a grid of image pixels (app.render.probe.SurfaceProbe)."""

    def __init__(self, session: Session, grid: tuple[int, int]) -> None:

        self.intrinsics: Intrinsics = session.intrinsics.scaled(*grid)
        self.surface = SurfaceProbe(session.scene())

    def points(self, enu: np.ndarray, q: np.ndarray) -> np.ndarray:
        return self.surface.points(
            Camera.create(self.intrinsics, enu, q, near=VIEW_NEAR_M, far=VIEW_FAR_M)
        )

    def errors(self, est: Poses, truth: Poses) -> tuple[np.ndarray, np.ndarray]:
        """(per-pixel distances (m), their column indices) over all frames."""
        dist, cols = [], []
        for k in range(len(est.enu)):
            a = self.points(est.enu[k], est.q[k])
            b = self.points(truth.enu[k], truth.q[k])
            d = np.linalg.norm(a - b, axis=2)
            dist.append(d.ravel())
            cols.append(np.tile(np.arange(d.shape[1]), d.shape[0]))
        return np.concatenate(dist), np.concatenate(cols)

    def release(self) -> None:
        self.surface.release()


@dataclass(frozen=True)
class SourceReport:
    name: str
    attitude: tuple[float, float, float, float]
    total: Stats
    by_cause: dict[str, Stats]


def evaluate(
    session: Session,
    sources: list[str],
    every: int = 10,
    grid: tuple[int, int] = (64, 36),
    paper: bool = True,
    progress: Callable[[float], None] | None = None,
    solved: dict[str, CameraTrack] | None = None,
) -> list[SourceReport]:
    """Attitude RMS and projection error for each source (and the paper's pipeline);
    progress(fraction) after each source solved and each measured (a long run on a terminal);
    solved: tracks of some sources already solved (by name), not solved again."""
    steps = 2 * len(sources) + (1 if paper and session.mag is not None else 0)
    done = [0]

    def step() -> None:
        done[0] += 1
        if progress is not None:
            progress(done[0] / steps)

    t_true = true_frame_times(session)
    pipeline_clock = frame_clock(session)
    frames = np.arange(0, len(t_true), every)
    truth_track = true_track(session)
    truth = poses_at(truth_track, frames)
    # Every source is solved before the probe's GL context exists: registration makes its own.
    # A source may correct the frame times itself (registered: its track is delay_s later), so
    # its pose at a frame's true time is found delay_s later on its own time axis.
    entries: list[tuple[str, Callable[[np.ndarray], Poses], np.ndarray, float]] = []
    for name in sources:
        track = (solved or {}).get(name) or solve_track(session, name)
        delay = (track.registration.delay_s or 0.0) if track.registration is not None else 0.0
        step()
        entries.append(
            (
                name,
                lambda tt, tr=track.poses: Poses(*tr.at(tt)[::2]),
                pipeline_clock.session_s[frames],
                delay,
            )
        )
    if paper and session.mag is not None:
        at, eq5 = paper_track(session)
        entries.append(("paper pipeline", at, eq5[frames], 0.0))
    probe = ProjectionProbe(session, grid)
    reports = []
    try:
        for name, at, pipeline_times, delay in entries:
            est = at(pipeline_times)  # what the pipeline shows for each frame
            est_true_time = at(
                t_true[frames] + delay
            )  # its attitude and position, at the right time
            by_cause = {
                "attitude": Poses(truth.enu, est_true_time.q),
                "position": Poses(est_true_time.enu, truth.q),
                "time": poses_at(
                    replace(truth_track, clock=replace(pipeline_clock, offset_s=-delay)), frames
                ),
            }
            total = split_stats(*probe.errors(est, truth), grid[0])
            causes = {k: split_stats(*probe.errors(v, truth), grid[0]) for k, v in by_cause.items()}
            reports.append(SourceReport(name, attitude_rms(est_true_time, truth), total, causes))
            step()
    finally:
        probe.release()
    return reports
