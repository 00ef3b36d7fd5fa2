"""Registration against the scene (app/register): keyframes of the world-versus-model sample
recovered from a perturbed pose, a featureless view refused, the fused track smooth and better
than its prior, control points by hand, the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import cv2
import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens
from app.camera.pinhole import Camera
from app.camera.trajectory import PoseTrack, PositionTrack
from app.core.errors import DataFormatError
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.video import frames_at
from app.register.fuse import (
    Correction,
    FuseSettings,
    Keyframe,
    corrected_pose_track,
    estimate_delay,
    gate,
    retimed,
)
from app.register.keyframe import pose_from_cv, pose_to_cv, solve_pose
from app.register.points import (
    ControlPoints,
    corrected_track,
    read_points,
    solve_control,
    write_points,
)
from app.register.solve import (
    Registrar,
    Registration,
    RegistrationSettings,
    keyframe_indices,
    registered_track,
)
from app.scene.mesh import MeshData
from app.session import open_session
from app.session.camera_track import camera_track
from app.simulate import session as sample
from app.simulate.sample import SAMPLE_DIR
from app.solve.accuracy import true_track
from app.solve.track import solve_track
from tests.conftest import run_viewer
from tools import gis_sessions

ROOT = SAMPLE_DIR.parents[1]


def _true_camera(session, k: int) -> Camera:
    return true_track(session).frame_camera(k)


def _perturbed(cam: Camera, metres: float, degrees: float, seed: int) -> Camera:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=3)
    d[2] *= 0.3  # mostly horizontal, as a GNSS error
    axis = rng.normal(size=3)
    turn = rotations.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis))
    q = rotations.multiply(turn, np.asarray(cam.orientation))
    return Camera.create(
        cam.intrinsics,
        np.asarray(cam.position) + metres * d / np.linalg.norm(d),
        q,
        cam.near,
        cam.far,
        cam.lens,
    )


def _pose_error(cam: Camera, position, q) -> tuple[float, float]:
    return float(np.linalg.norm(np.asarray(position) - cam.position)), float(
        np.degrees(rotations.angle_between(q, cam.orientation))
    )


# --- pure: the pose solver on points worked out by hand -------------------------------------------


def test_opencv_pose_conversion_round_trips_and_maps_the_optical_axis():
    q = rotations.camera_quat_from_hpr(30.0, -10.0, 5.0)
    c = np.array([10.0, -20.0, 3.0])
    rvec, tvec = pose_to_cv(c, q)
    # A point 50 m along the optical axis sits on OpenCV's +z axis at depth 50.
    ahead = c + 50.0 * (rotations.to_matrix(q) @ np.array([0.0, 0.0, -1.0]))
    cam_pt = cv2.Rodrigues(rvec)[0] @ ahead + tvec
    assert np.allclose(cam_pt, [0.0, 0.0, 50.0], atol=1e-9)
    p2, q2 = pose_from_cv(rvec, tvec)
    assert np.allclose(p2, c, atol=1e-9) and rotations.angle_between(q, q2) < 1e-9


@pytest.mark.parametrize("lens", [None, "fisheye"])
def test_solve_pose_recovers_a_camera_from_exact_correspondences(lens):
    intr = Intrinsics.from_fov(640, 360, 70.0)
    real_lens = (
        Lens.create("fisheye", 640, 360, 300.0, 300.0, 321.0, 178.0, [0.05, -0.01, 0.002, 0.0])
        if lens
        else None
    )
    truth = Camera.create(
        intr, [3.0, -40.0, 1.6], rotations.camera_quat_from_hpr(10.0, 5.0, -2.0), lens=real_lens
    )
    rng = np.random.default_rng(1)
    uv = np.column_stack([rng.uniform(20, 620, 60), rng.uniform(20, 340, 60)])
    points = np.asarray(truth.position) + truth.pixel_rays(uv) * rng.uniform(20, 90, (60, 1))
    start = _perturbed(truth, 3.0, 2.0, seed=2)
    fix = solve_pose(start, points, uv)
    assert fix.ok and fix.inliers == 60 and fix.error_px < 1e-3
    metres, degrees = _pose_error(truth, fix.position, fix.q)
    assert metres < 1e-4 and degrees < 1e-4


# --- GL: keyframes of the world-versus-model sample ----------------------------------------------


@pytest.fixture(scope="module")
def sample_session():
    return open_session(SAMPLE_DIR / "session.toml")


@pytest.mark.gl
def test_keyframes_recover_a_pose_perturbed_by_3_m_and_2_degrees(sample_session, gl_ctx):
    """The video is rendered from a world that differs from the model (app/simulate/world.py);
    from the true pose moved 3 m and turned 2 deg, render-and-compare finds it again."""
    frames = [91, 661, 1740, 2191]
    registrar = Registrar(sample_session, RegistrationSettings(), gl_ctx)
    try:
        for k, rgb in frames_at(sample_session.video, frames, registrar.settings.long_side):
            truth = _true_camera(sample_session, k)
            start = _perturbed(truth, 3.0, 2.0, seed=k)
            assert _pose_error(truth, start.position, start.orientation)[0] > 2.9
            fix, solved, renders = registrar.keyframe(rgb, start)
            assert solved is not None, f"frame {k}: {fix.reason}"
            metres, degrees = _pose_error(truth, solved.position, solved.orientation)
            assert metres < 0.3 and degrees < 0.3, (
                f"frame {k}: {metres:.2f} m, {degrees:.2f} deg after {renders} renderings"
            )
            assert fix.inliers >= 15 and fix.error_px < 2.5
    finally:
        registrar.release()


@pytest.mark.gl
def test_a_featureless_view_is_refused_with_the_reason(sample_session, gl_ctx):
    """A frame that shows nothing (a blank wall filling the lens, fog) does not register, and
    says why."""
    registrar = Registrar(sample_session, RegistrationSettings(), gl_ctx)
    try:
        start = _true_camera(sample_session, 661)
        blank = np.full((360, 640, 3), 128, np.uint8)
        fix, solved, _ = registrar.keyframe(blank, start)
        assert solved is None and not fix.ok
        assert "matches" in fix.reason
    finally:
        registrar.release()


def test_an_assumed_flat_ground_has_nothing_to_register_against(sample_session):
    flat = replace(sample_session, layers=())
    assert "registered" not in flat.sources
    with pytest.raises(ValueError, match="assumed flat ground"):
        flat.check_source("registered")


# --- pure: fusion ---------------------------------------------------------------------------------


def _keyframe(i: int, t: float, dp, dr_deg, used: bool = True) -> Keyframe:
    q0 = rotations.camera_quat_from_hpr(0.0, 0.0, 0.0)
    q = rotations.multiply(rotations.from_rotvec(np.radians(dr_deg)), q0)
    p0 = np.array([0.0, 0.0, 1.5])
    return Keyframe(i, t, used, "", 50, 40, 0.8, 2, p0, q0, p0 + np.asarray(dp, float), q)


def test_a_keyframe_that_disagrees_with_its_neighbours_is_not_used():
    kfs = [_keyframe(i, float(i), [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]) for i in range(8)]
    kfs[4] = _keyframe(4, 4.0, [2.0, 0.0, 0.0], [0.0, 0.0, 6.0])  # 5 deg off the others
    gated = gate(kfs, FuseSettings())
    assert [k.used for k in gated] == [True] * 4 + [False] + [True] * 3
    assert "disagrees with its" in gated[4].reason and "5.00 deg" in gated[4].reason


def test_a_prior_that_swerves_or_drags_keeps_keyframes_on_the_flights_path():
    """Keyframes every 0.5 s registered on a flight's curve (the weave: 9 m/s east, swinging
    north): where the prior swerves 10 m off for 3 s (a multipath burst) the corrections swerve
    with it and disagree with their neighbours' median, but the registered positions lie on the
    path the others fly, so they are used; where it walks off at 2 m/s to the clip's end (a
    drag no IMU screened) they lie on their neighbours' line. A false match 5 m off the path,
    its prior like its neighbours', is still set aside."""
    t = np.arange(0.0, 12.0, 0.5)
    path = np.column_stack([9.0 * t, 14.0 * np.sin(2 * np.pi * t / 12.0), np.full(len(t), 35.0)])
    q = rotations.camera_quat_from_hpr(90.0, -25.0, 0.0)
    burst = np.where((t >= 4.0) & (t < 7.0), 10.0, 0.0)[:, None] * [0.6, 0.8, 0.0]

    def keyframes(prior: np.ndarray, position: np.ndarray) -> list[Keyframe]:
        return [Keyframe(i, float(t[i]), True, "", 50, 40, 0.8, 2, prior[i], q, position[i], q) for i in range(len(t))]  # fmt: skip

    assert all(k.used for k in gate(keyframes(path + burst, path), FuseSettings()))
    drag = np.clip(t - 8.0, 0.0, None)[:, None] * [2.0, 0.0, 0.0]
    assert all(k.used for k in gate(keyframes(path + drag, path), FuseSettings()))
    false = path.copy()
    false[10] += [0.0, 5.0, 0.0]
    gated = gate(keyframes(path, false), FuseSettings())
    assert [k.index for k in gated if not k.used] == [10] and "5.00 m" in gated[10].reason


