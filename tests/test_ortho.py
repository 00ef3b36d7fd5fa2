"""The orthophoto a clip paints (app.export.ortho, `geofuse export ortho`): the surface seen from
above, a texel keeping its frame's colour and time, hidden surfaces never painted, the rules, the
georeference checked with rasterio, memory that does not grow with the clip."""

from __future__ import annotations

import re
import subprocess
import sys
import tracemalloc

import numpy as np
import pyproj
import pytest
import rasterio

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.export.ortho import OrthoMemory, make_grid, surface
from app.export.orthophoto import write_orthophoto
from app.export.painting import distances
from app.geodesy.enu import LocalFrame
from app.render.views import ModelViews
from app.scene import shapes
from app.scene.mesh import MeshData

FRAME = LocalFrame(50.1, 8.7, 120.0)
BOX = ((20.0, 20.0, 0.0), (30.0, 30.0, 5.0))  # ENU m: a 10 x 10 m block, 5 m tall


def _scene() -> MeshData:
    ground = shapes.quad([-100.0, -100.0, 0.0], [200.0, 0, 0], [0, 200.0, 0])
    return MeshData([ground.primitive(), shapes.box(*BOX).primitive()])


def _camera(eye, target, size=(320, 240), f=200.0) -> Camera:
    eye = np.asarray(eye, float)
    up = (0.0, 1.0, 0.0) if abs(eye[0] - target[0]) + abs(eye[1] - target[1]) < 1e-6 else (0, 0, 1)
    w, h = size
    return Camera.create(
        Intrinsics(w, h, f, f, w / 2, h / 2), eye, look_at_quat(eye, target, up), far=1000.0
    )


@pytest.fixture(scope="module")
def scene_views(gl_ctx):
    views = ModelViews(_scene(), gl_ctx)
    yield views
    views.release()


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A 3 s survey of the sample site, simulated once for the module's export tests; they read
    it (the 3D Tiles test paints a copy of its folder)."""
    from app.simulate.sample import SAMPLE_SCENE
    from app.simulate.session import SampleConfig, quick_config, write_sample_session

    return write_sample_session(
        tmp_path_factory.mktemp("survey"),
        SAMPLE_SCENE,
        SampleConfig(**{**quick_config(3.0).__dict__, "flight": "survey"}),
    )


def _memory(rule="newest", gsd=0.5) -> OrthoMemory:
    grid = make_grid(FRAME, (-40.0, -40.0), (60.0, 60.0), gsd)
    points, normals = surface(_scene(), grid, FRAME)
    return OrthoMemory(grid, points, normals, rule)


def _cell(memory: OrthoMemory, x: float, y: float) -> tuple[int, int]:
    c, r = memory.grid.enu_to_grid @ [x, y, 1.0]
    return int(r), int(c)


def test_the_surface_is_the_top_of_the_scene_in_a_utm_grid():
    m = _memory()
    assert m.grid.crs.to_epsg() == 32632 and m.grid.fit_error_m < 1e-3
    r, c = _cell(m, 25.0, 25.0)
    assert m.points[r, c, 2] == pytest.approx(5.0) and m.normals[r, c, 2] == pytest.approx(1.0)
    r, c = _cell(m, 0.0, 0.0)
    assert m.points[r, c, 2] == pytest.approx(0.0)
    assert np.asarray(m.points[r, c, :2]) == pytest.approx([0.0, 0.0], abs=0.5)
    # the cell's centre, taken to UTM, lies in the cell the grid's transform says
    lat, lon, _ = FRAME.enu_to_geodetic(np.array([[m.points[r, c, 0], m.points[r, c, 1], 0.0]]))[0]
    x, y = pyproj.Transformer.from_crs("EPSG:4326", m.grid.crs, always_xy=True).transform(lon, lat)
    assert (x - m.grid.west) / m.grid.gsd == pytest.approx(c + 0.5, abs=1e-3)
    assert (m.grid.north - y) / m.grid.gsd == pytest.approx(r + 0.5, abs=1e-3)


def _flat(colour, size=(320, 240)) -> np.ndarray:
    return np.tile(np.asarray(colour, np.uint8), (size[1], size[0], 1))


def test_a_texel_keeps_its_frames_colour_and_time_after_the_camera_turns_away(scene_views):
    m = _memory()
    down = _camera([0.0, 0.0, 60.0], [0.0, 0.0, 0.0])
    assert m.memory.paint(_flat((200, 30, 30)), down, distances(scene_views, down), 1000.0) > 0
    away = _camera([0.0, 0.0, 60.0], [0.0, 200.0, 50.0])  # looking at the sky over the north
    m.memory.paint(_flat((30, 30, 200)), away, distances(scene_views, away), 1001.0)
    r, c = _cell(m, 0.0, 0.0)
    assert m.seen[r, c] and tuple(m.rgb[r, c]) == (200, 30, 30) and m.time[r, c] == 1000.0
    far = _cell(m, -39.0, 59.0)  # never in view
    assert not m.seen[far] and np.isnan(m.time[far]) and m.quality[far] == 0


def test_a_hidden_surface_is_never_painted(scene_views):
    """From 12 m up in the south-west, the block hides the ground behind it: that ground stays
    unseen while the ground in front of it and the block's roof are painted."""
    m = _memory()
    cam = _camera([0.0, 0.0, 12.0], [25.0, 25.0, 2.0], f=150.0)
    m.memory.paint(_flat((90, 200, 90)), cam, distances(scene_views, cam), 5.0)
    assert m.seen[_cell(m, 15.0, 15.0)]  # the ground in front
    behind = [_cell(m, x, y) for x, y in ((34.0, 34.0), (36.0, 33.0), (33.0, 37.0))]
    assert not any(m.seen[rc] for rc in behind)
    # and without the depth test (no distances: nothing hides anything) it would be painted
    m2 = _memory()
    m2.memory.paint(_flat((90, 200, 90)), cam, np.full((240, 320), np.inf), 5.0)
    assert all(m2.seen[rc] for rc in behind)


