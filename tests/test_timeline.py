"""Several clips on one timeline (app.session.timeline): clips with absolute clocks at their true
times, frame by frame; clips without one start together; outside its span a clip shows nothing."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest

from app.footage.clips import open_clip
from app.session.timeline import Timeline
from app.simulate import drone
from app.simulate.phone import write_video


def _dji(folder, name: str, seconds: float, start, monkeypatch, dated: bool = True):
    """A DJI clip whose subtitle dates start at `start` (a datetime, UTC)."""
    folder.mkdir(parents=True, exist_ok=True)
    video = write_video(folder / f"{name}.MP4", np.arange(int(seconds * 30)) / 30.0, (96, 54), 0)
    monkeypatch.setattr(drone, "START", start)
    text = drone.srt_text(seconds, 0.0)
    if not dated:
        text = "\n".join(
            line for line in text.split("\n") if not line[:4].isdigit() or "-" not in line[:8]
        )
    (folder / f"{name}.SRT").write_text(text, encoding="utf-8")
    return open_clip(video)


def test_clips_with_clocks_play_at_their_true_times(tmp_path, monkeypatch):
    """Clip B began 5.5 s after clip A: on the timeline each of B's frames falls 5.5 s after
    A's frame of the same UTC time; at timeline 7 s, A shows its frame at 7 s, B its at 1.5 s."""
    t0 = drone.START
    a = _dji(tmp_path / "a", "A", 10.0, t0, monkeypatch)
    b = _dji(tmp_path / "b", "B", 6.0, t0 + timedelta(seconds=5.5), monkeypatch)
    line = Timeline.of([b, a])  # in any order
    tb, ta = line.clips
    assert ta.absolute and tb.absolute and line.utc0 == pytest.approx(t0.timestamp(), abs=1e-3)
    assert ta.start_s == pytest.approx(0.0, abs=1e-3) and tb.start_s == pytest.approx(5.5, abs=1e-3)
    # every frame of B at its true time: its own media time plus 5.5 s
    np.testing.assert_allclose(tb.times, 5.5 + b.video.pts_s, atol=1e-3)
    fb, fa = line.frames_at(7.0)
    assert fa == 210 and fb == 45  # 7.0 s and 1.5 s at 30 fps
    assert line.frames_at(2.0)[0] is None  # B has not begun
    assert line.frames_at(11.6) == [None, None]  # both over


def test_clips_without_a_clock_start_together_and_move_by_their_offset(tmp_path, monkeypatch):
    a = _dji(tmp_path / "a", "A", 4.0, drone.START, monkeypatch, dated=False)
    b = _dji(tmp_path / "b", "B", 4.0, drone.START, monkeypatch, dated=False)
    line = Timeline.of([a, b], [0.0, 1.0])
    assert line.utc0 is None and not any(c.absolute for c in line.clips)
    assert line.clips[0].start_s == pytest.approx(0.0) and line.clips[1].start_s == pytest.approx(
        1.0
    )
    assert line.frames_at(0.5) == [15, None]


def test_footprints_of_several_clips_carry_their_clip(tmp_path, monkeypatch, capsys):
    """`geofuse export footprints A.MP4 B.MP4`: every clip's footprints, each with its clip
    field, and a camera track per clip beside them; other exports take one input."""
    import json

    from shapely.geometry import shape

    from app.cli import main

    _dji(tmp_path / "a", "A", 3.0, drone.START, monkeypatch)
    _dji(tmp_path / "b", "B", 2.0, drone.START + timedelta(seconds=1), monkeypatch)
    out = tmp_path / "both.geojson"
    args = ["export", "footprints", str(tmp_path / "a" / "A.MP4"), str(tmp_path / "b" / "B.MP4")]
    assert main(args + ["--out", str(out), "--every", "15"]) == 0, capsys.readouterr().err
    assert "of 2 clips" in capsys.readouterr().out
    features = json.loads(out.read_text())["features"]
    clips = [f["properties"]["clip"] for f in features]
    assert clips.count("A.MP4") == 6 and clips.count("B.MP4") == 4
    assert all(shape(f["geometry"]).is_valid for f in features)
    tracks = json.loads((tmp_path / "both_track.geojson").read_text())["features"]
    assert sorted(t["properties"]["clip"] for t in tracks) == ["A.MP4", "B.MP4"]
    csv = tmp_path / "both.csv"
    assert main(["export", "fmv-csv", *args[2:], "--out", str(csv)]) == 2
    assert "one input at a time" in capsys.readouterr().err