def test_a_keyframe_no_registered_neighbour_confirms_is_not_used():
    """A fit alone is not trusted: one with no registered keyframe within window_s (4 s) is set
    aside; two that agree confirm each other; two that disagree are both set aside."""
    alone = [_keyframe(0, 0.0, [6.0, 0.0, 0.0], [0.0, 0.0, 3.0])]
    alone += [_keyframe(i, float(i), [0.0] * 3, [0.0] * 3, used=False) for i in range(1, 9)]
    alone.append(_keyframe(9, 9.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.5]))  # 9 s from the other
    gated = gate(alone, FuseSettings())
    assert not gated[0].used and not gated[9].used
    assert gated[0].reason == "no other keyframe within 4 s registered to confirm it"
    assert Correction.from_keyframes(gated).t.size == 0  # the prior stands
    pair = [
        _keyframe(0, 0.0, [2.0, 0.0, 0.0], [0.0] * 3),
        _keyframe(1, 3.5, [2.5, 0.0, 0.0], [0.0] * 3),
    ]
    assert [k.used for k in gate(pair, FuseSettings())] == [True, True]  # 0.5 m apart
    pair[1] = _keyframe(1, 3.5, [5.0, 0.0, 0.0], [0.0] * 3)  # 3 m apart: which is right?
    split = gate(pair, FuseSettings())
    assert [k.used for k in split] == [False, False]
    assert split[0].reason == "disagrees with its only neighbour by 3.00 m, 0.00 deg"


