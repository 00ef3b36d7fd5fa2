"""Clips opened with no manifest (DJI video + SRT made here from a real sample's entries), and the
telemetry inspector on every real SRT and GPX."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

from app.cli import main
from tests.conftest import run_viewer

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def dji_clip(shared_data, tmp_path_factory):
    """A 10 s H.264 clip with P4 RTK subtitle entries (gimbal attitude included) beside it, named
    in another letter case, as DJI cameras write them."""
    from app.simulate.phone import write_video

    folder = tmp_path_factory.mktemp("dji")
    video = write_video(folder / "DJI_0001.MP4", np.arange(300) / 30.0, (96, 54), 0)
    entries = (
        (shared_data / "real" / "dji" / "p4_rtk.SRT")
        .read_text(encoding="utf-8")
        .strip()
        .split("\n\n")[:10]
    )
    (folder / "dji_0001.srt").write_text("\n\n".join(entries) + "\n", encoding="utf-8")
    return video


def test_dji_clip_solves_from_gimbal_telemetry(dji_clip, tmp_path, capsys):
    out = tmp_path / "poses.csv"
    assert main(["solve", str(dji_clip), "--out", str(out)]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 300
    assert "attitude from telemetry" in capsys.readouterr().out
    # G.PRY of the first entries: pitch -24.4, roll 0.0, yaw 110.x
    first = rows[0]
    assert float(first["pitch"]) == pytest.approx(-24.4, abs=0.05)
    assert 105 < float(first["heading"]) < 116
    # Heights are above take-off: the camera flies ~85.8 m over the assumed ground.
    assert float(first["U"]) == pytest.approx(85.8, abs=0.5)


def test_dji_clip_without_attitude_uses_the_course(shared_data, tmp_path, capsys):
    from app.simulate.phone import write_video

    video = write_video(tmp_path / "clip.mp4", np.arange(150) / 30.0, (96, 54), 0)
    (tmp_path / "clip.SRT").write_text(
        (shared_data / "real" / "dji" / "p4p_sample.SRT").read_text()
    )
    out = tmp_path / "p.csv"
    assert main(["solve", str(video), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "heading from the track" in err and "pitch -30 deg assumed" in err
    with out.open() as f:
        assert float(next(csv.DictReader(f))["pitch"]) == pytest.approx(-30.0, abs=0.01)


def _dji_clip_naming(folder, shared_data, items):
    from app.simulate.mp4meta import add_user_data
    from app.simulate.phone import write_video

    folder.mkdir(exist_ok=True)
    video = add_user_data(
        write_video(folder / "DJI_0002.MP4", np.arange(60) / 30.0, (192, 108), 0), items
    )
    entries = (
        (shared_data / "real" / "dji" / "mavic_air2.srt")
        .read_text(encoding="utf-8")
        .strip()
        .split("\n\n")[:120]
    )
    (folder / "DJI_0002.SRT").write_text("\n\n".join(entries) + "\n", encoding="utf-8")
    return video


def test_a_dji_clip_gets_the_lens_profile_of_the_camera_its_mp4_names(
    shared_data, tmp_path, capsys
):
    """The subtitle names no aircraft; the MP4's camera code (FC3170: a Mavic Air 2) chooses the
    profile, which is said with its reason, scaled to the video, and brings its readout time;
    --lens overrides it; a file naming no camera, or an unknown one, is said to get a pinhole."""
    from app.camera.lens import read_profile
    from app.footage.clips import open_clip
    from app.simulate.mp4meta import intl_text

    video = _dji_clip_naming(
        tmp_path / "a", shared_data, {"\xa9mdl": b"FC3170", "\xa9too": intl_text("DJIMavicAir2")}
    )
    s = open_clip(video)
    said = [w for w in s.messages.items if w.startswith("lens: ")]
    assert len(said) == 1 and "DJI Mavic Air 2 (camera code FC3170 in the MP4)" in said[0], (
        s.messages.items
    )
    profile = next(
        p for p in (shared_data / "lens_profiles" / "DJI").glob("*.json") if p.stem in said[0]
    )
    want = read_profile(profile).scaled(192, 108)
    assert (
        s.lens.kind == want.kind
        and s.lens.coeffs == want.coeffs
        and s.lens.fx == pytest.approx(want.fx)
    )
    said = (
        "from the lens profile" if want.readout_s else "readout time unknown"
    )  # most DJI profiles have none
    assert s.readout_s == want.readout_s and any(said in w for w in s.messages.items)
    assert s.intrinsics.hfov_deg > want.hfov_deg  # the depth pass encloses the undistorted image

    other = next((shared_data / "lens_profiles" / "GoPro").glob("*1920x1080*.json"))
    assert open_clip(video, lens=other).lens.name == read_profile(other).name
    assert open_clip(video, hfov_deg=80.0).lens is None

    anonymous = open_clip(_dji_clip_naming(tmp_path / "b", shared_data, {}))
    assert anonymous.lens is None and any(
        "names no DJI camera" in w and "pinhole of" in w for w in anonymous.messages.items
    )
    unknown = open_clip(_dji_clip_naming(tmp_path / "c", shared_data, {"\xa9mdl": b"FC9999"}))
    assert unknown.lens is None and any(
        "FC9999 is not one geofuse knows" in w for w in unknown.messages.items
    )

    assert main(["solve", str(video), "--out", str(tmp_path / "p.csv")]) == 0
    assert "DJI Mavic Air 2 (camera code FC3170 in the MP4)" in capsys.readouterr().err
    assert (
        main(["telemetry", str(video)]) == 2
    )  # its telemetry is in the subtitle: said, naming the camera
    assert "DJI Mavic Air 2" in capsys.readouterr().err


def test_srt_that_does_not_fit_the_video(shared_data, tmp_path, capsys):
    from app.simulate.phone import write_video

    video = write_video(tmp_path / "short.mp4", np.arange(30) / 30.0, (96, 54), 0)  # 1 s of video
    (tmp_path / "short.srt").write_text(
        (shared_data / "real" / "dji" / "mavic_pro.SRT").read_text()
    )  # 468 s
    assert main(["solve", str(video), "--out", str(tmp_path / "p.csv")]) == 2
    assert "is it the subtitle of another clip" in capsys.readouterr().err


def test_view_a_dji_clip_screenshot(dji_clip, display, tmp_path):
    """The viewer opens a DJI clip straight away: the projector rides the gimbal telemetry, 85.8 m
    above the assumed ground (the subtitle's height above take-off), at the frame due."""
    import json

    from app.footage.clips import open_clip
    from app.session.camera_track import camera_track

    out, state = tmp_path / "dji.png", tmp_path / "dji.json"
    script = tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0 play\n1.5 screenshot {out}\n1.5 state {state}\n1.6 quit\n"
    )
    result = run_viewer(display, str(dji_clip), "--script", str(script), "--size", "640x360")
    assert result.returncode == 0, result.stderr[-2000:]
    s = json.loads(state.read_text())
    assert s["source"] == "telemetry" and s["frame"] == s["due_frame"] == 45 and s["errors"] == []
    expected = camera_track(open_clip(dji_clip), "telemetry").frame_camera(45)
    np.testing.assert_allclose(s["projector"]["position"], expected.position, atol=1e-6)
    assert s["projector"]["position"][2] == pytest.approx(85.8, abs=0.2)
    img = np.asarray(Image.open(out).convert("RGB"), int)
    x, y, w, h = s["view_rect"]
    assert img.shape == (360, 640, 3) and img[y : y + h, x : x + w].std() > 15


