"""3D Tiles: tilesets written here for every feature the reader handles, opened, streamed and
drawn; a video frame projected from a known pose must land on the facade of each exactly where
the frustum says (the same check as test_render_projection's checkerboard)."""

from __future__ import annotations

import functools
import http.server
import threading
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.geodesy.enu import LocalFrame
from app.scene import shapes
from app.scene.mesh import MeshData
from app.scene.tiles import fetch
from app.scene.tiles import write as tjw
from app.scene.tiles.stream import TileStream, TileView
from app.scene.tiles.tileset import Tileset, TilesetError
from app.simulate import tileset as tw
from tests.test_render_projection import (
    BLOCK,
    VIDEO_H,
    VIDEO_W,
    WALL_Y,
    checkerboard,
    hit_plane,
    projector,
    view_camera,
)

FRAME = LocalFrame(47.0, 8.0, 400.0)
WALL = shapes.quad([-20, WALL_Y, 0], [40, 0, 0], [0, 0, 20])  # the facade, ENU m
LEFT = shapes.quad([-20, WALL_Y, 0], [20, 0, 0], [0, 0, 20])
RIGHT = shapes.quad([0, WALL_Y, 0], [20, 0, 0], [0, 0, 20])
NEAR_WALL = shapes.quad([-20, 10.0, 0], [40, 0, 0], [0, 0, 20])  # would hide the facade if drawn
LO, HI = np.array([-25.0, 5.0, -1.0]), np.array([25.0, 25.0, 21.0])  # encloses both


def ecef_b3dm(shape, rtc_enu=(0.0, WALL_Y, 10.0)) -> bytes:
    """b3dm whose vertices are ECEF relative to RTC_CENTER (no tileset transform)."""
    rtc = FRAME.enu_to_ecef(np.asarray(rtc_enu, np.float64))
    return tw.b3dm(tw.glb(FRAME.enu_to_ecef(shape.vertices) - rtc, shape.faces), rtc)


def region_tile(shape_bytes_name: str, error: float = 0.0, **extra) -> dict:
    return {
        "boundingVolume": {"region": tw.region_of(FRAME, LO, HI)},
        "geometricError": error,
        "content": {"uri": shape_bytes_name},
        **extra,
    }


def enu_box_tile(uri: str | None, error: float = 0.0, **extra) -> dict:
    node = {"boundingVolume": {"box": tjw.box_of(LO, HI)}, "geometricError": error, **extra}
    if uri:
        node["content"] = {"uri": uri}
    return node


def tileset_doc(root: dict, version: str = "1.0") -> dict:
    root.setdefault("refine", "REPLACE")
    return {"asset": {"version": version}, "geometricError": 500.0, "root": root}


# -- the tilesets --------------------------------------------------------------------------------


def b3dm_rtc_region(d: Path) -> Path:
    (d / "wall.b3dm").write_bytes(ecef_b3dm(WALL))
    return tjw.write_json(d / "tileset.json", tileset_doc(region_tile("wall.b3dm")))


def glb_box_transform(d: Path, draco: bool = False) -> Path:
    (d / "wall.glb").write_bytes(tw.glb(WALL.vertices, WALL.faces, draco=draco))
    root = enu_box_tile("wall.glb", transform=tjw.column_major(tjw.enu_to_ecef_matrix(FRAME)))
    return tjw.write_json(d / "tileset.json", tileset_doc(root, "1.1"))


def glb_draco(d: Path) -> Path:
    return glb_box_transform(d, draco=True)


def external(d: Path) -> Path:
    shift = np.eye(4)
    shift[:3, 3] = (5.0, 0.0, 0.0)  # the external root moves its content 5 m east ...
    (d / "sub").mkdir()
    (d / "sub" / "wall.glb").write_bytes(
        tw.glb(WALL.vertices - [5.0, 0.0, 0.0], WALL.faces)
    )  # ... back to the wall
    tjw.write_json(
        d / "sub" / "tileset.json",
        tileset_doc(enu_box_tile("wall.glb", transform=tjw.column_major(shift))),
    )
    root = enu_box_tile(
        None,
        100.0,
        transform=tjw.column_major(tjw.enu_to_ecef_matrix(FRAME)),
        children=[enu_box_tile("sub/tileset.json", 50.0)],
    )
    return tjw.write_json(d / "tileset.json", tileset_doc(root))