def test_a_registration_that_used_no_keyframe_says_the_prior_stands_and_what_can_correct_it():
    refused = [
        replace(_keyframe(i, float(i), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], used=False), reason=why)
        for i, why in enumerate(["the model's lines in view leave the pose unfixed (0.9 m, 2.7 deg a pixel)"] * 3 + ["edge distance 3.1 px (at most 2.5)"])
    ]  # fmt: skip
    line = Registration("offline", tuple(refused), {}).summary()
    assert line.startswith(
        "registered 0 of 4 keyframes (0 %) against the scene, correcting offline"
    )
    assert "4 not used (most often: the model's lines in view leave the pose unfixed)" in line
    assert "the track is offline's" in line and "--points" in line
    some = Registration(
        "offline", (refused[0], _keyframe(9, 9.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0])), {}
    )
    assert "the track is" not in some.summary() and "registered 1 of 2" in some.summary()
    assert "searched for" not in some.summary()
    lost = replace(some, searched=((20.0, 34.5, True), (24.0, 38.0, False), (28.0, 42.0, False)))
    assert "; lost with no fix to trust, searched for 3 times within 42 m, found again 1" in (
        lost.summary()
    )


def test_corrections_are_continuous_and_fall_back_to_the_prior_far_from_keyframes():
    kfs = [_keyframe(i, 10.0 + i, [3.0, -1.0, 0.0], [0.0, 0.0, 2.0]) for i in range(5)]
    c = Correction.from_keyframes(kfs, FuseSettings(hold_s=30.0))
    dp, dr = c(np.array([12.0, 12.5, 14.0, 44.0, 214.0]))
    assert np.allclose(
        dp[:3], [3.0, -1.0, 0.0], atol=1e-9
    )  # the same correction everywhere: smoothing keeps it
    assert np.allclose(np.degrees(dr[:3, 2]), 2.0, atol=1e-9)
    assert np.allclose(
        dp[3], np.array([3.0, -1.0, 0.0]) * np.exp(-1.0)
    )  # 30 s past the last: e^-1 of it
    assert np.linalg.norm(dp[4]) < 0.1
    empty = Correction.from_keyframes([replace(k, used=False) for k in kfs])
    assert np.all(empty(np.linspace(0, 20, 9))[0] == 0.0)


