"""The world streams in (issue 48): the viewer opens a clip at once on the flat ground while a
loopback tile server holds every request, keeps drawing, and draws the world's imagery on its
terrain once the server answers; the builder hands a coarse level over before the full one,
and stops when cancelled. Tiles come from tests/test_world.py's synthetic world."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
import rasterio
from OpenGL import GL
from PIL import Image

from app.core.messages import Messages
from app.geodesy import geoid
from app.geodesy.enu import LocalFrame
from app.render import staging
from app.render.primitives import interleave
from app.render.staging import mip_chain
from app.scene.mesh import MeshData, Primitive
from app.world import tiles as tm
from app.world.background import COARSE_LEVELS, WorldBuilder
from app.world.build import WorldRequest, world_layer
from tests import test_world
from tests.conftest import run_viewer, state_camera
from tests.test_world import IMAGERY_Z, LAT0, LON0, TRACK, _settings, _world, height
from tests.waiting import wait_until

# test_world's fixtures: the test's own settings, tile cache and no default world (autouse);
# the synthetic world's tile server; a 4 s DJI clip over it
own_folders = test_world._own_folders
tiles = test_world.server
dji_clip = test_world.drone_clip


def _request(server: test_world.TileServer) -> WorldRequest:
    n = len(TRACK)
    return WorldRequest(
        world_layer(_world(server)), TRACK[:, 0], TRACK[:, 1], np.full(n, 700.0), 600.0, 300.0
    )


def _read(path) -> dict | None:
    """A state file the viewer wrote, None until it is there whole."""
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def _zoom(layer) -> int:
    """The imagery zoom a built DEM layer's orthophoto says it was read at."""
    with rasterio.open(layer.ortho) as src:
        return int(src.tags()["SOURCE"].rsplit("zoom ", 1)[1])


def test_the_builder_hands_a_coarse_level_before_the_full_one(tiles):
    server = tiles
    server.gate = threading.Event()
    levels = []
    builder = WorldBuilder([_request(server)], Messages(), levels.append).start()
    try:
        # held: the coarse level's tiles are asked for, none is answered, nothing handed over
        assert wait_until(lambda: len(server.log) > 0 and builder.progress.tiles > 0)
        p = builder.progress
        assert (p.level, p.done, levels) == ("coarse", 0, [])
    finally:
        server.gate.set()
    assert builder.wait(60) and builder.progress.level == "done"
    assert [lv.coarse for lv in levels] == [True, False]
    coarse, full = (lv.layers[0] for lv in levels)
    # the full level at the finest zoom the server has (16 for 100 m above ground, 0.3 m asked),
    # the coarse one COARSE_LEVELS above it: 1/64 of the tiles, and fewer requests
    assert _zoom(full) == IMAGERY_Z and _zoom(coarse) == IMAGERY_Z - COARSE_LEVELS
    coarse_requests = [p for p, _, _ in server.log if p.startswith(f"/img/{IMAGERY_Z - 3}/")]
    full_requests = [p for p, _, _ in server.log if p.startswith(f"/img/{IMAGERY_Z}/")]
    assert 0 < len(coarse_requests) * 4 < len(full_requests)


def test_a_cancelled_build_hands_nothing_over(tiles):
    server = tiles
    server.gate = threading.Event()
    levels = []
    builder = WorldBuilder([_request(server)], Messages(), levels.append).start()
    assert wait_until(lambda: len(server.log) > 0)
    builder.cancel()
    server.gate.set()
    assert builder.wait(60)
    assert levels == [] and builder.progress.level == "cancelled"