@pytest.mark.parametrize(
    "rule, expected", [("newest", (30, 30, 200)), ("best", (200, 30, 30)), ("first", (200, 30, 30))]
)
def test_the_rules_choose_as_documented(scene_views, rule, expected):
    """A cell seen first near and head-on (quality high, red), then far and slanted (blue):
    newest keeps blue, best and first keep red."""
    m = _memory(rule)
    near = _camera([0.0, 0.0, 20.0], [0.0, 0.0, 0.0])
    far = _camera([-80.0, -80.0, 40.0], [0.0, 0.0, 0.0], f=600.0)
    m.memory.paint(_flat((200, 30, 30)), near, distances(scene_views, near), 1.0)
    r, c = _cell(m, 0.0, 0.0)
    q_near = m.quality[r, c]
    m.memory.paint(_flat((30, 30, 200)), far, distances(scene_views, far), 2.0)
    assert tuple(m.rgb[r, c]) == expected
    assert m.time[r, c] == (2.0 if rule == "newest" else 1.0)
    assert rule != "newest" or m.quality[r, c] < q_near


def test_a_painted_marker_lands_at_its_coordinates_in_the_geotiff(scene_views, tmp_path):
    """A red dot in a frame, where the camera sees a known ground point, lands in the written
    GeoTIFF (read back with rasterio) within one cell of that point's UTM coordinates."""
    m = _memory(gsd=0.25)
    cam = _camera([-5.0, 3.0, 40.0], [0.0, 0.0, 0.0])
    target = np.array([6.3, -4.1, 0.0])
    uv, _ = cam.project(target[None])
    u, v = uv[0]
    frame = _flat((128, 128, 128))
    yy, xx = np.mgrid[0:240, 0:320]
    frame[(xx + 0.5 - u) ** 2 + (yy + 0.5 - v) ** 2 < 2.0**2] = (255, 0, 0)
    m.memory.paint(frame, cam, distances(scene_views, cam), 7.0)
    out, seen = write_orthophoto(m, tmp_path / "ortho.tif", [])
    with rasterio.open(out) as src:
        assert src.crs.to_epsg() == 32632 and src.count == 4 and src.overviews(1) is not None
        rgba = src.read()
        red = (rgba[0] > 200) & (rgba[1] < 80) & (rgba[3] == 255)
        rows, cols = np.nonzero(red)
        x, y = src.xy(rows.mean(), cols.mean())
    lat, lon, _ = FRAME.enu_to_geodetic(target[None])[0]
    tx, ty = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(
        lon, lat
    )
    assert np.hypot(x - tx, y - ty) < m.grid.gsd
    with rasterio.open(seen) as src:
        t, q = src.read()
        assert np.nanmax(t) == 7.0 and np.all(np.isnan(t[~red & (rgba[3] == 0)]))
        assert q.max() > 0