def test_corrections_follow_an_error_that_moves_within_a_second_without_a_kink():
    """The prior's error moves within a second (GNSS between its 1 Hz fixes, a drone's attitude):
    keyframes two a second whose corrections swing 0.6 m over a 2 s period are followed, not
    averaged away (a 1 s smoothing left 1 % of the swing: docs/ACCURACY.md); between keyframes
    the correction stays within its neighbours' values, its rate is continuous across a
    keyframe (no kink in the track), and it comes to rest at the last keyframe, where the held
    value takes over."""
    t = 10.0 + 0.5 * np.arange(12)
    swing = 0.6 * np.sin(2 * np.pi * (t - 10.0) / 2.0 + 0.3)
    kfs = [
        _keyframe(i, ti, [x, 0.0, 0.0], [0.0, 0.0, 0.0])
        for i, (ti, x) in enumerate(zip(t, swing, strict=True))
    ]
    c = Correction.from_keyframes(kfs)
    dp, _ = c(t)
    assert np.allclose(dp[:, 0], swing, atol=0.01 * 0.6)
    fine = np.arange(t[0], t[-1], 0.01)
    x = c(fine)[0][:, 0]
    for i in range(len(t) - 1):
        inside = x[(fine >= t[i]) & (fine <= t[i + 1])]
        lo, hi = sorted(swing[i : i + 2])
        assert lo - 1e-9 <= inside.min() and inside.max() <= hi + 1e-9
    h = 1e-4
    for ti in t[1:-1]:
        left = (c(ti)[0][0, 0] - c(ti - h)[0][0, 0]) / h
        right = (c(ti + h)[0][0, 0] - c(ti)[0][0, 0]) / h
        assert abs(left - right) < 0.01, (ti, left, right)
    end = (c(t[-1])[0][0, 0] - c(t[-1] - h)[0][0, 0]) / h
    assert abs(end) < 0.01


def test_keyframes_fall_every_spacing_and_on_the_last_frame_where_the_video_ends_well_after():
    """Every every_s from the first frame; the last frame too where the video runs on more than
    half a spacing after the last of those (an 8 s clip at 30 fps, keyframes every 0.5 s: 7.5 s
    and its last frame, 7.97 s), not where it ends within half a spacing (7.2 s: 7.0 s is the
    last)."""
    media_s = np.arange(240) / 30.0
    got = keyframe_indices(media_s, 0.5)
    assert list(got) == [*range(0, 240, 15), 239]
    assert list(keyframe_indices(media_s[:217], 0.5)) == list(range(0, 217, 15))
    assert list(keyframe_indices(media_s, 4.0)) == [0, 120, 239]


# --- the whole source on a short world-versus-model session ---------------------------------------


@pytest.fixture(scope="module")
def short_session(short_walk):
    return open_session(short_walk)  # conftest's 6 s walk, simulated once for the session