def replace(d: Path) -> Path:
    (d / "coarse.b3dm").write_bytes(ecef_b3dm(NEAR_WALL))
    (d / "fine.b3dm").write_bytes(ecef_b3dm(WALL))
    root = region_tile("coarse.b3dm", 200.0, refine="REPLACE", children=[region_tile("fine.b3dm")])
    return tjw.write_json(d / "tileset.json", tileset_doc(root))


def add(d: Path) -> Path:
    (d / "left.b3dm").write_bytes(ecef_b3dm(LEFT))
    (d / "right.b3dm").write_bytes(ecef_b3dm(RIGHT))
    root = region_tile("left.b3dm", 200.0, refine="ADD", children=[region_tile("right.b3dm")])
    return tjw.write_json(d / "tileset.json", tileset_doc(root))


def composite(d: Path) -> Path:
    (d / "both.cmpt").write_bytes(
        tw.cmpt([ecef_b3dm(LEFT), tw.other_tile(b"i3dm"), ecef_b3dm(RIGHT, (10.0, WALL_Y, 0.0))])
    )
    return tjw.write_json(d / "tileset.json", tileset_doc(region_tile("both.cmpt")))


def implicit_quadtree(d: Path) -> Path:
    """Root box 80 m x 80 m; the level-1 tiles (0, 1) and (1, 1) (x < 0 and x > 0, y > 0) hold
    the facade's halves; the root and the other level-1 tiles have no content."""
    (d / "content").mkdir()
    (d / "subtrees").mkdir()
    (d / "content" / "1_0_1.glb").write_bytes(tw.glb(LEFT.vertices, LEFT.faces))
    (d / "content" / "1_1_1.glb").write_bytes(tw.glb(RIGHT.vertices, RIGHT.faces))
    tiles = {(0, (0, 0))} | {(1, (x, y)) for x in (0, 1) for y in (0, 1)}
    (d / "subtrees" / "0.0.0.subtree").write_bytes(
        tw.subtree(2, 2, tiles, {(1, (0, 1)), (1, (1, 1))})
    )
    root = {
        "boundingVolume": {"box": [0, 0, 10, 40, 0, 0, 0, 40, 0, 0, 0, 11]},
        "geometricError": 100.0,
        "refine": "REPLACE",
        "transform": tjw.column_major(tjw.enu_to_ecef_matrix(FRAME)),
        "content": {"uri": "content/{level}_{x}_{y}.glb"},
        "implicitTiling": {
            "subdivisionScheme": "QUADTREE",
            "subtreeLevels": 2,
            "availableLevels": 2,
            "subtrees": {"uri": "subtrees/{level}.{x}.{y}.subtree"},
        },
    }
    return tjw.write_json(
        d / "tileset.json", {"asset": {"version": "1.1"}, "geometricError": 200.0, "root": root}
    )


def glb_y_up_ecef_root(d: Path) -> Path:
    """A glb whose root node carries the ECEF offset in glTF's Y-up axes (as the official 3D
    Tiles tools write it): only the Y-up -> Z-up rule puts it back on the facade."""
    centre = FRAME.enu_to_ecef(np.array([0.0, WALL_Y, 10.0]))
    node = np.eye(4)
    node[:3, 3] = tw.Z_UP_TO_Y_UP @ centre
    (d / "wall.glb").write_bytes(
        tw.glb(FRAME.enu_to_ecef(WALL.vertices) - centre, WALL.faces, node_matrix=node)
    )
    return tjw.write_json(d / "tileset.json", tileset_doc(region_tile("wall.glb")))


TILESETS = [
    b3dm_rtc_region,
    glb_box_transform,
    glb_draco,
    external,
    replace,
    add,
    composite,
    implicit_quadtree,
    glb_y_up_ecef_root,
]