def test_a_mip_chain_halves_as_gl_sizes_levels_and_averages_2x2():
    img = np.arange(5 * 7 * 4, dtype=np.uint8).reshape(5, 7, 4)
    chain = mip_chain(img)
    assert [lv.shape[:2] for lv in chain] == [(5, 7), (2, 3), (1, 1)]
    want = img[:2, :2].astype(int).sum(axis=(0, 1))
    assert np.array_equal(chain[1][0, 0], (want + 2) // 4)


@pytest.mark.gl
def test_a_staged_scene_is_uploaded_in_pieces_and_whole(gl_ctx, monkeypatch):
    monkeypatch.setattr(staging, "PIECE_BYTES", 4096)  # many pieces of a small scene
    rng = np.random.default_rng(3)
    n = 500
    prim = Primitive(
        rng.random((n, 3)).astype(np.float32), np.ones((n, 4), np.float32),
        rng.integers(0, n, (300, 3)).astype(np.uint32), rng.random((n, 2)).astype(np.float32),
        rng.integers(0, 255, (61, 90, 4), dtype=np.uint8), "ortho",
    )  # fmt: skip
    prepared = staging.prepare(MeshData([prim]))
    staged = staging.StagedScene(gl_ctx, prepared, 1.0)
    steps = 1
    while not staged.step(0.0):  # a budget of nothing: one piece a step
        steps += 1
    assert steps == staged.pieces > 20
    (gpu,) = staged.primitives
    try:
        assert np.array_equal(np.frombuffer(gpu.vbo.read(), np.float32), interleave(prim).ravel())
        assert np.array_equal(np.frombuffer(gpu.ibo.read(), np.uint32), prim.indices.ravel())
        gpu.texture.use(0)
        for level, want in enumerate(prepared[0].levels):  # 61 x 90 down to 1 x 1, as GL sizes
            got = GL.glGetTexImage(GL.GL_TEXTURE_2D, level, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)
            assert np.array_equal(np.frombuffer(got, np.uint8).reshape(want.shape), want), level
        assert len(prepared[0].levels) == 7 and gl_ctx.error == "GL_NO_ERROR"
    finally:
        staged.release()


@pytest.mark.gl
def test_the_viewer_draws_while_the_server_holds_then_the_world(display, tiles, dji_clip, tmp_path):
    server = tiles
    _settings(tmp_path, server.base)
    server.gate = threading.Event()
    held, final, shot = tmp_path / "held.json", tmp_path / "world.json", tmp_path / "world.png"
    script = tmp_path / "script.txt"
    script.write_text(
        f"""0.0 clock 0.0333333
0.0 panels off
0.0 lines off
0.0 project off
1.0 state {held}
1.0 wait world
1.1 state {final}
1.1 screenshot {shot}
1.2 quit
"""
    )
    result: dict = {}
    viewer = threading.Thread(
        target=lambda: result.update(
            run=run_viewer(
                display,
                str(dji_clip),
                "--world",
                "local",
                "--script",
                str(script),
                "--size",
                "640x360",
                config_home=tmp_path / "config",
            )
        ),  # fmt: skip
        daemon=True,
    )
    viewer.start()
    try:
        # a second of frames drawn with every tile request held: the frame loop waits on nothing
        assert wait_until(lambda: _read(held) is not None, 180), "no frame drawn while held"
        state = _read(held)
        answered = server.gate.is_set()
    finally:
        server.gate.set()
    viewer.join(300)
    run = result["run"]
    assert run.returncode == 0, run.stderr[-3000:]
    assert not answered and state["frames_drawn"] >= 30 and server.log
    w = state["world"]
    assert w["shown"] is None and w["building"] == "coarse" and w["done"] == 0
    assert w["status"] == f"world local: fetching the coarse level: {w['tiles']} tiles (0 done)"
    assert w["tiles"] > 0 and state["layers"] == []  # the flat ground, nothing named yet
    after = json.loads(final.read_text())
    w = after["world"]
    assert w["shown"] == "full" and w["done_all"] and w["swaps"] >= 1, w
    assert after["errors"] == [] and after["layers"] == ["world:world:local"]
    # the full level's imagery where the window camera sees the terrain: at ground points in
    # view, texel (column, row) = (R, G) / B x 160, blue 10 x zoom 16, whatever the shading
    cam = state_camera(after["window_camera"])
    frame = LocalFrame(LAT0, LON0, 0.0)  # the clip's frame: heights above take-off, ground 0
    e, n = np.meshgrid(np.linspace(-150, 250, 21), np.linspace(0, 400, 21))
    lat, lon, _ = frame.enu_to_geodetic(np.column_stack([e.ravel(), n.ravel(), 0 * e.ravel()])).T
    ell = geoid.to_ellipsoidal(height(lat, lon), lat, lon, "egm2008")
    first = geoid.to_ellipsoidal(height(np.array([LAT0]), np.array([LON0])), LAT0, LON0, "egm2008")
    # the terrain is drawn with its ground under the first fix at the take-off height (0 m)
    enu = frame.geodetic_to_enu(lat, lon, ell - first)
    px, depth = cam.project(enu)
    x, y = tm.to_mercator(lat, lon)
    res = tm.tile_span_m(IMAGERY_Z) / 256
    col = np.floor((x + tm.HALF_WORLD_M) / res).astype(int) % 256
    row = np.floor((tm.HALF_WORLD_M - y) / res).astype(int) % 256
    img = np.asarray(Image.open(shot).convert("RGB"), float)
    h, w_ = img.shape[:2]
    inside = (
        (depth > 0)
        & (px[:, 0] > 0.2 * w_)
        & (px[:, 0] < 0.8 * w_)
        & (px[:, 1] > 0.2 * h)
        & (px[:, 1] < 0.8 * h)
    )
    safe = (col > 20) & (col < 235) & (row > 20) & (row < 235)
    pick = np.flatnonzero(inside & safe)
    assert len(pick) >= 10
    rgb = img[px[pick, 1].astype(int), px[pick, 0].astype(int)]
    seen_col, seen_row = 160 * rgb[:, 0] / rgb[:, 2], 160 * rgb[:, 1] / rgb[:, 2]
    near = (np.abs(seen_col - col[pick]) <= 3) & (np.abs(seen_row - row[pick]) <= 3)
    assert near.mean() >= 0.9, np.column_stack([seen_col, col[pick], seen_row, row[pick]])
    assert (rgb[:, 2] > 0.8 * 160).all()  # zoom 16's blue, lit (the coarse level's is 130)