@pytest.mark.gl
def test_the_registered_track_is_smooth_and_beats_its_prior(short_session, gl_ctx):
    fractions = []
    track = registered_track(
        short_session, settings=RegistrationSettings(), progress=fractions.append, ctx=gl_ctx
    )
    reg = track.registration
    assert track.source == "registered" and reg.prior == "offline"
    # every 0.5 s from 0 to 5.5 s, and the last frame (5.97 s): 13
    assert fractions[-1] == 1.0 and len(reg.keyframes) == 13
    assert reg.used_fraction >= 0.75, reg.summary()
    assert reg.delay_s == pytest.approx(
        sample.SYNC_ERROR_S, abs=0.02
    )  # the manifest's start is 80 ms late
    prior = camera_track(short_session, "offline")
    truth = true_track(short_session)
    frames = np.arange(0, track.frame_count)
    ours, before, true = (
        track.poses_at(track.clock.media_s[frames]),
        prior.poses_at(prior.clock.media_s[frames]),
        truth.frame_poses(),
    )
    err = np.linalg.norm(ours.enu - true.enu, axis=1)
    assert np.median(err) < 0.5 < 2.0 < np.median(np.linalg.norm(before.enu - true.enu, axis=1))
    # No jump: no frame-to-frame step longer than the prior's own (GNSS) or the true walk's, and
    # no kink: the step changes from one frame to the next by no more than the walk's does + 5 mm.
    step = np.linalg.norm(np.diff(ours.enu, axis=0), axis=1)
    limit = max(
        np.linalg.norm(np.diff(true.enu, axis=0), axis=1).max(),
        np.linalg.norm(np.diff(before.enu, axis=0), axis=1).max(),
    )
    assert step.max() <= limit
    kink = np.linalg.norm(np.diff(ours.enu, 2, axis=0), axis=1)
    assert kink.max() < np.linalg.norm(np.diff(true.enu, 2, axis=0), axis=1).max() + 0.005
    turn = np.degrees(rotations.angle_between(ours.q[1:], ours.q[:-1]))
    true_turn = np.degrees(rotations.angle_between(true.q[1:], true.q[:-1]))
    assert turn.max() < true_turn.max() + 0.1


# --- control points by hand -----------------------------------------------------------------------


def _control_case(session, boresight_deg=(0.8, -1.1, 0.5), offset=(2.0, -1.5, 0.4), noise_px=0.3):
    """Pairs seen by a camera whose mount is off by a known boresight and whose positions are off
    by a known offset, against the session's true track."""
    track = camera_track(session, "truth")
    b = rotations.from_rotvec(np.radians(boresight_deg))
    rng = np.random.default_rng(4)
    frames, pixels, points = [], [], []
    for k in (10, 60, 120, 170):
        cam = track.frame_camera(k)
        real = replace(
            cam,
            position=tuple(np.asarray(cam.position) + offset),
            orientation=tuple(rotations.multiply(np.asarray(cam.orientation), b)),
        )
        uv = np.column_stack([rng.uniform(40, 600, 3), rng.uniform(40, 320, 3)])
        x = np.asarray(real.position) + real.pixel_rays(uv) * rng.uniform(25, 80, (3, 1))
        frames += [k] * 3
        pixels.append(uv + rng.normal(0, noise_px, uv.shape))
        points.append(session.frame.enu_to_geodetic(x))
    return track, b, ControlPoints(np.array(frames), np.concatenate(pixels), np.concatenate(points))


def test_control_points_recover_a_known_boresight_within_0_2_degrees(short_session, tmp_path):
    track, b, pts = _control_case(short_session)
    path = write_points(tmp_path / "pairs.csv", pts)
    sol = solve_control(track, read_points(path))
    assert np.degrees(rotations.angle_between(sol.boresight, b)) < 0.2
    assert np.allclose(sol.offset_m, [2.0, -1.5, 0.4], atol=0.3)
    assert np.median(sol.residual_px) < 1.0 < np.median(sol.before_px)
    fixed = corrected_track(track, sol).frame_camera(60)
    want = track.frame_camera(60)
    turned = rotations.multiply(np.asarray(want.orientation), b)
    assert np.degrees(rotations.angle_between(fixed.orientation, turned)) < 0.2


def test_bad_control_point_files_name_the_line_and_field(tmp_path):
    p = tmp_path / "pairs.csv"
    p.write_text("frame,x,y,latitude,longitude\n1,2,3,4,5\n")
    with pytest.raises(DataFormatError, match="missing columns height"):
        read_points(p)
    p.write_text(
        "frame,x,y,latitude,longitude,height\n"
        + "1,2,3,34.8,113.5,100\n" * 3
        + "4,nan,3,34.8,113.5,100\n"
    )
    with pytest.raises(DataFormatError, match=r"pairs.csv:5 field 'x'.*not a finite number"):
        read_points(p)
    p.write_text("frame,x,y,latitude,longitude,height\n1,2,3,34.8,113.5,100\n")
    with pytest.raises(DataFormatError, match="need at least 4 pairs"):
        read_points(p)


