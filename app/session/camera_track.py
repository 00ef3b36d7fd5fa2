"""The camera at any media time: the one owner of "where is the video's camera at time t, with
which lens, seen through which mount". Built once per session and source, it answers
`camera_at(t_media) -> Camera`; the viewer, `render`, `solve`, the accuracy report and the
benchmarks all ask it, so a pose for display is computed in one place.

Times: *media time* is a frame's presentation time in seconds from the video's first frame (what
the decoder hands over, app.io.video.media_seconds); *session time* is the session clock's
seconds. `FrameClock` maps one to the other through the frames' own session times (so the
paper's Eq. 5 timing and true frame times of a simulation map the same way), plus a live time
offset. World: local ENU metres; quaternions camera -> ENU, [w, x, y, z].
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from app.camera.fixes import FixStatus
from app.camera.frame_time import corrected_times
from app.camera.intrinsics import Intrinsics, Zoom
from app.camera.lens import Lens
from app.camera.pinhole import Camera
from app.camera.trajectory import PoseTrack, PositionTrack
from app.core.constants import DEFAULT_FAR_M, DEFAULT_NEAR_M
from app.geodesy import rotations
from app.session.model import TRUTH, Session, device_attitude

FloatArray = npt.NDArray[np.float64]


class Registration(Protocol):
    """What a `registered` track says of its keyframes, as its readers (the viewer's panels,
    `locate`'s error model, the CLI) use it. Its one maker is app.register.solve.Registration; the
    track types it by this Protocol so that the session sits below registration, which reads
    sessions and tracks (no import from here to app.register, at run time or for typing)."""

    prior: str  # the source the keyframes corrected
    keyframes: tuple[Any, ...]  # app.register.fuse.Keyframe, one a keyframe, in time order
    delay_s: float | None  # how late the frame times were (s), when estimated
    carried: Any  # app.register.inertial.Carried or None: each frame's position sigma (issue 52)

    def summary(self) -> str: ...


@dataclass(frozen=True)
class FrameClock:
    """Media time -> session time. media_s: (F,) each frame's presentation time (s from the first
    frame); session_s: (F,) the session time the pipeline gives that frame; offset_s, drift_ppm,
    pivot_s: a live correction on top (a sync's offset in seconds and clock drift in parts per
    million about session time pivot_s; app.camera.frame_time.corrected_times)."""

    media_s: FloatArray
    session_s: FloatArray
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    pivot_s: float = 0.0

    def session_time(self, t_media: npt.ArrayLike) -> FloatArray:
        """Session seconds at media times (any shape): interpolated between frames, extended at
        the ends with the first/last frame's offset between the two clocks."""
        t = np.asarray(t_media, np.float64)
        m, s = self.media_s, self.session_s
        inside = np.interp(t, m, s)
        before = s[0] + (t - m[0])
        after = s[-1] + (t - m[-1])
        base = np.where(t < m[0], before, np.where(t > m[-1], after, inside))
        return corrected_times(base, self.offset_s, self.drift_ppm, self.pivot_s)


@dataclass(frozen=True)
class FramePoses:
    """Camera poses at F times: index (F,) frame numbers; time_s (F,) session seconds; geodetic
    (F, 3) lat deg, lon deg, ellipsoidal height m; enu (F, 3) m; hpr (F, 3) heading, pitch, roll
    of the optical axis in degrees; q (F, 4) camera -> ENU."""

    index: npt.NDArray[np.int64]
    time_s: FloatArray
    geodetic: FloatArray
    enu: FloatArray
    hpr: FloatArray
    q: FloatArray
    gnss: npt.NDArray[np.str_] | None = None  # (F,) app.camera.fixes: used, rejected, missing

    def __len__(self) -> int:
        return len(self.time_s)