def test_memory_stays_within_its_cap_on_a_long_clip(scene_views):
    """600 frames (20 s at 30 fps) painted into one memory: it holds the same bytes as
    before the first, and painting allocates no more than a frame's worth on top."""
    m = _memory()
    held = m.nbytes
    cams = [
        _camera([np.cos(a) * 30, np.sin(a) * 30, 50.0], [0.0, 0.0, 0.0])
        for a in np.linspace(0, 6.28, 8)
    ]
    dists = [distances(scene_views, c) for c in cams]
    frame = _flat((120, 140, 160))
    tracemalloc.start()
    try:
        for k in range(600):
            m.memory.paint(frame, cams[k % 8], dists[k % 8], float(k))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert m.nbytes == held and m.frames == 600
    assert peak < 0.5 * held + 20e6, f"painting peaked at {peak / 1e6:.1f} MB over {held / 1e6:.1f}"


def test_export_ortho_of_a_survey_puts_the_roof_where_the_model_has_it(survey, tmp_path):
    """`geofuse export ortho` on a 3 s survey (truth poses): the COG opens with rasterio in the
    site's UTM zone; where the model's surface is building 5's roof (10 m up) the picture is
    its grey roof, around it the green ground."""
    from app.simulate.sample import SAMPLE_ORIGIN, SAMPLE_SCENE
    from app.simulate.session import SampleConfig, quick_config, write_sample_session

    manifest = survey
    out = tmp_path / "ortho.tif"
    args = [
        "export",
        "ortho",
        str(manifest),
        "--out",
        str(out),
        "--source",
        "truth",
        "--gsd",
        "0.5",
    ]
    # a process of its own: the command makes its own GL context current on this thread, which
    # the session's shared context (gl_ctx, this module's other tests) must not meet
    subprocess.run([sys.executable, "-m", "app", *args], check=True, capture_output=True)
    with rasterio.open(out) as src:
        assert src.crs.to_epsg() == 32649 and src.res == pytest.approx((0.5, 0.5))
        rgba = src.read().transpose(1, 2, 0).astype(int)
        transform, crs = src.transform, src.crs
    # the roof of building 5 (app.simulate.stadium: -104..-76 E, -62..-36 N, 10 m), inset 2 m
    frame = LocalFrame(*SAMPLE_ORIGIN)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs.to_wkt(), always_xy=True)

    def pixel(e, n):
        lat, lon, _ = frame.enu_to_geodetic(np.array([[e, n, 0.0]]))[0]
        x, y = to_utm.transform(lon, lat)
        col, row = ~transform @ (x, y)
        return rgba[int(row), int(col)]

    roof = np.array([pixel(e, n) for e in (-100, -90, -80) for n in (-58, -49, -40)])
    grass = np.array([pixel(e, n) for e in (-70, -60) for n in (-95, -85)])
    assert np.all(roof[:, 3] == 255) and np.all(grass[:, 3] == 255)
    assert np.all(np.abs(roof[:, 1] - roof[:, 0]) < 25)  # grey
    assert np.all(grass[:, 1] > grass[:, 0] + 20)  # green

    # a second clip (an orbit) paints the same orthophoto: more of the site is seen, on the
    # same grid where it is given one
    orbit = write_sample_session(
        tmp_path / "o",
        SAMPLE_SCENE,
        SampleConfig(**{**quick_config(3.0).__dict__, "flight": "orbit"}),
    )
    both = tmp_path / "both.tif"
    args[2:5] = [str(manifest), str(orbit), "--out", str(both)]
    done = subprocess.run([sys.executable, "-m", "app", *args], check=True, capture_output=True)
    assert "of 2 clip(s)" in done.stdout.decode()
    with rasterio.open(both) as src:
        seen_both = int((src.read(4) > 0).sum()) * src.res[0] ** 2
    assert seen_both > 1.2 * int((rgba[..., 3] > 0).sum()) * 0.25


def test_a_surface_seen_edge_on_is_not_painted(scene_views):
    """From 3 m up, the ground 21 m away is seen 82 deg from its normal (cosine 0.14): too
    oblique to paint (MIN_COS_INCIDENCE), while nearer ground (cosine over 0.2) is."""
    m = _memory()
    cam = _camera([0.0, 0.0, 3.0], [25.0, 25.0, 0.0], f=150.0)
    m.memory.paint(_flat((90, 200, 90)), cam, distances(scene_views, cam), 5.0)
    assert not m.seen[_cell(m, 15.0, 15.0)]
    assert m.seen[_cell(m, 7.0, 7.0)]  # 9.9 m away: cosine 0.29