@pytest.mark.gl
def test_the_viewer_plays_two_clips_on_one_timeline(display, tmp_path, monkeypatch):
    """`geofuse view walk.toml DJI_0001.MP4`: both clocks are absolute (the walk from 09:46:40.08,
    the drone's subtitle from 09:46:40.00 UTC), so at the walk's frame 150 the drone shows the
    frame the timeline says; moved by an offset, another; hidden, its decoder is released and no
    further projector is drawn."""
    import json
    import shutil

    from app.session import open_session
    from app.simulate.sample import SAMPLE_DIR
    from tests.conftest import run_viewer

    shutil.copytree(SAMPLE_DIR, tmp_path / "walk")
    drone_clip = _dji(tmp_path / "drone", "DJI_0001", 20.0, drone.START, monkeypatch)
    walk = open_session(tmp_path / "walk" / "session.toml")
    line = Timeline.of([walk, drone_clip])
    s1, s2, s3 = (tmp_path / f"s{k}.json" for k in (1, 2, 3))
    script = tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0 seek 5\n0 pause\n0.2 state {s1}\n"
        f"0.25 clip 1 offset 2\n0.25 clip 1 alpha 0.5\n0.25 clip 1 source course\n0.3 state {s2}\n0.35 clip 1 off\n0.4 state {s3}\n0.45 quit\n"
    )
    result = run_viewer(
        display,
        str(tmp_path / "walk" / "session.toml"),
        str(tmp_path / "drone" / "DJI_0001.MP4"),
        "--script",
        str(script),
        "--size",
        "640x360",
    )
    assert result.returncode == 0, result.stderr[-2000:]
    first, moved, hidden = (json.loads(p.read_text()) for p in (s1, s2, s3))
    assert first["errors"] == [] and first["frame"] == 150
    expected = line.clips[1].frame_at(float(line.clips[0].times[150]))
    assert first["clips"][0]["frame"] == expected == 152 and first["extra_projectors"] == 1
    # Each frame's age at the moment drawn (where views tie, the younger wins): the first's is
    # its clock past its frame's time, the drone's the moment past the drone frame's time.
    walk_age, drone_age = first["frame_ages_s"]
    assert 0.0 <= walk_age < 0.034
    moment = first["timeline_s"] + walk_age
    assert drone_age == pytest.approx(moment - float(line.clips[1].times[152]), abs=1e-9)
    assert 0.0 <= drone_age < 0.034 + walk_age
    assert moved["clips"][0]["frame"] == expected - 60  # 2 s later on the timeline at 30 fps
    assert moved["clips"][0]["alpha"] == 0.5 and moved["clips"][0]["source"] == "course"
    assert hidden["clips"][0]["decoder"] is False and hidden["extra_projectors"] == 0