def test_register_cli_solves_and_keeps_the_points_beside_the_input(short_session, tmp_path):
    _, b, pts = _control_case(short_session)
    path = write_points(tmp_path / "pairs.csv", pts)
    manifest = short_session.path
    before = manifest.read_bytes()
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "app",
            "register",
            str(manifest),
            "--points",
            str(path),
            "--source",
            "truth",
            "--write",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert run.returncode == 0, run.stderr
    assert "12 control points against truth" in run.stdout and "boresight" in run.stdout
    kept = manifest.with_name(manifest.stem + ".control.csv")
    assert kept.is_file() and np.allclose(read_points(kept).pixel, pts.pixel, atol=0.01)
    assert manifest.read_bytes() == before
    kept.unlink()


@pytest.mark.gl
def test_solve_offers_the_registered_source_and_says_how_much_registered(short_session, tmp_path):
    out = tmp_path / "poses.csv"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "app",
            "solve",
            str(short_session.path),
            "--source",
            "registered",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert run.returncode == 0, run.stderr
    assert (
        "registered" in run.stderr
        and "keyframes" in run.stderr
        and "against the scene" in run.stderr
    )
    rows = out.read_text().splitlines()
    assert len(rows) == 1 + len(short_session.frame_times)
    direct = solve_track(short_session, "offline").frame_poses()
    assert direct.enu.shape[0] == len(rows) - 1


CONTROL_PICKS = ["0.30,0.50", "0.62,0.42", "0.48,0.62", "0.72,0.58"]  # X,Y in the 3D view


@pytest.fixture(scope="module")
def viewer_run(short_session, display, tmp_path_factory):
    """One viewer launch on the short session for the two viewer tests below, each checking
    its own part: nobody asks for `registered`, and once it is solved in the background the
    viewer shows it (shot.png, registered.json); then the offline source is chosen and four
    control pairs are picked in the window and solved (control.json). The manifest's bytes
    before the launch are kept to check it was never written."""
    d = tmp_path_factory.mktemp("viewer")
    lines = [
        "0 clock 0.05",
        "0 wait registered",
        f"0.2 screenshot {d / 'shot.png'}",
        f"0.2 state {d / 'registered.json'}",
        "0.3 source offline",
        "0.3 panels off",
        "0.3 seek 2",
        "0.3 view phone",
    ]
    for xy in CONTROL_PICKS:
        lines += [f"0.4 control video {xy}", f"0.4 control model {xy}"]
    lines += ["0.5 control solve", f"0.6 state {d / 'control.json'}", "0.7 quit"]
    script = d / "script.txt"
    script.write_text("\n".join(lines) + "\n")
    before = short_session.path.read_bytes()
    result = run_viewer(
        display, str(short_session.path), "--script", str(script), "--size", "800x450"
    )
    assert result.returncode == 0, result.stderr[-3000:]
    yield d, before
    # the session's manifest is shared (conftest): no control points left for later registrations
    short_session.path.with_name(short_session.path.stem + ".control.csv").unlink(missing_ok=True)


@pytest.mark.gl
def test_the_viewer_registers_in_the_background_and_shows_the_registered_source(
    short_session, viewer_run
):
    """Nobody asks for `registered`: once solved in the background the viewer shows it, and says
    so among the notes."""
    d, _ = viewer_run
    s = json.loads((d / "registered.json").read_text())
    assert s["source"] == "registered" and "registered" in s["solved"] and s["errors"] == []
    assert any(n.startswith("registered is solved: showing it instead of") for n in s["info"])
    reg = s["registration"]
    assert reg["prior"] == "offline" and reg["keyframes"] == 13 and reg["used"] >= 10
    assert reg["summary"].startswith(f"registered {reg['used']} of 13 keyframes")
    # The projector is the registered track's camera at the frame shown.
    track = solve_track(short_session, "offline")
    assert (
        np.linalg.norm(
            np.subtract(s["projector"]["position"], track.frame_camera(s["frame"]).position)
        )
        > 0.5
    )