SRT_ROWS = {
    "air2s.srt": 17,
    "mavic_air2.srt": 25,
    "matrice_300.srt": 381,
    "mavic_pro.SRT": 468,
    "p4_rtk.SRT": 55,
    "p4p_sample.SRT": 5,
    "broken_incomplete.SRT": 19,
}
GPX_ROWS = {
    "around-visnjan-with-car.gpx": 104,
    "cerknicko-jezero.gpx": 296,
    "gpx1.0_with_all_fields.gpx": 1,
    "track-with-empty-segment.gpx": 9,
    "track_with_speed.gpx": 3,
}


@pytest.mark.parametrize("name", sorted(SRT_ROWS) + sorted(GPX_ROWS))
def test_telemetry_csv_rows(shared_data, tmp_path, name):
    folder = shared_data / "real" / ("dji" if name in SRT_ROWS else "gpx")
    out = tmp_path / "track.csv"
    assert main(["telemetry", str(folder / name), "--csv", str(out)]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == {**SRT_ROWS, **GPX_ROWS}[name]
    assert list(rows[0])[:4] == ["time_s", "latitude", "longitude", "height"]
    assert float(rows[0]["time_s"]) >= 0.0
    if name == "p4_rtk.SRT":
        assert "gimbal_yaw" in rows[0] and float(rows[-1]["gimbal_yaw"]) == pytest.approx(111.9)
        assert (float(rows[-1]["latitude"]), float(rows[-1]["longitude"])) == pytest.approx(
            (-34.232349, -58.849196)
        )


@pytest.mark.parametrize(
    "folder, name, message",
    [
        ("dji", "broken_empty.SRT", "empty subtitle file"),
        ("gpx", "cerknicko-without-times.gpx", "has no <time>"),
        ("gpx", "Mojstrovka.gpx", "broken logger clock"),
    ],
)
def test_telemetry_bad_files_exit_2(shared_data, capsys, folder, name, message):
    assert main(["telemetry", str(shared_data / "real" / folder / name)]) == 2
    err = capsys.readouterr().err
    assert name in err and message in err and "Traceback" not in err


def test_manifest_naming_gopro_telemetry(shared_data, tmp_path):
    from app.session import open_session
    from app.session.camera_track import camera_track

    clip = shared_data / "real" / "gopro" / "max-heromode.mp4"
    scene = tmp_path / "ground.obj"
    scene.write_text(
        "v -500 -500 -2\nv 500 -500 -2\nv 500 500 -2\nv -500 500 -2\nf 1 2 3\nf 1 3 4\n"
    )
    manifest = tmp_path / "walk.toml"
    manifest.write_text(
        f'[origin]\nlat = 33.1268\nlon = -117.3273\nh = -21.0\n\n[scene]\npath = "{scene}"\norigin = [33.1268, -117.3273, -21.0]\n\n'
        f'[video]\npath = "{clip}"\nstart_time = 1000.0\n\n[camera]\nhfov_deg = 92.0\n\n[sensors]\nformat = "gopro"\n'
    )
    s = open_session(manifest)
    assert (
        s.heading_from_course
        and s.heading_note.startswith("heading from the GNSS course")
        and s.device_is_camera
    )
    assert s.gyr.t[0] > 1000.0 and s.gnss.t[0] > 1000.0  # clip seconds moved onto the session clock
    assert "camera" in s.sources and "gd-imu" in s.sources
    assert np.all(np.isfinite(camera_track(s, "camera").frame_camera(0).position))


def test_manifest_naming_a_dji_subtitle_takes_off_from_the_scene(dji_clip, tmp_path):
    """Heights above take-off + the scene's ground under the first position (20 m here)."""
    from app.geodesy.enu import LocalFrame
    from app.session import open_session
    from app.solve.track import solve_frames

    lat, lon = -34.237922, -58.851745  # the first P4 RTK position
    frame = LocalFrame(lat, lon, 20.0)
    scene = tmp_path / "flat.obj"
    corners = frame.enu_to_ecef(
        np.array([[-2000, -2000, 0], [2000, -2000, 0], [2000, 2000, 0], [-2000, 2000, 0]], float)
    )
    scene.write_text(
        "".join(f"v {x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in corners) + "f 1 2 3\nf 1 3 4\n"
    )
    manifest = tmp_path / "dji.toml"
    srt = dji_clip.parent / "dji_0001.srt"
    manifest.write_text(
        f'[origin]\nlat = {lat}\nlon = {lon}\nh = 20.0\n\n[scene]\npath = "{scene}"\n\n[video]\npath = "{dji_clip}"\nstart_time = 0.0\n\n'
        f'[camera]\nhfov_deg = 73.7\n\n[sensors]\nformat = "none"\n\n[gnss]\npath = "{srt}"\n'
    )
    s = open_session(manifest)
    assert any("take-off height 20.00 m from the scene" in w for w in s.messages.items)
    rows = solve_frames(s, "telemetry")
    assert rows.geodetic[0, 2] == pytest.approx(
        20.0 + 85.8, abs=0.05
    )  # ellipsoidal height of the first pose
    assert rows.enu[0, 2] == pytest.approx(85.8, abs=0.05)  # Up above the scene's ground


def test_course_pitch_setting_resolves_the_track(shared_data, tmp_path):
    """The viewer asks the solver library for another pitch; the library re-solves the course
    source under its own lock and bumps its version; the session itself never changes."""
    from app.footage.clips import open_clip
    from app.playback.library import SolverLibrary
    from app.simulate.phone import write_video

    video = write_video(tmp_path / "c.mp4", np.arange(150) / 30.0, (96, 54), 0)
    (tmp_path / "c.srt").write_text((shared_data / "real" / "dji" / "p4p_sample.SRT").read_text())
    s = open_clip(video)
    assert s.sources == ["course"] and "pitch -30 deg assumed" in s.heading_note
    lib = SolverLibrary(s)
    assert lib.wait(timeout=60)
    assert lib.track("course").frame_poses().hpr[0, 1] == pytest.approx(-30.0, abs=0.01)
    before = lib.version
    lib.set_course_pitch(-60.0)
    assert lib.wait(timeout=60) and lib.version > before
    assert lib.track("course").frame_poses().hpr[0, 1] == pytest.approx(-60.0, abs=0.01)
    assert lib.course_pitch_deg == -60.0 and s.course_pitch_deg == -30.0


def test_the_viewer_reopens_a_clip_through_another_lens(dji_clip, display, tmp_path, shared_data):
    import json

    profile = next((shared_data / "lens_profiles" / "DJI").glob("*.json"))
    state1, state2 = tmp_path / "a.json", tmp_path / "b.json"
    script = tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0.1 state {state1}\n0.2 lens {profile}\n0.3 wait solved\n0.4 state {state2}\n0.5 quit\n"
    )
    result = run_viewer(display, str(dji_clip), "--script", str(script), "--size", "640x360")
    assert result.returncode == 0, result.stderr[-2000:]
    a, b = json.loads(state1.read_text()), json.loads(state2.read_text())
    assert (
        a["lens"] is None
        and b["lens"] == json.loads(profile.read_text())["name"]
        and b["errors"] == []
    )
    assert any(n.startswith("lens: ") for n in b["info"])