def test_render_sessions_together_at_one_moment(tmp_path, monkeypatch, capsys):
    """`render --session walk.toml --session DJI.MP4 --time 5`: the drone's frame at the same
    UTC moment (151 of it, at the walk's frame 149) drawn with the walk's on its scene; the drone
    (heights above take-off) is seated on the walk's ground, so its frame lands on the scene."""
    import shutil

    from PIL import Image

    from app.cli import main
    from app.simulate.sample import SAMPLE_DIR

    shutil.copytree(SAMPLE_DIR, tmp_path / "walk")
    _dji(tmp_path / "drone", "DJI_0001", 20.0, drone.START, monkeypatch)
    out, alone = tmp_path / "both.png", tmp_path / "alone.png"
    view = [
        "--time",
        "5",
        "--size",
        "320x180",
        "--view-from",
        "-40,-100,250",
        "--look-at",
        "-40,-99,0",
    ]
    walk = ["--session", str(tmp_path / "walk" / "session.toml")]
    both = walk + ["--session", str(tmp_path / "drone" / "DJI_0001.MP4")]
    assert main(["render", *both, *view, "--no-frustum", "--out", str(out)]) == 0
    assert "with DJI_0001.MP4 frame 151" in capsys.readouterr().out
    assert main(["render", *walk, *view, "--no-frustum", "--out", str(alone)]) == 0
    a = np.asarray(Image.open(out).convert("RGB")).astype(int)
    b = np.asarray(Image.open(alone).convert("RGB")).astype(int)
    changed = np.abs(a - b).max(axis=2) > 40
    assert changed.mean() > 0.05  # the drone's frame covers a good part of the ground seen


def test_a_manifest_lists_further_clips(tmp_path, monkeypatch, capsys):
    """[[clips]] tables: a further clip's file and its offset, read by render --session (and
    the viewer); an unknown key names itself; a missing file names the table."""
    import shutil

    from app.cli import main
    from app.simulate.sample import SAMPLE_DIR

    shutil.copytree(SAMPLE_DIR, tmp_path / "walk")
    _dji(tmp_path / "drone", "DJI_0001", 20.0, drone.START, monkeypatch)
    base = (tmp_path / "walk" / "session.toml").read_text()
    manifest = tmp_path / "walk" / "site.toml"
    manifest.write_text(base + '\n[[clips]]\npath = "../drone/DJI_0001.MP4"\noffset_s = 1.0\n')
    out = tmp_path / "r.png"
    assert (
        main(
            [
                "render",
                "--session",
                str(manifest),
                "--time",
                "5",
                "--size",
                "160x90",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "with DJI_0001.MP4 frame 121" in capsys.readouterr().out  # 151 less 1 s at 30 fps
    manifest.write_text(base + '\n[[clips]]\npth = "x"\n')
    assert main(["render", "--session", str(manifest), "--time", "5", "--out", str(out)]) == 2
    assert "field 'clips.pth': unknown key; did you mean 'path'?" in capsys.readouterr().err
    manifest.write_text(base + '\n[[clips]]\npath = "gone.mp4"\n')
    assert main(["render", "--session", str(manifest), "--time", "5", "--out", str(out)]) == 2
    assert "clips[0].path" in capsys.readouterr().err


def test_export_video_draws_every_clip(tmp_path, monkeypatch, capsys):
    """`export video walk.toml DJI.MP4`: the drone's frames of the same moments are drawn too
    (the top view differs from the walk's alone where the drone's video lies)."""
    import shutil

    import av

    from app.cli import main
    from app.simulate.sample import SAMPLE_DIR

    shutil.copytree(SAMPLE_DIR, tmp_path / "walk")
    _dji(tmp_path / "drone", "DJI_0001", 20.0, drone.START, monkeypatch)
    walk = str(tmp_path / "walk" / "session.toml")
    opts = ["--from", "4", "--to", "4.3", "--size", "320x180", "--view", "top"]
    both, alone = tmp_path / "both.mp4", tmp_path / "alone.mp4"
    assert (
        main(
            [
                "export",
                "video",
                walk,
                str(tmp_path / "drone" / "DJI_0001.MP4"),
                *opts,
                "--out",
                str(both),
            ]
        )
        == 0
    )
    assert "with 1 further clips" in capsys.readouterr().out
    assert main(["export", "video", walk, *opts, "--out", str(alone)]) == 0

    def frames(path):
        with av.open(str(path)) as c:
            return [f.to_ndarray(format="rgb24").astype(int) for f in c.decode(c.streams.video[0])]

    a, b = frames(both), frames(alone)
    assert len(a) == len(b) >= 9
    changed = [(np.abs(x - y).max(axis=2) > 40).mean() for x, y in zip(a, b, strict=True)]
    assert min(changed) > 0.02
