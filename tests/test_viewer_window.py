"""The real viewer window under Xvfb, driven by a script: play, scrub, toggle AHRS/IMU, change
the transparency, take a screenshot, and check that the video's pixels land on the model where an
off-screen render of the same state puts them; then open a broken manifest and check that the
error is reported and rendering goes on."""

from __future__ import annotations

import json
import re

import numpy as np
import pyproj
import pytest
from PIL import Image

from tests.conftest import ROOT, run_viewer, state_camera

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def scripted(display, tmp_path_factory):
    d = tmp_path_factory.mktemp("viewer")
    bad = d / "bad.toml"
    bad.write_text(
        (ROOT / "assets/sample/session.toml")
        .read_text()
        .replace('path = "clip.mp4"', 'path = "missing.mp4"')
        .replace('path = "scene.glb"', f'path = "{ROOT / "assets/sample/scene.glb"}"')
    )
    script = d / "script.txt"
    script.write_text(
        f"""0.0 clock 0.0333333
0.0 wait solved
0.0 play
2.0 state {d / "played.json"}
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
5.7 sync
5.7 wait synced
5.8 state {d / "synced.json"}
5.9 quit
"""
    )
    result = run_viewer(display, "--script", str(script), "--size", "960x540")
    assert result.returncode == 0, result.stderr[-3000:]
    return d, result


def test_scripted_session_state(scripted):
    d, _ = scripted
    played = json.loads((d / "played.json").read_text())
    # Two seconds of the script's clock went by, whatever this machine's speed: the frame shown is
    # the one due, and every frame due was either shown or counted as dropped.
    assert played["frame"] == played["due_frame"] == 60
    assert played["frames_shown"] + played["dropped"] == played["frame"] + 1
    assert (
        played["frames_shown"] >= 30
    )  # the sample is ~30 fps VFR; a 30 Hz clock shows most frames
    # `wait solved` holds for every source but the registered one, solved last (it may be done).
    assert sorted(set(played["solved"]) - {"registered"}) == sorted(
        ["gd-ahrs", "gd-imu", "cf-ahrs", "cf-imu", "offline", "phone", "truth"]
    )
    state = json.loads((d / "scene.json").read_text())
    assert state["source"] == "gd-ahrs"  # gd-imu, then the AHRS toggle back on
    assert state["alpha"] == 1.0
    assert state["frame"] == state["due_frame"] == 600  # paused after seeking to 20 s at 30 fps
    assert state["errors"] == []
    assert state["view_rect"] == [0, 0, 960, 540]  # panels off: the 3D view is the whole window


