"""Manifest -> session -> poses, end to end on a simulated phone session with known truth."""

from __future__ import annotations

import csv
import shutil

import numpy as np
import pytest

from app.attitude.metrics import hpr_rms
from app.cli import main
from app.core.errors import ManifestError
from app.geodesy import rotations
from app.session import open_session
from app.simulate.phone import walking_pan
from app.solve.track import COLUMNS, solve_frames


@pytest.fixture(scope="module")
def session(session_dir):
    return open_session(session_dir / "session.toml")


def test_session_reads_everything(session):
    assert session.sources == [
        "gd-ahrs",
        "gd-imu",
        "cf-ahrs",
        "cf-imu",
        "offline",
        "registered",
        "truth",
    ]  # a grey scene: by geometry
    assert len(session.frame_times) == 600
    assert session.video.rotation_cw == 90
    assert (session.intrinsics.width, session.intrinsics.height) == (36, 64)  # portrait display
    assert session.declination_deg == pytest.approx(-5.6, abs=0.5)  # WMM near Zhengzhou, 2023
    assert [
        w
        for w in session.messages.items
        if not w.startswith(("magnetometer calibrated", "rolling shutter"))
    ] == []
    assert (
        "rolling shutter: readout time unknown (camera.readout_ms): not corrected"
        in session.messages.items
    )  # said, not silent
    offset = session.messages.items[0]
    assert "hard-iron offset" in offset  # the simulated phone has none: the fit must stay small


@pytest.mark.parametrize(
    "source, bound_deg", [("gd-ahrs", 1.0), ("cf-ahrs", 1.0), ("offline", 1.0)]
)
def test_solved_attitude_matches_the_truth(session, source, bound_deg):
    truth = solve_frames(session, "truth")
    rows = solve_frames(session, source)
    heading, pitch, roll, total = hpr_rms(rows.q, truth.q)
    assert total < bound_deg, (heading, pitch, roll, total)


def test_positions_follow_the_simulated_walk(session):
    rows = solve_frames(session, "truth")
    t = rows.time_s - 1_700_000_000.0
    expected = walking_pan().position(t)
    # 1 Hz fixes with exact velocities: the Hermite curve follows the horizontal path to a
    # millimetre; the 3 cm step bounce at 1.8 Hz is beyond what 1 Hz fixes can see.
    assert np.abs(rows.enu[:, :2] - expected[:, :2]).max() < 0.001
    assert np.abs(rows.enu[:, 2] - expected[:, 2]).max() < 0.07


def test_solve_cli_writes_one_row_per_frame(session_dir, tmp_path, capsys):
    out = tmp_path / "poses.csv"
    assert (
        main(["solve", str(session_dir / "session.toml"), "--source", "gd-ahrs", "--out", str(out)])
        == 0
    )
    with out.open() as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == COLUMNS and len(rows) == 601
    assert "600 frames" in capsys.readouterr().out