@dataclass(frozen=True)
class CameraTrack:
    """One session's video camera under one attitude source: pose track (position, attitude,
    device -> camera mount), frame clock, intrinsics and clipping planes (m)."""

    source: str
    poses: PoseTrack
    clock: FrameClock
    intrinsics: Intrinsics
    near: float = DEFAULT_NEAR_M
    far: float = DEFAULT_FAR_M
    lens: Lens | None = None  # intrinsics then enclose its image
    readout_s: float | None = None  # rolling shutter: first row to last, seconds (None: off)
    readout_axis: tuple[float, float, float] = (
        0.0,
        1.0,
        0.0,
    )  # where the sensor's rows run in the displayed image (readout_axis())
    registration: Registration | None = None  # the `registered` source: every keyframe's outcome
    zoom: Zoom | None = None  # a field of view per time: each camera's own (pinhole only)
    fixes: FixStatus | None = None  # which GNSS fixes the positions stand on (None: not GNSS)

    @property
    def frame_count(self) -> int:
        return len(self.clock.media_s)

    def with_offset(
        self, offset_s: float, drift_ppm: float = 0.0, pivot_s: float = 0.0
    ) -> CameraTrack:
        """The same track with another live time correction: offset (s), clock drift (ppm)
        about session time pivot_s."""
        clock = replace(
            self.clock, offset_s=float(offset_s), drift_ppm=float(drift_ppm), pivot_s=float(pivot_s)
        )
        return replace(self, clock=clock)

    def with_clip(self, near: float, far: float) -> CameraTrack:
        return replace(self, near=near, far=far)

    def camera_at(self, t_media: float) -> Camera:
        """The posed camera at one media time (seconds from the video's first frame)."""
        t = float(self.clock.session_time([float(t_media)])[0])
        enu, _, q = self.poses.at([t])
        turn = None
        if self.readout_s:
            _, _, qq = self.poses.at([t - self.readout_s / 2, t + self.readout_s / 2])
            turn = rotations.to_scipy(
                rotations.multiply(rotations.conjugate(qq[0]), qq[1])
            ).as_rotvec()
        intr = self.intrinsics
        if self.zoom is not None and self.lens is None:
            intr = self.zoom.intrinsics_at(intr, t)
        return Camera.create(
            intr, enu[0], q[0], self.near, self.far, self.lens, turn, self.readout_axis
        )

    def frame_camera(self, index: int) -> Camera:
        """The posed camera of video frame `index`."""
        return self.camera_at(float(self.clock.media_s[index]))

    def poses_at(self, t_media: npt.ArrayLike, index: npt.ArrayLike | None = None) -> FramePoses:
        """Poses at media times (M,); `index` labels them (default 0..M-1)."""
        t = self.clock.session_time(np.atleast_1d(np.asarray(t_media, np.float64)))
        enu, geo, q = self.poses.at(t)
        idx = np.arange(len(t)) if index is None else np.asarray(index, np.int64)
        gnss = None if self.fixes is None else self.fixes.at(t)
        return FramePoses(idx, t, geo, enu, rotations.hpr_from_camera_quat(q), q, gnss)

    def frame_poses(self, step: int = 1) -> FramePoses:
        """Poses of every `step`-th video frame."""
        idx = np.arange(0, self.frame_count, step)
        return self.poses_at(self.clock.media_s[idx], idx)


def frame_clock(session: Session, true_timing: bool = False) -> FrameClock:
    """The session's media -> session time map: the pipeline's frame times, or (true_timing) the
    simulation's true ones where the session has them."""
    times = (
        session.truth_frame_times
        if true_timing and session.truth_frame_times is not None
        else session.frame_times
    )
    return FrameClock(np.asarray(session.video.pts_s, np.float64), np.asarray(times, np.float64))


def pose_track(
    session: Session,
    source: str,
    course_pitch_deg: float | None = None,
    positions: PositionTrack | None = None,
) -> PoseTrack:
    """Positions and attitude of one source (for truth: true positions too, where known);
    positions: the track's instead of the session's GNSS (a cold start's, found on the scene)."""
    t_att, q = device_attitude(session, source, course_pitch_deg)
    if positions is None and source == TRUTH and session.truth_position is not None:
        g = session.truth_position
        positions = PositionTrack.from_fixes(g.t, g.lat, g.lon, g.h, g.vel_enu)
    elif positions is None:
        positions = session.positions()
    return PoseTrack(session.frame, positions, t_att, q, session.camera_mount())


def camera_track(
    session: Session,
    source: str,
    *,
    course_pitch_deg: float | None = None,
    true_timing: bool = False,
    time_offset_s: float = 0.0,
    positions: PositionTrack | None = None,
) -> CameraTrack:
    """Solve one source of a session into its camera track. ValueError for a source the session
    does not offer (naming those it does). positions: the track's positions instead of the
    session's GNSS (a cold start's: then no frame stands on a fix)."""
    clock = replace(frame_clock(session, true_timing), offset_s=float(time_offset_s))
    poses = pose_track(session, source, course_pitch_deg, positions)
    fixes = (
        None
        if source == TRUTH
        else FixStatus.all_used(poses.positions.t if positions is None else [])
    )
    return CameraTrack(
        source, poses, clock, session.intrinsics, lens=session.lens,
        readout_s=session.readout_s, readout_axis=readout_axis(session.rotation_cw), zoom=session.zoom,
        fixes=fixes,
    )  # fmt: skip


def readout_axis(rotation_cw: int) -> tuple[float, float, float]:
    """(a, b, c): the fraction of the sensor's readout at which the displayed pixel (u, v) of a
    W x H display was exposed is a u/W + b v/H + c. The sensor reads its stored rows top to
    bottom; the display turns the stored image by rotation_cw clockwise, which takes its top row
    to the right edge (90), the bottom (180) or the left edge (270)."""
    return {0: (0.0, 1.0, 0.0), 90: (-1.0, 0.0, 1.0), 180: (0.0, -1.0, 1.0), 270: (1.0, 0.0, 0.0)}[
        int(rotation_cw) % 360
    ]
