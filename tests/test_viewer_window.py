"""The real viewer window under Xvfb, driven by a script: play, scrub, toggle AHRS/IMU, change
the transparency, take a screenshot, and check that the video's pixels land on the model where an
off-screen render of the same state puts them; then open a broken manifest and check that the
error is reported and rendering goes on."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from tests.conftest import ROOT, run_viewer

pytestmark = pytest.mark.gl




@pytest.fixture(scope="module")
def scripted(display, tmp_path_factory):
    d = tmp_path_factory.mktemp("viewer")
    bad = d / "bad.toml"
    bad.write_text((ROOT / "assets/sample/session.toml").read_text().replace('path = "clip.mp4"', 'path = "missing.mp4"').replace('path = "scene.glb"', f'path = "{ROOT / "assets/sample/scene.glb"}"'))
    script = d / "script.txt"
    script.write_text(
        f"""0.0 play
2.0 pause
2.2 seek 20
2.6 source gd-imu
2.8 ahrs on
3.0 alpha 1.0
3.2 panels off
3.2 lines off
4.5 screenshot {d / "scene.png"}
4.5 state {d / "scene.json"}
4.7 panels on
4.8 open {bad}
5.6 screenshot {d / "after_error.png"}
5.6 state {d / "after_error.json"}
5.8 quit
"""
    )
    result = run_viewer(display, "--script", str(script), "--size", "960x540")
    assert result.returncode == 0, result.stderr[-3000:]
    return d, result


def test_scripted_session_state(scripted):
    d, _ = scripted
    state = json.loads((d / "scene.json").read_text())
    assert state["source"] == "gd-ahrs"  # gd-imu, then the AHRS toggle back on
    assert state["alpha"] == 1.0
    assert state["frame"] == 600  # paused after seeking to 20 s at 30 fps
    assert state["frames_shown"] > 20  # two seconds of playback went by
    assert state["errors"] == []


def test_video_lands_where_an_offscreen_render_puts_it(scripted, gl_ctx):
    from app.camera import Camera, Intrinsics
    from app.config import OverlaySettings, ProjectionSettings
    from app.io.video import read_frame
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer
    from app.scene import load_scene
    from app.session import open_session, pose_track

    d, _ = scripted
    state = json.loads((d / "scene.json").read_text())
    shot = np.asarray(Image.open(d / "scene.png").convert("RGB"), int)
    session = open_session(state["manifest"])
    k = state["frame"]
    enu, _, q = pose_track(session, state["source"]).at(session.frame_times[k : k + 1])
    np.testing.assert_allclose(enu[0], state["projector"]["position"], atol=1e-3)
    projector = Camera.create(session.intrinsics, enu[0], q[0], near=0.5, far=2000.0)
    wc = state["window_camera"]
    view = Camera.create(Intrinsics(*wc["size"], wc["fx"], wc["fy"], wc["cx"], wc["cy"]), wc["position"], wc["orientation"], wc["near"], wc["far"])
    renderer = FusionRenderer(gl_ctx, load_scene(session.scene_path, session.frame, session.placement))
    try:
        renderer.set_video_frame(read_frame(session.video.path, k, session.video))
        renderer.set_projector(projector)
        none = OverlaySettings(frustum=False, trajectory=False)
        on = render_to_array(renderer, view, ProjectionSettings(alpha=1.0), none).astype(int)
        off = render_to_array(renderer, view, ProjectionSettings(enabled=False), none).astype(int)
    finally:
        renderer.release()
    assert shot.shape == on.shape
    covered = np.abs(on - off).max(axis=2) > 40  # where the video visibly changes the model
    assert covered.sum() > 2000
    to_on = np.abs(shot - on).max(axis=2)[covered]
    to_off = np.abs(shot - off).max(axis=2)[covered]
    # The window shows the video where the off-screen render does (the YUV path differs from the
    # RGB still by its rounding and chroma filtering), and not the bare model.
    assert np.median(to_on) <= 6 and np.mean(to_on <= 16) > 0.98
    assert np.median(to_off) > 40


def test_a_broken_manifest_shows_an_error_and_rendering_goes_on(scripted):
    d, result = scripted
    before = json.loads((d / "scene.json").read_text())
    after = json.loads((d / "after_error.json").read_text())
    assert any("missing.mp4" in e and "does not exist" in e for e in after["errors"])
    assert after["manifest"] == before["manifest"]  # the sample stays open
    assert after["frames_drawn"] > before["frames_drawn"] and (d / "after_error.png").stat().st_size > 10_000
    assert "missing.mp4" in result.stderr  # and it is logged


def test_screenshot_alone_plays_the_sample_and_exits(display, tmp_path):
    out = tmp_path / "view.png"
    result = run_viewer(display, "--screenshot", str(out), "--size", "800x450", "--play", "1.0")
    assert result.returncode == 0, result.stderr[-2000:]
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (450, 800, 3) and img.std() > 20