def test_the_docked_panels_leave_the_3d_view_most_of_the_window(scripted):
    d, _ = scripted
    played = json.loads((d / "played.json").read_text())
    x, y, w, h = played["view_rect"]
    W, H = played["window"]
    assert w * h >= 0.6 * W * H and x + w <= W and y + h <= H
    shot = np.asarray(Image.open(d / "after_error.png").convert("RGB"), int)
    # The panels sit outside the 3D view: ImGui's dark panel background fills the left column.
    assert shot[:, : max(1, x - 2)].mean() < 80 and shot[y + h // 2, x + w // 2].mean() > 60


def test_video_lands_where_an_offscreen_render_puts_it(scripted, gl_ctx):
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.io.video import read_frame
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer
    from app.scene import load_scene
    from app.session import open_session
    from app.session.camera_track import camera_track

    d, _ = scripted
    state = json.loads((d / "scene.json").read_text())
    shot = np.asarray(Image.open(d / "scene.png").convert("RGB"), int)
    session = open_session(state["manifest"])
    k = state["frame"]
    projector = camera_track(session, state["source"]).frame_camera(k)
    np.testing.assert_allclose(projector.position, state["projector"]["position"], atol=1e-3)
    wc = state["window_camera"]
    view = state_camera(wc)
    renderer = FusionRenderer(
        gl_ctx, load_scene(session.scene_path, session.frame, session.placement)
    )
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
    assert after["frames_drawn"] > before["frames_drawn"]
    shot = np.asarray(Image.open(d / "after_error.png").convert("RGB"), int)
    x, y, w, h = after["view_rect"]
    assert shot[y : y + h, x : x + w].std() > 20  # the scene is still drawn, not a blank window
    assert "missing.mp4" in result.stderr  # and it is logged


def test_screenshot_alone_plays_the_sample_and_exits(display, tmp_path):
    out = tmp_path / "view.png"
    result = run_viewer(display, "--screenshot", str(out), "--size", "800x450", "--play", "1.0")
    assert result.returncode == 0, result.stderr[-2000:]
    img = np.asarray(Image.open(out).convert("RGB"), int)
    assert img.shape == (450, 800, 3)
    # Default layout: panels (dark) down the left, the 3D view with the sky (the renderer's
    # background colour) at its top right.
    assert img[:300, :150].mean() < 80
    sky = np.abs(img[5:40, 500:790] - np.array([158, 189, 219])).max(axis=2) <= 3
    assert sky.mean() > 0.5


def test_the_panel_layout_is_remembered_between_runs(display, tmp_path):
    """A run saves its docked layout in $XDG_CONFIG_HOME/geofuse/imgui.ini; the next run reads it
    back (here: a layout with a narrower left column, written by hand) instead of the default."""
    script = tmp_path / "s.txt"
    script.write_text(f"0.0 clock 0.05\n0.2 state {tmp_path / 'first.json'}\n0.3 quit\n")
    result = run_viewer(display, "--script", str(script), "--size", "800x450", config_home=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    ini = tmp_path / "geofuse" / "imgui.ini"
    text = ini.read_text()
    assert "[Docking]" in text and "Timeline" in text
    first = json.loads((tmp_path / "first.json").read_text())
    central = re.search(r"SizeRef=(\d+),(\d+) CentralNode=1", text)
    cw, ch = int(central[1]), int(central[2])
    left = int(re.search(r"SizeRef=(\d+),\d+ Split=Y", text)[1])  # the left column
    text = text.replace(f"SizeRef={left},", f"SizeRef={left // 2},").replace(
        central[0], f"SizeRef={cw + left - left // 2},{ch} CentralNode=1"
    )
    ini.write_text(text)
    script.write_text(f"0.0 clock 0.05\n0.2 state {tmp_path / 'second.json'}\n0.3 quit\n")
    result = run_viewer(display, "--script", str(script), "--size", "800x450", config_home=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    second = json.loads((tmp_path / "second.json").read_text())
    assert second["view_rect"][2] > first["view_rect"][2]  # the edited, narrower column was used


def test_export_and_record_from_the_viewer(display, tmp_path, session_dir):
    """The Export panel's commands: footprints exported in the background while the viewer runs
    (then checked as GeoJSON: one footprint per video frame), and the window recorded: the
    recording has the window's size and one frame per drawn frame of the fixed-step clock. On
    the simulated 20 s phone session (conftest's, read only), whose every frame exports far
    faster than the sample's 2400."""
    import av

    with av.open(str(session_dir / "clip.mp4")) as c:  # every frame, counted apart from the app
        n_frames = sum(1 for _ in c.decode(c.streams.video[0]))
    assert n_frames == 600  # 20 s at 30 fps
    fp, rec, state = tmp_path / "fp.geojson", tmp_path / "rec.mp4", tmp_path / "s.json"
    script = tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0 export footprints {fp}\n0 record start {rec}\n0 play\n"
        f"1.0 record stop\n1.0 wait exported\n1.05 state {state}\n1.1 quit\n"
    )
    result = run_viewer(
        display, str(session_dir / "session.toml"), "--script", str(script), "--size", "640x360"
    )
    assert result.returncode == 0, result.stderr[-2000:]
    s = json.loads(state.read_text())
    said = (s["errors"], s["info"])
    assert s["errors"] == [] and any(n.startswith(f"recorded {rec}") for n in s["info"]), said
    doc = json.loads(fp.read_text())
    assert doc["type"] == "FeatureCollection"
    assert len(doc["features"]) == n_frames, len(doc["features"])  # every frame
    track = json.loads(fp.with_name(f"{fp.stem}_track.geojson").read_text())["features"]
    assert len(track[0]["geometry"]["coordinates"]) == n_frames
    with av.open(str(rec)) as c:
        frames = [f for f in c.decode(c.streams.video[0])]
    assert (frames[0].width, frames[0].height) == (640, 360)
    assert 19 <= len(frames) <= 21, len(frames)  # 1 s of a 20 Hz clock


def test_sync_from_the_viewer_applies_the_offset(scripted):
    """The Sync button's command (run last in the scripted session, on the sample that stayed
    open): the offset found (the sample's start time is 80 ms off) becomes the session's time
    offset, and no error comes with it."""
    d, _ = scripted
    before = json.loads((d / "after_error.json").read_text())
    s = json.loads((d / "synced.json").read_text())
    assert s["manifest"] == before["manifest"] and s["manifest"].endswith("session.toml")
    assert before["time_offset_s"] == 0.0  # the offset is the sync's doing, not the manifest's
    assert s["errors"] == before["errors"] and s["sync"]["confidence"] > 0.9
    assert (
        s["time_offset_s"] == pytest.approx(s["sync"]["offset_s"]) == pytest.approx(-0.08, abs=0.01)
    )


def run_script(display, folder, target: str, text: str) -> None:
    """Run the viewer on `target` with a script (640x360) and check it exited cleanly."""
    script = folder / "script.txt"
    script.write_text(text)
    result = run_viewer(display, target, "--script", str(script), "--size", "640x360")
    assert result.returncode == 0, result.stderr[-3000:]


def test_a_tileset_session_in_the_window_matches_the_model_it_was_made_from(
    display, tmp_path, gl_ctx
):
    """The sample's stadium as 3D Tiles (plus a generated city as a second layer) in the window:
    once its tiles are loaded, the screenshot shows what an off-screen render of the same state
    shows, and the tileset's stadium is the sample GLB drawn in place."""
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.io.video import read_frame
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer
    from app.scene import load_scene
    from app.session import open_session
    from app.session.camera_track import camera_track
    from tools.gis_sessions import tiles

    manifest = tiles(tmp_path)
    run_script(
        display,
        tmp_path,
        str(manifest),
        f"""0.0 clock 0.0333333
0.0 wait solved
0.0 seek 20
0.0 pause
0.1 panels off
0.1 lines off
0.2 look -150,-170,70 0,0,10
0.3 wait tiles
0.4 wait tiles
0.5 screenshot {tmp_path / "tiles.png"}
0.5 state {tmp_path / "tiles.json"}
0.6 quit
""",
    )
    state = json.loads((tmp_path / "tiles.json").read_text())
    assert state["errors"] == [] and state["layers"] == [
        "tileset:stadium/tileset.json",
        "tileset:city/tileset.json",
    ]
    shot = np.asarray(Image.open(tmp_path / "tiles.png").convert("RGB"), int)
    session = open_session(manifest)
    assert len(session.scene().tilesets) == 2
    k = state["frame"]
    projector = camera_track(session, state["source"]).frame_camera(k)
    wc = state["window_camera"]
    view = state_camera(wc)
    none = OverlaySettings(frustum=False, trajectory=False)
    renderer = FusionRenderer(gl_ctx, session.scene())
    try:
        renderer.set_video_frame(read_frame(session.video.path, k, session.video))
        renderer.set_projector(projector)
        on = render_to_array(renderer, view, ProjectionSettings(alpha=1.0), none).astype(int)
        tiles_off = render_to_array(renderer, view, ProjectionSettings(enabled=False), none).astype(
            int
        )
    finally:
        renderer.release()
    model = FusionRenderer(gl_ctx, load_scene(ROOT / "assets/sample/scene.glb", session.frame))
    try:
        glb_off = render_to_array(model, view, ProjectionSettings(enabled=False), none).astype(int)
    finally:
        model.release()
    diff = np.abs(shot - on).max(axis=2)
    assert np.median(diff) <= 4 and np.mean(diff <= 16) > 0.97
    assert (np.abs(on - tiles_off).max(axis=2) > 40).sum() > 500  # the video is on the stadium
    stadium = np.abs(glb_off - tiles_off).max(axis=2) <= 3  # the city only adds to the model
    assert np.mean(stadium) > 0.8


@pytest.fixture(scope="module")
def gopro_run(display, tmp_path_factory, shared_data):
    """One viewer launch on the GoPro clip for the DEM and city tests, each checking its own
    part: a DEM dropped on the clip (with_dem.json), then a CityJSON around its track
    (with_city.json), then a damaged one (after.json); then the sample's manifest opened and the
    DEM dropped on it (manifest.json)."""
    from app.footage.clips import open_any
    from app.geodesy.crs import utm_zone
    from app.simulate.city import Building, write_cityjson
    from tests.corpus.generate import dem_under_gopro_clip

    d = tmp_path_factory.mktemp("gopro")
    dem_under_gopro_clip(d, shared_data)
    clip = shared_data / "real/gopro/max-heromode.mp4"
    frame = open_any(clip).frame
    crs = utm_zone(frame.lat_deg, frame.lon_deg)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(
        frame.lon_deg, frame.lat_deg
    )
    good = write_cityjson(
        d / "block.city.json",
        [Building.box("block", (x + 10, y + 10, x + 30, y + 25), 0.0, 15.0)],
        f"EPSG:{crs.to_epsg()}",
    )
    broken = d / "broken.city.json"
    broken.write_text(good.read_text()[:200])
    run_script(
        display,
        d,
        str(clip),
        f"""0.0 clock 0.0333333
0.2 open {d / "dem.tif"}
0.4 state {d / "with_dem.json"}
0.5 open {good}
0.7 state {d / "with_city.json"}
0.8 open {broken}
1.0 state {d / "after.json"}
1.1 open {ROOT / "assets/sample/session.toml"}
1.3 open {d / "dem.tif"}
1.5 state {d / "manifest.json"}
1.6 quit
""",
    )
    return d


def test_a_dem_dropped_on_an_open_clip_becomes_its_terrain(gopro_run):
    """Opening a .tif while a clip is open adds it to the clip's scene (the clip reopens on it);
    with a manifest open it is refused with a message, and the viewer goes on."""
    with_dem = json.loads((gopro_run / "with_dem.json").read_text())
    assert with_dem["errors"] == [] and any("terrain of" in n for n in with_dem["info"])
    assert with_dem["manifest"].endswith("max-heromode.mp4") and with_dem["layers"] == [
        "dem:dem.tif"
    ]
    refused = json.loads((gopro_run / "manifest.json").read_text())
    assert any("a manifest names its scene" in e for e in refused["errors"])
    assert refused["manifest"].endswith("session.toml")


def test_a_city_model_opened_on_a_clip_is_drawn_and_a_damaged_one_is_refused(gopro_run):
    """Opening a CityJSON while a GoPro clip is open (its DEM dropped on it first) adds it to the
    clip's scene, read around its track, beside the terrain; a damaged one is refused with the
    file named, and the viewer goes on with the scene it had."""
    with_city = json.loads((gopro_run / "with_city.json").read_text())
    assert with_city["errors"] == [] and with_city["manifest"].endswith("max-heromode.mp4")
    assert with_city["layers"] == ["dem:dem.tif", "city:block.city.json"]
    assert any("CityJSON 2.0" in n and "1 of 1 objects" in n for n in with_city["info"])
    after = json.loads((gopro_run / "after.json").read_text())
    assert any("broken.city.json" in e and "broken JSON" in e for e in after["errors"])
    assert after["layers"] == ["dem:dem.tif", "city:block.city.json"]


def _grey(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("L"), np.float64)


def _painted_memory(d, name: str = "memory") -> dict:
    """The memory's part of the state a script wrote to {name}.json in d, checked painted
    without an error (and the viewer without one)."""
    state = json.loads((d / f"{name}.json").read_text())
    m = state["memory"]
    assert state["errors"] == [] and m["done"] and m["error"] is None
    return m


def _memory_against_the_drape(d, name: str = "memory") -> tuple[np.ndarray, float, float, float]:
    """From the screenshots drape.png, model.png and {name}.png in d (the same view): the
    memory's grey image, the fraction of pixels where the video is draped (drape and model
    differ; the sky is neither), and there the memory's and the model's correlation with the
    drape."""
    drape, model, mem = (_grey(d / f"{n}.png") for n in ("drape", "model", name))
    lit = np.abs(drape - model) > 0
    corr = [float(np.corrcoef(x[lit], drape[lit])[0, 1]) for x in (mem, model)]
    return mem, float(lit.mean()), corr[0], corr[1]


# the sample at 30 s through the video's camera: the drape, then the model alone (the script's
# start of the memory tests; {d}: their folder)
MEMORY_START = """0.0 clock 0.0333333
0.0 wait solved
0.0 pause
0.1 seek 30
0.2 panels off
0.2 lines off
0.2 view phone
0.2 alpha 1.0
0.4 screenshot {d}/drape.png
0.5 project off
0.7 screenshot {d}/model.png
"""


@pytest.fixture(scope="module")
def memories(display, tmp_path_factory):
    """One viewer run on the sample for both memory tests (each checks its own part): the
    memory painted in one atlas (a frame every 4 s) and looked at as the memory, as "seen at",
    and scrubbed back to 2 s; then, back at 30 s in the same view, painted again with the atlas
    capped at 20000 texels (a frame every 8 s), so that it is paged (paged.png, paged.json)."""
    d = tmp_path_factory.mktemp("memory")
    run_script(
        display,
        d,
        str(ROOT / "assets/sample/session.toml"),
        MEMORY_START.format(d=d)
        + f"""0.8 memory paint newest 4.0
0.9 wait painted
1.0 screenshot {d / "memory.png"}
1.0 state {d / "memory.json"}
1.1 memory seen
1.2 wait painted
1.3 screenshot {d / "seen.png"}
1.4 seek 2
1.5 memory memory
1.6 wait painted
1.7 screenshot {d / "early.png"}
1.7 state {d / "early.json"}
1.8 seek 30
1.9 memory paint newest 8.0 20000
2.0 wait painted
2.1 screenshot {d / "paged.png"}
2.1 state {d / "paged.json"}
2.2 quit
""",
    )
    return d


def test_the_scene_memory_shows_what_the_video_saw_as_it_was(memories):
    """Painted in the background (a frame every 4 s here), the memory seen through the video's
    camera looks like the video draped there (it is the video, where the frustum put it), much
    more than the model does (the sample's world differs from its model); "seen at" is mostly
    recent there; and scrubbed back to 2 s, the memory holds only what had been seen by then."""
    d = memories
    m = _painted_memory(d)
    # the 80 s sample's frames 4 s apart (VFR: a frame at or just after each 4 s step)
    assert 18 <= m["frames"] <= 21 and m["seen"] > 5000 and m["range_s"][1] <= 30.0 + 1e-6
    mem, lit, like_drape, like_model = _memory_against_the_drape(d)
    assert lit > 0.3
    assert like_drape > like_model + 0.15, (like_drape, like_model)
    seen = np.asarray(Image.open(d / "seen.png").convert("RGB"), np.float64)
    red = (seen[..., 0] > seen[..., 2] + 40).mean()
    blue = (seen[..., 2] > seen[..., 0] + 40).mean()
    assert red > 2 * blue  # looked at in the last seconds: the ramp's recent end
    early = json.loads((d / "early.json").read_text())["memory"]
    assert early["range_s"][1] <= 2.0 + 1e-6
    assert np.abs(_grey(d / "early.png") - mem).mean() > 1.0


def test_a_paged_scene_memory_in_the_window(memories):
    """`memory paint newest 8 20000`: the atlas capped far below what the video's sampling asks
    for, the window pages the memory: the pages its view meets are composed and drawn over the
    model, said in the state (pages made, held on the GPU within its budget), and seen through
    the video's camera the memory looks like the video draped there more than the model does."""
    d = memories
    single = json.loads((d / "memory.json").read_text())
    paged = json.loads((d / "paged.json").read_text())
    # the same view as drape.png and model.png: the video's camera at the same frame
    assert paged["frame"] == single["frame"] and paged["window_camera"] == single["window_camera"]
    m = _painted_memory(d, "paged")
    assert 9 <= m["frames"] <= 11  # painted again (a frame every 8 s), not the first memory
    pages = m["pages"]
    assert pages is not None and pages["made"] > 5 and 0 < pages["gpu_pages"] <= pages["made"]
    assert pages["gpu_mb"] <= 96.0
    _, _, like_drape, like_model = _memory_against_the_drape(d, "paged")
    assert like_drape > like_model + 0.15, (like_drape, like_model)