@pytest.mark.gl
@pytest.mark.parametrize("kind", ["tiles", "terrain"])
def test_keyframes_register_against_3d_tiles_and_a_dem_with_an_orthophoto(kind, tmp_path, gl_ctx):
    """The same world-versus-model video against the stadium as a 3D Tiles tileset (with a
    generated city beside it), and against a DEM with an orthophoto under the model."""
    session = open_session(getattr(gis_sessions, kind)(tmp_path))
    registrar = Registrar(session, RegistrationSettings(), gl_ctx)
    try:
        for k, rgb in frames_at(session.video, [661, 2191], registrar.settings.long_side):
            truth = _true_camera(session, k)
            fix, solved, _ = registrar.keyframe(rgb, _perturbed(truth, 3.0, 2.0, seed=k))
            assert solved is not None, f"{kind} frame {k}: {fix.reason}"
            metres, degrees = _pose_error(truth, solved.position, solved.orientation)
            assert metres < 0.3 and degrees < 0.3, (
                f"{kind} frame {k}: {metres:.2f} m, {degrees:.2f} deg"
            )
    finally:
        registrar.release()


@pytest.mark.gl
def test_a_scene_without_texture_is_registered_by_its_geometry(sample_session, gl_ctx):
    """The grey model offers `registered`, by its lines (app.register.edges), the textured one
    by its textures."""
    grey = replace(
        sample_session,
        mesh=MeshData(
            [replace(p, texture=None, uvs=None) for p in sample_session.scene().primitives]
        ),
    )
    assert "registered" in grey.sources and "registered" in sample_session.sources
    grey.check_source("registered")
    for session, geometry in ((grey, True), (sample_session, False)):
        registrar = Registrar(session, ctx=gl_ctx)
        try:
            assert registrar.settings.by_geometry is geometry
        finally:
            registrar.release()


@pytest.mark.gl
def test_control_points_picked_in_the_viewer_are_solved_and_kept_beside_the_input(
    short_session, viewer_run
):
    """Four pairs picked in the window (a video pick, then a model pick) under the offline
    source: each video pick is the pixel the projector drapes at that place, the solve reports
    residuals, and the points go into NAME.control.csv beside the manifest (never into it)."""
    d, before = viewer_run
    s = json.loads((d / "control.json").read_text())
    c = s["control"]
    assert s["source"] == "offline"
    assert s["errors"] == [] and len(c["pairs"]) == len(CONTROL_PICKS) and not c["pending"]
    # Each video pick is where the shown pose projects the model point under the cursor.
    projector = solve_track(short_session, "offline").frame_camera(s["frame"])
    for pair in c["pairs"]:
        uv, _ = projector.project(np.array([pair["enu"]]))
        assert np.allclose(uv[0], pair["pixel"], atol=0.05)
    # Picked on the same pose, the pairs agree with it: nothing to correct.
    assert (
        max(c["residual_px"]) < 0.5
        and c["boresight_deg"] < 0.05
        and np.linalg.norm(c["offset_m"]) < 0.05
    )
    kept = short_session.path.with_name(short_session.path.stem + ".control.csv")
    assert c["saved"] == str(kept) and len(read_points(kept)) == 4
    assert short_session.path.read_bytes() == before
    kept.unlink()