def open_tileset(location: str) -> Tileset:
    return Tileset(location, FRAME)


def assert_video_lands_on_wall(ctx, tileset: Tileset) -> None:
    from app.core.settings import ProjectionSettings
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer

    r = FusionRenderer(ctx, MeshData(tilesets=[tileset]))
    try:
        image = checkerboard()
        r.set_video_frame(image)
        proj = projector()
        r.set_projector(proj)
        view = view_camera([4, 2, 12], [0, WALL_Y, 10])
        out = render_to_array(r, view, ProjectionSettings(alpha=1.0)).astype(int).reshape(-1, 3)
        world, _ = hit_plane(view, 1, WALL_Y)
        uv, depth = proj.project(world)
        inside_block = np.abs((uv % BLOCK) - BLOCK / 2) <= BLOCK / 2 - 1.0
        on_wall = (np.abs(world[:, 0]) < 19.5) & (world[:, 2] > 0.5) & (world[:, 2] < 19.5)
        ok = (
            (depth > 0)
            & np.all(inside_block, axis=1)
            & np.all((uv >= 0) & (uv < [VIDEO_W, VIDEO_H]), axis=1)
            & on_wall
        )
        assert ok.sum() > 4000
        texel = np.floor(uv[ok]).astype(int)
        expected = image[texel[:, 1], texel[:, 0]].astype(int)
        diff = np.abs(out[ok] - expected).max(axis=1)
        assert diff.max() <= 1, f"{(diff > 1).sum()} of {ok.sum()} pixels off, worst {diff.max()}"
    finally:
        r.release()


@pytest.mark.gl
@pytest.mark.parametrize("make", TILESETS, ids=[f.__name__ for f in TILESETS])
def test_video_lands_on_the_facade_of_each_tileset(gl_ctx, tmp_path, make):
    assert_video_lands_on_wall(gl_ctx, open_tileset(str(make(tmp_path))))


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def http_root(tmp_path):
    """A local HTTP server over tmp_path: (base URL, folder)."""
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_Quiet, directory=str(tmp_path))
    )
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}/", tmp_path
    server.shutdown()
    server.server_close()


@pytest.mark.gl
@pytest.mark.parametrize("make", [external, implicit_quadtree, composite], ids=lambda f: f.__name__)
def test_a_tileset_served_over_http_is_read_like_a_folder(gl_ctx, http_root, make):
    base, folder = http_root
    make(folder)
    assert_video_lands_on_wall(gl_ctx, open_tileset(base + "tileset.json"))


# -- selection, streaming and damage (no GL) -------------------------------------------------


def settle(stream: TileStream, view: TileView, rounds: int = 2000):
    """Select until complete, marking decoded tiles ready as the GPU layer would (condition-
    waited, not timed)."""
    for _ in range(rounds):
        sel = stream.select(view)
        for item in stream.take_loaded():
            if item.mesh is not None:
                stream.mark_ready(item.tile)
        if sel.complete:
            return sel
        stream.wait_loaded(timeout_s=1.0)  # a worker's result, or the next round
    raise AssertionError("selection never completed")