def test_imu_only_session_offers_imu_filters(session_dir, tmp_path, capsys):
    folder = tmp_path / "nomag"
    shutil.copytree(session_dir, folder)
    text = (folder / "session.toml").read_text().replace('mag = "mag.csv"\n', "")
    (folder / "session.toml").write_text(text)
    s = open_session(folder / "session.toml")
    assert s.sources == ["gd-imu", "cf-imu", "offline", "registered", "truth"]
    assert (
        main(
            [
                "solve",
                str(folder / "session.toml"),
                "--source",
                "gd-ahrs",
                "--out",
                str(tmp_path / "p.csv"),
            ]
        )
        == 2
    )
    assert (
        "this session offers gd-imu, cf-imu, offline, registered, truth" in capsys.readouterr().err
    )


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda t: t.replace('[video]\npath = "clip.mp4"', '[video]\npath = "missing.mp4"'),
            "field 'video.path': names 'missing.mp4', which does not exist",
        ),
        (
            lambda t: t.replace("[camera]\nhfov_deg = 60.0", '[camera]\nhfov_deg = "wide"'),
            "field 'camera.hfov_deg': got 'wide', expected float",
        ),
        (
            lambda t: t.replace("start_time = 1700000000.0", "start_time = 1600000000.0"),
            "field 'video.start_time': no video frame lies within the sensor log",
        ),
        (
            lambda t: t.replace("[gnss]\n", "[gnss_typo]\n"),
            "field 'gnss_typo': unknown table [gnss_typo]; did you mean 'gnss'?",
        ),
        (lambda t: t[: t.index("[gnss]")], "field 'gnss': missing section [gnss]"),
        (
            lambda t: t.replace("[gnss]\n", "[gnss]\naccuracy_m = 0\n"),
            "field 'gnss.accuracy_m': got 0.0, expected a finite number in [0.1, 1000]",
        ),
        (lambda t: t + "\n[[[", "not valid TOML"),
    ],
)
def test_manifest_errors_name_the_key(session_dir, tmp_path, capsys, edit, message):
    folder = tmp_path / "bad"
    shutil.copytree(session_dir, folder)
    manifest = folder / "session.toml"
    manifest.write_text(edit(manifest.read_text()))
    with pytest.raises(ManifestError) as err:
        open_session(manifest)
    assert message in str(err.value) and "session.toml" in str(err.value)
    assert main(["solve", str(manifest), "--out", str(tmp_path / "p.csv")]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_eq5_timing_fallback(session_dir, tmp_path):
    folder = tmp_path / "eq5"
    shutil.copytree(session_dir, folder)
    manifest = folder / "session.toml"
    manifest.write_text(
        manifest.read_text().replace('path = "clip.mp4"', 'path = "clip.mp4"\ntiming = "eq5"')
    )
    s = open_session(manifest)
    np.testing.assert_allclose(
        np.diff(s.frame_times), 1 / 30, atol=1e-6
    )  # float64 Unix seconds: 0.24 us steps


@pytest.mark.gl
def test_render_session_frame(session_dir, tmp_path, gl_ctx, capsys):
    """The frame at --time lands on the model: riding the video's own camera (--view-from its
    position, looking along its axis), the still shows the video frame wherever the model is
    behind it, so with the video opaque it differs from the model-only render over most of it."""
    from PIL import Image

    from app.camera.frame_time import frame_at
    from app.io.video import read_frame
    from app.session.camera_track import camera_track

    session = open_session(session_dir / "session.toml")
    k = frame_at(session.video.pts_s, 5.0)  # the frame on screen at 5 s, as the viewer shows it
    cam = camera_track(session, "gd-ahrs").frame_camera(k)
    ahead = np.asarray(cam.position) + 10.0 * rotations.rotate(cam.orientation, [0.0, 0.0, -1.0])
    w, h = session.intrinsics.width * 4, session.intrinsics.height * 4
    common = ["render", "--session", str(session_dir / "session.toml"), "--time", "5", "--source", "gd-ahrs", "--size", f"{w}x{h}", "--no-frustum",
              "--view-from=" + ",".join(f"{v:.4f}" for v in cam.position), "--look-at=" + ",".join(f"{v:.4f}" for v in ahead), "--view-fov", f"{session.intrinsics.hfov_deg:.6f}"]  # fmt: skip
    assert main([*common, "--out", str(tmp_path / "video.png")]) == 0
    assert f"frame {k} at" in capsys.readouterr().out
    assert main([*common, "--alpha", "0", "--out", str(tmp_path / "model.png")]) == 0
    video = np.asarray(Image.open(tmp_path / "video.png").convert("RGB"), int)
    model = np.asarray(Image.open(tmp_path / "model.png").convert("RGB"), int)
    frame = np.asarray(
        Image.fromarray(read_frame(session.video.path, k, session.video)).resize((w, h)), int
    )
    assert video.shape == model.shape == frame.shape
    on_model = np.abs(model - np.array([158, 189, 219])).max(axis=2) > 3  # not the background
    assert on_model.mean() > 0.3
    to_frame = np.abs(video - frame).max(axis=2)[on_model]
    # Seen from the projector itself, the projected video is the frame (filtering aside) ...
    assert np.median(to_frame) < 25
    # ... and not the bare model.
    assert np.median(np.abs(model - frame).max(axis=2)[on_model]) > np.median(to_frame) + 30


def test_solve_never_overwrites_an_input(session_dir, capsys):
    gyr = session_dir / "gyr.csv"
    before = gyr.read_bytes()
    assert main(["solve", str(session_dir / "session.toml"), "--out", str(gyr)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert gyr.read_bytes() == before