def test_export_ortho_paints_a_3d_tiles_scene_as_its_model(survey, tmp_path):
    """The same 3 s survey, its scene the sample model wrapped as 3D Tiles: the tiles the
    frames need are frozen and painted, and building 5's roof lands where the GLB scene puts
    it (the orthophotos agree cell for cell where both saw)."""
    import shutil

    from app.scene.tiles import write as tjw
    from app.simulate.sample import SAMPLE_DIR, SAMPLE_ORIGIN

    shutil.copytree(survey.parent, tmp_path / "s")  # the tileset goes beside its manifest
    manifest = tmp_path / "s" / survey.name
    tiles = tmp_path / "s" / "stadium"
    tiles.mkdir()
    shutil.copy(SAMPLE_DIR / "scene.glb", tiles / "scene.glb")
    root = {
        "boundingVolume": {"box": tjw.box_of([-300, -300, -5], [300, 300, 60])},
        "geometricError": 0.0,
        "refine": "REPLACE",
        "transform": tjw.column_major(tjw.enu_to_ecef_matrix(LocalFrame(*SAMPLE_ORIGIN))),
        "content": {"uri": "scene.glb"},
    }
    tjw.write_json(
        tiles / "tileset.json", {"asset": {"version": "1.1"}, "geometricError": 50.0, "root": root}
    )
    text = manifest.read_text()
    start = text.index("[scene]")
    end = text.index("\n[", start + 1) + 1
    lat, lon, h = SAMPLE_ORIGIN
    tiled = tmp_path / "s" / "tiled.toml"
    tiled.write_text(
        text[:start]
        + f'[origin]\nlat = {lat}\nlon = {lon}\nh = {h}\n\n[scene]\npath = "stadium/tileset.json"\n\n'
        + text[end:]
    )
    outs = []
    for m, name in ((manifest, "glb.tif"), (tiled, "tiles.tif")):
        out = tmp_path / name
        args = ["export", "ortho", str(m), "--out", str(out), "--source", "truth", "--gsd", "0.5"]
        args += ["--area", str(_area_geojson(tmp_path))]
        subprocess.run([sys.executable, "-m", "app", *args], check=True, capture_output=True)
        with rasterio.open(out) as src:
            outs.append(src.read().transpose(1, 2, 0).astype(int))
    glb, tiled_rgba = outs
    both = (glb[..., 3] == 255) & (tiled_rgba[..., 3] == 255)
    assert both.sum() > 10_000
    assert np.median(np.abs(glb[both, :3] - tiled_rgba[both, :3])) <= 2


def _area_geojson(folder):
    """A GeoJSON polygon over the sample site's middle (lat/lon), written once."""
    import json

    from app.simulate.sample import SAMPLE_ORIGIN

    path = folder / "area.geojson"
    if not path.exists():
        frame = LocalFrame(*SAMPLE_ORIGIN)
        ll = frame.enu_to_geodetic(np.array([[-120.0, -100.0, 0.0], [120.0, 100.0, 0.0]]))
        (la0, lo0, _), (la1, lo1, _) = ll
        ring = [[lo0, la0], [lo1, la0], [lo1, la1], [lo0, la1], [lo0, la0]]
        path.write_text(json.dumps({"type": "Polygon", "coordinates": [ring]}))
    return path


def test_export_ortho_registers_a_keyframe_a_second_unless_told(survey, tmp_path):
    """`export ortho --source registered` registers keyframes ORTHO_KEYFRAMES_S apart (a survey's
    orthophoto keeps its goal at half the registration's time: docs/ACCURACY.md); --keyframes-s
    sets it, and `export model` keeps registration's own spacing."""
    from app.cli.export import keyframes_s
    from app.cli.parser import build_parser
    from app.core.constants import KEYFRAMES_S, ORTHO_KEYFRAMES_S
    from app.register.solve import keyframe_indices
    from app.session import open_session

    parser = build_parser()
    common = [str(survey), "--out", str(tmp_path / "x.tif")]
    assert keyframes_s(parser.parse_args(["export", "ortho", *common])) == ORTHO_KEYFRAMES_S
    assert keyframes_s(parser.parse_args(["export", "model", *common])) is None
    told = parser.parse_args(["export", "ortho", *common, "--keyframes-s", "0.25"])
    assert keyframes_s(told) == 0.25
    with pytest.raises(SystemExit):
        parser.parse_args(["export", "ortho", *common, "--keyframes-s", "0"])

    media_s = np.asarray(open_session(survey).video.pts_s, np.float64)
    expected = len(keyframe_indices(media_s, ORTHO_KEYFRAMES_S))
    assert expected < len(keyframe_indices(media_s, KEYFRAMES_S))
    out = tmp_path / "registered.tif"
    args = ["export", "ortho", str(survey), "--out", str(out), "--source", "registered"]
    done = subprocess.run([sys.executable, "-m", "app", *args, "--gsd", "0.5"], capture_output=True)
    assert done.returncode == 0, done.stderr.decode()
    assert re.search(rf"registered \d+ of {expected} keyframes", done.stderr.decode())
    assert out.is_file()