def test_screen_space_error_picks_the_level_of_detail_and_culls(tmp_path):
    stats = tw.write_city(
        tmp_path / "city",
        (47.0, 8.0, 400.0),
        size_m=400.0,
        levels=3,
        blocks_per_leaf=4,
        leaf_detail=2,
    )
    ts = Tileset(str(stats.path), FRAME)
    stream = TileStream(ts)
    try:
        intr = Intrinsics.from_fov(1280, 720, 60)
        far_eye = np.array([0.0, -20000.0, 3000.0])
        far = Camera.create(intr, far_eye, look_at_quat(far_eye, [0, 0, 0]), near=1.0, far=1e5)
        sel = settle(stream, TileView.of(far))
        assert [t.depth for t in sel.tiles] == [
            0
        ]  # root error 25 m at 20 km: 25 * 1108 / 20000 < 16 px
        # The root refines where its error reaches 16 px on screen: at the distance d from its
        # bounding sphere's surface where error * fy / d = 16 (fy = 640 / tan 30 deg = 1108.5 px).
        fy = 640.0 / np.tan(np.radians(30.0))
        d16 = ts.root.geometric_error * fy / 16.0 + ts.root.radius
        for factor, refined in ((1.15, False), (0.85, True)):
            eye = ts.root.center + np.array([0.0, -factor * d16, 0.0])
            cam = Camera.create(intr, eye, look_at_quat(eye, ts.root.center), near=1.0, far=1e5)
            depths = {t.depth for t in settle(stream, TileView.of(cam)).tiles}
            assert (depths != {0}) is refined, f"at {factor} x the 16 px distance: depths {depths}"
        near_eye = np.array([-150.0, -150.0, 30.0])
        near = Camera.create(
            intr, near_eye, look_at_quat(near_eye, [-150, 0, 0]), near=1.0, far=1e5
        )
        sel = settle(stream, TileView.of(near))
        depths = sorted({t.depth for t in sel.tiles})
        assert depths == [2]  # full detail around the camera
        assert len(sel.tiles) < 16  # tiles behind the camera and beside the frustum are culled

        # Culling, checked without the selector's own test: points spread over each leaf's
        # bounding sphere, projected by the camera; a drawn leaf shows some, and a leaf none of
        # whose points the image shows is not drawn.
        def seen(tile) -> bool:
            i = np.arange(200) + 0.5
            z, phi = 1 - 2 * i / 200, np.pi * (1 + 5**0.5) * i
            r = np.sqrt(1 - z**2)
            pts = tile.center + tile.radius * np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
            uv, depth = near.project(np.vstack([pts, tile.center]))
            inside = (
                (depth > near.near)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] <= 1280)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] <= 720)
            )
            return bool(inside.any())

        leaves = [t for t in _walk(ts.root) if t.depth == 2]
        drawn = {t.id for t in sel.tiles}
        assert all(seen(t) for t in sel.tiles)
        unseen = [t for t in leaves if not seen(t)]
        assert unseen and not drawn & {t.id for t in unseen}
        # REPLACE: a drawn tile never shares the screen with its own ancestor
        ids = {t.id for t in sel.tiles}
        for tile in sel.tiles:
            assert not ids & {t.id for t in _walk(tile) if t is not tile}
    finally:
        stream.close()


def _walk(tile):
    yield tile
    for child in tile.children or []:
        yield from _walk(child)


def test_select_never_waits_for_a_tile(tmp_path):
    """With a decoder stuck on I/O, select returns at once, incomplete, drawing nothing, and
    completes once the decoder is let go."""
    path = b3dm_rtc_region(tmp_path)
    gate = threading.Event()

    def slow_decode(tileset, tile, skipped):
        from app.scene.tiles.stream import decode_tile

        gate.wait()
        return decode_tile(tileset, tile, skipped)

    stream = TileStream(Tileset(str(path), FRAME), decode=slow_decode)
    try:
        view = TileView.of(view_camera([4, 2, 12], [0, WALL_Y, 10]))
        for _ in range(20):
            sel = stream.select(view)
            assert not sel.complete and sel.tiles == []
        gate.set()
        sel = settle(stream, view)
        assert len(sel.tiles) == 1
    finally:
        gate.set()
        stream.close()


