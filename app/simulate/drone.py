"""A simulated DJI drone clip over the sample site: an MP4 rendered by the project's renderer and
the per-frame subtitle (.SRT, the Air 2S / Mini layout: no gimbal angles) a DJI aircraft writes
beside it, with the subtitle's positions lagging the video by a known time.

The flight (ENU metres about the site origin): 35 m above the ground, eastward at 9 m/s along the
stadium's south side, weaving +-40 deg about east with a 12 s period; the camera looks along the
direction of travel, pitched 25 deg down, as a drone flown forward with its gimbal fixed. Its
field of view is that of the 24 mm (35 mm equivalent) focal length the subtitle states, so a
session opened from the clip has the camera's true pinhole. Used by the tests and `geofuse bench
sync` (the GNSS lag found from the course)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.misb import camera_set
from app.scene import load_scene
from app.simulate.sample import SAMPLE_DIR
from app.simulate.stadium import SITE_ORIGIN
from app.simulate.video import render_video

SPEED_MPS = 9.0
WEAVE_DEG = 40.0
WEAVE_PERIOD_S = 12.0
HEIGHT_M = 35.0
PITCH_DEG = -25.0
FOCAL_35MM = 24.0
HFOV_DEG = float(np.degrees(2 * np.arctan(18.0 / FOCAL_35MM)))  # 73.7 deg
FPS = 30.0
START = datetime(2025, 11, 15, 9, 46, 40, tzinfo=UTC)


def flight(
    t: np.ndarray, period_s: float = WEAVE_PERIOD_S, weave_deg: float = WEAVE_DEG
) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3) ENU m, headings (N,) deg from north) at times t (N,) s; period_s and
    weave_deg: the weave's period and its swing either side of east."""
    t = np.asarray(t, np.float64)
    w = 2 * np.pi / period_s
    north_speed = SPEED_MPS * np.tan(np.radians(weave_deg)) * np.cos(w * t)
    pos = np.column_stack(
        [
            -110.0 + SPEED_MPS * t,
            -95.0 + SPEED_MPS * np.tan(np.radians(weave_deg)) * np.sin(w * t) / w,
            np.full(len(t), HEIGHT_M),
        ]
    )
    return pos, np.degrees(np.arctan2(SPEED_MPS, north_speed)) % 360.0


def write_video(
    path: Path,
    duration_s: float = 24.0,
    size: tuple[int, int] = (320, 180),
    crf: int = 20,
    path_of=flight,
    klv: Sequence[tuple[float, bytes]] = (),
) -> Path:
    """The drone's video: the sample scene seen from the flight (path_of(t) -> positions,
    headings, as `flight`), at FPS, width x height pixels; klv: (time s, payload) packets beside
    it (a .ts: a drone's downlink)."""

    t = np.arange(0.0, duration_s, 1.0 / FPS)
    pos, heading = path_of(t)
    q = rotations.camera_quat_from_hpr(heading, np.full(len(t), PITCH_DEG), np.zeros(len(t)))
    mesh = load_scene(SAMPLE_DIR / "scene.glb", LocalFrame(*SITE_ORIGIN))
    return render_video(
        path, mesh, Intrinsics.from_fov(*size, HFOV_DEG), pos, q, t, crf=crf, klv=klv
    )


def klv_sets(
    duration_s: float, placed_until_s: float = math.inf, ground_h_m: float | None = None
) -> list[tuple[float, bytes]]:
    """The weave's MISB ST 0601 Local Sets, one per frame (time s, payload): the camera's
    position, angles and field of view (app.io.misb.camera_set), from placed_until_s on without
    its latitude and longitude (a platform without a fix, its angles and height going on);
    ground_h_m: the frame centre's ellipsoidal height while placed."""
    frame = LocalFrame(*SITE_ORIGIN)
    out = []
    for t in np.arange(0.0, duration_s, 1.0 / FPS):
        pos, heading = flight(np.array([t]))
        geodetic = tuple(float(v) for v in frame.enu_to_geodetic(pos)[0])
        hpr = (float(heading[0]), PITCH_DEG, 0.0)
        utc = START.timestamp() + t
        payload = camera_set(utc, geodetic, hpr, HFOV_DEG, ground_h_m, t < placed_until_s)
        out.append((float(t), payload))
    return out


def srt_text(
    duration_s: float,
    lag_s: float,
    path_of=flight,
    fixed: bool = True,
    gimbal: bool = False,
    outage: tuple[float, float] | None = None,
) -> str:
    """The subtitle of the clip: one entry per frame, each carrying the position `lag_s` seconds
    older than its frame (the GNSS track lags the video), in DJI's 6 decimals; heights above
    take-off (rel_alt) and above the ellipsoid (abs_alt). fixed=False: every position 0, 0 as
    DJI writes it without a fix (abs_alt 0; rel_alt, from the barometer, kept); gimbal: the
    camera's angles as the Mini 3 / Mavic 3 layout adds them (gb_yaw, gb_pitch, gb_roll, deg);
    outage: (from, until) s of the clip whose entries have no fix (0, 0, as fixed=False)."""
    frame = LocalFrame(*SITE_ORIGIN)
    t = np.arange(0.0, duration_s, 1.0 / FPS)
    pos, _ = path_of(t - lag_s)
    geo = frame.enu_to_geodetic(pos)
    if not fixed:
        geo[:, :] = 0.0
    if outage is not None:
        geo[(t >= outage[0]) & (t < outage[1])] = 0.0
    _, heading = path_of(t)

    def stamp(s: float) -> str:
        ms = int(round(s * 1000))
        return f"{ms // 3600000:02d}:{ms // 60000 % 60:02d}:{ms // 1000 % 60:02d},{ms % 1000:03d}"

    out = []
    for k, tk in enumerate(t):
        when = START + timedelta(seconds=float(tk))
        out.append(
            f'{k + 1}\n{stamp(tk)} --> {stamp(tk + 1.0 / FPS)}\n<font size="28">SrtCnt : {k + 1}, DiffTime : 33ms\n'
            f"{when:%Y-%m-%d %H:%M:%S},{when.microsecond // 1000:03d},{when.microsecond % 1000:03d}\n"
            f"[iso : 100] [shutter : 1/1000.0] [fnum : 280] [ev : 0] [ct : 5500] [color_md : default] [focal_len : {FOCAL_35MM * 10:.0f}] "
            f"[latitude: {geo[k, 0]:.6f}] [longitude: {geo[k, 1]:.6f}] [rel_alt: {pos[k, 2]:.3f} abs_alt: {geo[k, 2]:.3f}] "
            + (
                f"[gb_yaw: {heading[k]:.1f} gb_pitch: {PITCH_DEG:.1f} gb_roll: 0.0] "
                if gimbal
                else ""
            )
            + "</font>\n"
        )
    return "\n".join(out)


def straight(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A flight due east at SPEED_MPS without a turn (the course says nothing of time)."""
    t = np.asarray(t, np.float64)
    return np.column_stack(
        [-110.0 + SPEED_MPS * t, np.full(len(t), -95.0), np.full(len(t), HEIGHT_M)]
    ), np.full(len(t), 90.0)
