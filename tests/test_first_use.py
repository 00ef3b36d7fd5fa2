"""What a new user trips on (issue 20): misspelt manifest keys, impossible fields of view, a start
time filled in silently, absurd gyroscope rates, a sync kept at no confidence, a screenshot of a
session that did not open."""

from __future__ import annotations

import io
import re
import shutil

import numpy as np
import pytest

from app.cli import main
from app.core.errors import ManifestError, SceneError
from app.core.progress import ProgressBar
from app.geodesy.enu import LocalFrame
from app.scene import load_scene
from app.session import open_session, read_config
from tests.conftest import run_viewer


@pytest.fixture(scope="module")
def walk_dir(short_walk):
    """The sample walk's first 6 s (conftest's, simulated once; the tests edit copies of it): a
    rendered video with a creation time, a real gyroscope."""
    return short_walk.parent


def _copy(session_dir, tmp_path, edit) -> str:
    folder = tmp_path / "copy"
    shutil.copytree(session_dir, folder)
    manifest = folder / "session.toml"
    manifest.write_text(edit(manifest.read_text()))
    return manifest


def test_a_misspelt_key_is_named_with_the_key_meant(session_dir, tmp_path):
    manifest = _copy(session_dir, tmp_path, lambda t: t.replace("hfov_deg =", "hfov ="))
    with pytest.raises(
        ManifestError, match=r"field 'camera.hfov': unknown key; did you mean 'hfov_deg'\?"
    ):
        read_config(manifest)
    (tmp_path / "copy").rename(tmp_path / "first")
    manifest = _copy(session_dir, tmp_path, lambda t: t.replace("[camera]", "[camra]"))
    with pytest.raises(ManifestError, match=r"unknown table \[camra\]; did you mean 'camera'\?"):
        read_config(manifest)


def test_a_field_of_view_no_camera_has_is_refused(session_dir, tmp_path, capsys):
    manifest = _copy(
        session_dir, tmp_path, lambda t: t.replace("hfov_deg = 60.0", "hfov_deg = 1e-300")
    )
    with pytest.raises(ManifestError, match=r"camera.hfov_deg.*\[0.01, 179\]"):
        read_config(manifest)
    assert main(["render", "--fov", "1e-300", "--out", str(tmp_path / "x.png")]) == 2
    assert "--fov" in capsys.readouterr().err


def test_a_start_time_filled_in_from_the_file_says_so(walk_dir, tmp_path):
    manifest = _copy(walk_dir, tmp_path, lambda t: re.sub(r"start_time = [0-9.]+ .*\n", "", t))
    s = open_session(manifest)
    assert any("video.start_time not given" in w and "creation time" in w for w in s.messages.items)


def test_gyroscope_rates_no_sensor_reads_are_dropped_and_counted(session_dir, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(session_dir, folder)
    gyr = folder / "gyr.csv"
    lines = gyr.read_text().splitlines()
    t = lines[50].split(",")[0]
    lines[50] = f"{t},1e300,0,0"
    lines[51] = f"{lines[51].split(',')[0]},-1e300,1e300,0"
    gyr.write_text("\n".join(lines) + "\n")
    s = open_session(folder / "session.toml")
    assert any("2 gyr samples beyond 70 rad/s" in w for w in s.messages.items)
    assert np.all(np.linalg.norm(s.gyr.values, axis=1) < 70.0)
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
        == 0
    )


def test_sync_refuses_to_keep_an_offset_it_has_no_confidence_in(walk_dir, tmp_path, capsys):
    """The video against a gyroscope that recorded something else (noise): the offset found means
    nothing, so --write refuses (exit 1, the reason) unless --force."""
    folder = tmp_path / "copy"
    shutil.copytree(walk_dir, folder)
    gyr = folder / "gyr.csv"
    rows = np.loadtxt(gyr, delimiter=",", skiprows=1)
    rows[:, 1:] = np.random.default_rng(3).normal(0.0, 0.6, (len(rows), 3))
    np.savetxt(gyr, rows, delimiter=",", header="t,x,y,z", comments="", fmt="%.6f")
    manifest = folder / "session.toml"
    kept = folder / "session.geofuse.toml"
    assert main(["sync", str(manifest), "--write"]) == 1
    out = capsys.readouterr()
    assert "not written: confidence" in out.err and "--force" in out.err and not kept.exists()
    assert main(["sync", str(manifest), "--write", "--force"]) == 0
    assert kept.is_file()


@pytest.mark.gl
def test_a_screenshot_of_a_session_that_did_not_open_exits_non_zero(session_dir, tmp_path, display):
    manifest = _copy(
        session_dir, tmp_path, lambda t: t.replace('path = "clip.mp4"', 'path = "gone.mp4"')
    )
    shot = tmp_path / "shot.png"
    result = run_viewer(display, str(manifest), "--screenshot", str(shot), "--play", "0.2")
    assert result.returncode == 1
    assert "did not open" in result.stderr and shot.is_file()


@pytest.mark.parametrize(
    ("vertices", "message"),
    [
        ("v 0 0 0\nv nan 0 0\nv 0 1 0\n", "1 vertices are not finite"),
        ("v 0 0 0\nv 1e30 0 0\nv 0 1 0\n", "lie 1e\\+30 units from the origin"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\n", "every face of the scene is degenerate"),
    ],
)
def test_a_model_with_broken_geometry_is_refused_with_the_reason(tmp_path, vertices, message):
    obj = tmp_path / "broken.obj"
    obj.write_text(vertices + "f 1 2 3\n")
    with pytest.raises(SceneError, match=f"broken.obj: .*{message}"):
        load_scene(obj, LocalFrame(34.8, 113.53, 110.0))


def test_degenerate_faces_are_dropped_and_the_rest_drawn(tmp_path):
    obj = tmp_path / "mixed.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    mesh = load_scene(obj, LocalFrame(34.8, 113.53, 110.0))
    assert mesh.triangle_count == 1


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_progress_bars_are_drawn_on_a_terminal_only():
    """A redirected log gets no bar redrawn at every percent; a terminal does."""
    for tty in (True, False):
        out = _Stream(tty)
        bar = ProgressBar("solving", out, clock=iter(range(100)).__next__)
        for f in np.linspace(0.0, 1.0, 11):
            bar(f)
        assert ("100.0%" in out.getvalue()) is tty
        assert (out.getvalue() == "") is not tty


@pytest.mark.gl
def test_the_no_display_demo_drapes_a_frame_of_the_walk_video(tmp_path, capsys):
    out = tmp_path / "demo.png"
    assert main(["demo", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "frame 600 at 19.997 s" in said and out.is_file()


def test_a_video_ffmpeg_cannot_read_names_the_manifest_and_the_key(session_dir, tmp_path, capsys):
    manifest = _copy(session_dir, tmp_path, lambda t: t)
    (manifest.parent / "clip.mp4").write_bytes(b"not a video at all")
    with pytest.raises(ManifestError) as err:
        open_session(manifest)
    text = str(err.value)
    assert (
        "session.toml field 'video.path': clip.mp4: not a video FFmpeg can read (Invalid data found"
        in text
    )
    assert "Errno" not in text
    assert main(["solve", str(manifest), "--out", str(tmp_path / "p.csv")]) == 2
    assert "field 'video.path'" in capsys.readouterr().err