def test_damaged_and_unsupported_content_is_counted_never_fatal(tmp_path):
    (tmp_path / "good.b3dm").write_bytes(ecef_b3dm(WALL))
    (tmp_path / "cut.b3dm").write_bytes(ecef_b3dm(WALL)[:60])
    (tmp_path / "points.pnts").write_bytes(tw.other_tile(b"pnts"))
    ktx = tw.glb(WALL.vertices, WALL.faces, extensions_required=("EXT_meshopt_compression",))
    (tmp_path / "meshopt.glb").write_bytes(ktx)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    (tmp_path / "ktx2.glb").write_bytes(
        tw.glb(
            FRAME.enu_to_ecef(WALL.vertices),
            WALL.faces,
            uvs=uv,
            texture_rgb=np.zeros((4, 4, 3), np.uint8),
            ktx2=True,
        )
    )
    kids = [
        region_tile(n)
        for n in ("good.b3dm", "cut.b3dm", "points.pnts", "meshopt.glb", "missing.b3dm", "ktx2.glb")
    ]
    path = tjw.write_json(
        tmp_path / "tileset.json",
        tileset_doc(
            enu_box_tile(None, 100.0, transform=tjw.column_major(np.eye(4)), children=kids)
            | {"boundingVolume": {"region": tw.region_of(FRAME, LO, HI)}}
        ),
    )
    stream = TileStream(Tileset(str(path), FRAME))
    try:
        sel = settle(stream, TileView.of(view_camera([4, 2, 12], [0, WALL_Y, 10])))
        assert stream.failures == 2  # the truncated b3dm and the missing file
        assert any("cut.b3dm" in e for e in stream.errors) and any(
            "missing.b3dm" in e and "does not exist" in e for e in stream.errors
        )
        assert stream.skipped.counts["point clouds (pnts)"] == 1
        assert stream.skipped.counts["content needing EXT_meshopt_compression"] == 1
        assert stream.skipped.counts["KTX2/Basis textures (drawn untextured)"] == 1
        assert len(sel.tiles) == 6  # all drawn, three of them empty, the KTX2 one untextured
    finally:
        stream.close()


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"asset": {"version": "1.0"}}, "root"),
        ({"asset": {"version": "1.0"}, "root": {"geometricError": 1}}, "root.boundingVolume"),
        (
            {
                "asset": {"version": "1.0"},
                "root": {"boundingVolume": {"box": [0] * 12}, "refine": "SOMETIMES"},
            },
            "root.refine",
        ),
        (
            {
                "asset": {"version": "1.0"},
                "root": {"boundingVolume": {"box": [0] * 12}, "transform": [1, 2]},
            },
            "root.transform",
        ),
        (
            {
                "asset": {"version": "1.0"},
                "root": {
                    "boundingVolume": {"box": [0] * 12},
                    "children": [{"boundingVolume": {"cone": 1}}],
                },
            },
            "root.children[0].boundingVolume",
        ),
    ],
)
def test_a_broken_tileset_names_the_file_and_the_key(tmp_path, doc, field):
    path = tjw.write_json(tmp_path / "tileset.json", doc)
    with pytest.raises(TilesetError) as err:
        Tileset(str(path), FRAME)
    assert err.value.field == field and str(path) in str(err.value)


@pytest.mark.gl
def test_gpu_cache_stays_under_its_cap_evicting_least_recently_used(gl_ctx, tmp_path):
    from app.render.gpu_scene import GpuScene

    stats = tw.write_city(
        tmp_path / "city",
        (47.0, 8.0, 400.0),
        size_m=400.0,
        levels=3,
        blocks_per_leaf=4,
        leaf_detail=4,
    )
    ts = Tileset(str(stats.path), FRAME)
    scene = GpuScene(gl_ctx, MeshData(tilesets=[ts]))
    try:
        intr = Intrinsics.from_fov(640, 360, 60)
        layer = scene.tilesets[0]

        def fly(x):
            eye = np.array([x, -120.0, 25.0])
            cam = Camera.create(intr, eye, look_at_quat(eye, [x, 100, 0]), near=1.0, far=3000.0)
            assert scene.settle([(cam, None, "view")], timeout_s=120)
            drawn = scene.drawables(cam, None, "view")
            scene.update()
            return drawn

        west = fly(-150.0)
        layer.cache_bytes = int(layer.bytes_held * 1.2)  # room for the west half and a little more
        for x in (150.0, -150.0):  # the east half, then back west
            drawn = fly(x)
            resident = {q for _, ps in layer.resident.values() for q in ps}
            assert drawn and all(p in resident for p in drawn)  # what is drawn is never evicted
            assert layer.bytes_held <= max(layer.cache_bytes, sum(p.nbytes for p in drawn))
        assert layer.evictions > 0
        assert not set(map(id, west)) & set(
            map(id, drawn)
        )  # the west tiles were evicted and loaded again
    finally:
        scene.release()