def test_the_frame_times_offset_is_found_from_the_keyframes():
    """Keyframes of a camera that sways (1.3 Hz) and pans, registered at the moments the frames
    show, while the pipeline placed the frames 80 ms late, under a slowly drifting heading bias:
    the offset comes back from the fast part of the corrections, and the corrected track then
    shows each frame's true pose."""
    frame = LocalFrame(34.8, 113.53, 110.0)
    t = np.arange(0.0, 40.0, 0.01)

    def attitude(tt):
        heading = 20.0 * np.sin(2 * np.pi * tt / 17.0) + 3.0 * np.sin(2 * np.pi * 1.3 * tt)
        return rotations.camera_quat_from_hpr(heading, 2.0 * np.sin(2 * np.pi * 0.9 * tt), 0.0 * tt)

    geo = frame.enu_to_geodetic(np.column_stack([1.4 * t, 0 * t, 1.5 + 0 * t]))
    prior = PoseTrack(
        frame,
        PositionTrack.from_fixes(t, geo[:, 0], geo[:, 1], geo[:, 2]),
        t,
        attitude(t),
        np.array([1.0, 0, 0, 0]),
    )
    late = 0.08
    kfs = []
    for i, tk in enumerate(np.arange(1.0, 39.0, 0.5)):
        bias = rotations.from_rotvec([0.0, 0.0, np.radians(1.5 + 0.5 * np.sin(tk / 10.0))])
        q_true = attitude(np.array([tk - late]))[0]
        enu, _, q_prior = prior.at(np.array([tk]))
        kfs.append(
            Keyframe(
                i,
                float(tk),
                True,
                "",
                50,
                40,
                0.8,
                2,
                enu[0],
                q_prior[0],
                enu[0] + [0.5, -2.0, 0.0],
                rotations.multiply(bias, q_true),
            )
        )
    delay = estimate_delay(kfs, prior)
    assert delay == pytest.approx(late, abs=0.005)
    fixed = corrected_pose_track(
        prior, Correction.from_keyframes(retimed(kfs, prior, delay)), delay
    )
    _, _, q = fixed.at(np.array([20.0]))
    want = rotations.multiply(
        rotations.from_rotvec([0.0, 0.0, np.radians(1.5 + 0.5 * np.sin(2.0))]),
        attitude(np.array([20.0 - late]))[0],
    )
    assert np.degrees(rotations.angle_between(q[0], want)) < 0.05


@pytest.mark.gl
def test_a_view_down_on_retaken_textures_aligns_densely(sample_session, gl_ctx):
    """From 70 m straight down on the sample site, the frame is the model seen from the true
    pose with its textures taken again (another exposure and gamma, blurred, noisy); from 3 m
    and 1 deg off, the dense alignment (`align`), rendered again at each pose it finds, reaches
    the pose within 0.3 m and 0.3 deg in three steps. A street-level view, too deep to be one
    plane, is refused, saying so."""
    from app.geodesy import rotations as rot
    from app.register.keyframe import Frame, MatchSettings, Rendering, align
    from app.render.views import ModelViews

    views = ModelViews(sample_session.scene(), gl_ctx)
    try:
        intr = Intrinsics.from_fov(640, 360, 70.0)
        eye = np.array([15.0, -25.0, 70.0])
        down = rot.camera_quat_from_hpr(np.array([20.0]), np.array([-90.0]), np.array([0.0]))[0]
        truth = Camera.create(intr, eye, down, far=500.0)
        seen, _ = views.render(truth)
        rng = np.random.default_rng(7)
        retaken = 255.0 * (seen.astype(np.float64) / 255.0) ** 0.8 * 1.15 + rng.normal(
            0, 6, seen.shape
        )
        frame_rgb = cv2.GaussianBlur(np.clip(retaken, 0, 255).astype(np.uint8), (0, 0), 1.0)
        cam = _perturbed(truth, 3.0, 1.0, seed=3)
        for _ in range(3):  # as the keyframe loop does: render at the pose found, align again
            rgb, positions = views.render(cam)
            fix = align(MatchSettings(), Frame(frame_rgb, 1.0, cam), Rendering(rgb, positions, cam))
            assert fix.ok, fix.reason
            cam = Camera.create(intr, fix.position, fix.q, far=500.0)
        metres, degrees = _pose_error(truth, fix.position, fix.q)
        assert metres < 0.3 and degrees < 0.3, (metres, degrees)
        street = _true_camera(sample_session, 661).pinhole(0.5)
        rgb, positions = views.render(street)
        fix = align(MatchSettings(), Frame(rgb, 1.0, street), Rendering(rgb, positions, street))
        assert not fix.ok and "too deep" in fix.reason
    finally:
        views.release()