def test_ground_heights_under_a_track_come_from_a_tileset_as_from_its_model(tmp_path):
    """height = "ground" on the sample stadium as 3D Tiles gives the camera the same heights as
    on the GLB it was made from (the tiles under the track are read on the CPU)."""
    from app.session import open_session
    from app.simulate.sample import SAMPLE_DIR
    from tools.gis_sessions import tiles

    tiled = open_session(tiles(tmp_path))
    model = open_session(SAMPLE_DIR / "session.toml")
    t = np.linspace(model.gnss.t[0], model.gnss.t[-1], 50)
    np.testing.assert_allclose(
        tiled.positions().geodetic_at(t), model.positions().geodetic_at(t), atol=1e-6
    )
    assert not any("off the model" in w for w in tiled.messages.items)


def test_a_worker_survives_any_failure_of_one_tile(tmp_path):
    """An unexpected exception while decoding (here a KeyError) fails that tile only: it is
    counted and named, drawn empty, and the selection still completes."""
    path = b3dm_rtc_region(tmp_path)

    def broken(tileset, tile, skipped):
        raise KeyError("accessors")

    stream = TileStream(Tileset(str(path), FRAME), decode=broken, workers=1)
    try:
        sel = settle(stream, TileView.of(view_camera([4, 2, 12], [0, WALL_Y, 10])))
        assert stream.failures == 1 and "wall.b3dm: KeyError" in stream.errors[0]
        assert len(sel.tiles) == 1
    finally:
        stream.close()


class _Keyed(_Quiet):
    """Answers 403 without the key, and for anything but the root without the session the
    root's children name (as Google Photorealistic 3D Tiles does); keeps every request."""

    KEY, SESSION = "k3y-Secret_9", "s3ss10n"
    seen: list[str] = []

    def do_GET(self):  # noqa: N802 - http.server's name
        parts = urllib.parse.urlsplit(self.path)
        query = dict(urllib.parse.parse_qsl(parts.query))
        self.seen.append(self.path)
        root = parts.path == "/tileset.json"
        if query.get("key") != self.KEY or (not root and query.get("session") != self.SESSION):
            self.send_error(403, "no key, or no session")
            return
        self.path = parts.path
        super().do_GET()


@pytest.mark.gl
def test_a_keyed_tileset_sends_its_key_and_session_to_every_child_and_never_shows_it(
    gl_ctx, tmp_path
):
    """The root asked for with ?key=K names its children with ?session=S: every request carries
    both (a child inheriting what its parent's URL carried), the video lands on the wall as from
    a folder, and a child that fails is named without the key."""
    external(tmp_path)
    doc = (tmp_path / "tileset.json").read_text()
    (tmp_path / "tileset.json").write_text(
        doc.replace('"sub/tileset.json"', f'"sub/tileset.json?session={_Keyed.SESSION}"')
    )
    _Keyed.seen = []
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_Keyed, directory=str(tmp_path))
    )
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    try:
        assert_video_lands_on_wall(gl_ctx, open_tileset(f"{base}tileset.json?key={_Keyed.KEY}"))
        assert len(_Keyed.seen) == 3  # the root, the external tileset, the wall
        assert all(f"key={_Keyed.KEY}" in p for p in _Keyed.seen)
        assert all(f"session={_Keyed.SESSION}" in p for p in _Keyed.seen[1:])
        # a child on another host gets no key; a missing one is named without it
        assert fetch.resolve(f"{base}tileset.json?key=K", "http://127.0.0.2/a.glb") == (
            "http://127.0.0.2/a.glb"
        )
        with pytest.raises(fetch.FetchError) as err:
            fetch.read(fetch.resolve(f"{base}tileset.json?key={_Keyed.KEY}", "gone.glb"))
        assert _Keyed.KEY not in str(err.value) and "key=***" in str(err.value)
        assert _Keyed.KEY not in fetch.display_name(f"{base}tileset.json?key={_Keyed.KEY}")
    finally:
        server.shutdown()
        server.server_close()
