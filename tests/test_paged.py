"""The memory in pages at the video's ground sampling (app.export.sampling, app.export.paged):
texel sizes derived by hand, triangles cut without moving their colours, pages evicted least
recently used and read back so that a memory held within a tight bound paints exactly what an
unbounded one does, each texel with the colour its frame has where the frustum puts it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.export.atlas import chart_sizes, packed, triangles_of
from app.export.paged import PagedMemory
from app.export.sampling import COARSEST_M, texel_targets
from app.scene import shapes
from app.scene.mesh import MeshData, Primitive

F = 500.0


def _camera(eye, target, w=960, h=540) -> Camera:
    return Camera.create(
        Intrinsics(w, h, F, F, w / 2, h / 2), np.asarray(eye, float), look_at_quat(eye, target)
    )


def _tiny(centre, normal_axis: int, size=0.01) -> np.ndarray:
    """A small triangle around centre, in the plane across axis normal_axis."""
    a, b = [k for k in range(3) if k != normal_axis]
    tri = np.tile(np.asarray(centre, float), (3, 1))
    tri[1, a] += size
    tri[2, b] += size
    return tri


def test_the_texel_is_what_a_pixel_covers_there():
    cam = _camera([0.0, 0.0, 2.0], [0.0, 20.0, 2.0])
    wall = _tiny([0.0, 20.0, 2.0], 1)  # head-on, 20 m ahead
    floor = _tiny([0.0, 4.0, 0.0], 2)  # the ground 4 m ahead, 2 m below
    behind = _tiny([0.0, -20.0, 2.0], 1)
    aside = _tiny([30.0, 5.0, 2.0], 0)  # outside the field of view
    got = texel_targets(np.stack([wall, floor, behind, aside]), [cam], 960, finest_m=0.001)
    assert got[0] == pytest.approx(20.0 / F, rel=0.01)
    rng = np.hypot(4.0, 2.0)
    assert got[1] == pytest.approx(rng / (F * np.sqrt(2.0 / rng)), rel=0.01)  # cos = 2 / range
    assert got[2] == got[3] == COARSEST_M
    # frames decoded at half size: pixels twice as large; the nearer of two cameras counts
    assert texel_targets(wall[None], [cam], long_side=480)[0] == pytest.approx(0.08, rel=0.01)
    near = _camera([0.0, 15.0, 2.0], [0.0, 20.0, 2.0])
    assert texel_targets(wall[None], [cam, near], 960, 0.001)[0] == pytest.approx(5 / F, rel=0.01)
    assert texel_targets(wall[None], [cam, near], 960)[0] == 0.02  # the finest, by default


def test_cut_triangles_keep_their_place_winding_and_colours():
    corners = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [2.0, 6.0, 0.0]], np.float32)
    colours = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]], np.float32)
    prim = Primitive(corners, colours, np.array([[0, 1, 2]], np.uint32))
    mesh = MeshData([prim])
    tris = triangles_of(mesh)
    for _ in range(3):
        tris, old = tris.split(np.ones(len(tris), bool))
        assert (old == 0).all() or len(old) == len(tris)
    assert len(tris) == 8
    area = np.cross(
        tris.corners[:, 1] - tris.corners[:, 0], tris.corners[:, 2] - tris.corners[:, 0]
    )
    assert (area[:, 2] > 0).all() and area[:, 2].sum() / 2 == pytest.approx(30.0)
    atlas = packed(mesh, tris, np.full(len(tris), 0.1))
    # colours are linear in place: each sample's base colour is its point's, from the source
    p = atlas.points[:, :2].astype(float)
    m = np.column_stack([corners[1, :2] - corners[0, :2], corners[2, :2] - corners[0, :2]])
    w12 = np.linalg.solve(m, (p - corners[0, :2]).T).T
    bary = np.column_stack([1 - w12.sum(axis=1), w12])
    want = np.clip(np.round(255 * bary @ colours[:, :3]), 0, 255)
    assert np.abs(atlas.base.astype(int) - want).max() <= 2


def _scene() -> MeshData:
    ground = shapes.quad([-40.0, -40.0, 0.0], [80.0, 0, 0], [0, 80.0, 0])
    box = shapes.box((5.0, 5.0, 0.0), (15.0, 15.0, 6.0))
    return MeshData([ground.primitive((0.3, 0.6, 0.3, 1.0)), box.primitive((0.8, 0.8, 0.8, 1.0))])


def _frames() -> list[tuple[np.ndarray, Camera, float]]:
    """Eight frames around the box; each image's colour says where its pixel is (red u, green v,
    blue the frame), so a texel's colour tells the pixel it was read from."""
    out = []
    h, w = 135, 240
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    for k in range(8):
        a = 2 * np.pi * k / 8
        eye = [10 + 25 * np.cos(a), 10 + 25 * np.sin(a), 12.0]
        cam = _camera(eye, [10.0, 10.0, 2.0], w, h)
        rgb = np.stack([u, v, np.full_like(u, 30 * k)], axis=2).astype(np.uint8)
        out.append((rgb, cam, float(k)))
    return out


def _painted(resident_bytes: float) -> PagedMemory:
    paged = PagedMemory(
        _scene(), lambda t: np.full(len(t), 0.25), page_texels=16_384, resident_bytes=resident_bytes
    )
    for rgb, cam, t in _frames():
        paged.paint(rgb, cam, np.full((64, 64), np.inf), t)
    return paged


def test_a_tight_bound_pages_out_least_recently_used_and_paints_the_same():
    free = _painted(1e12)
    assert len(free.pages) > 20 and free.stats.evicted == 0
    biggest = max(free._bytes.values())
    cap = 3 * biggest
    tight = _painted(cap)
    try:
        assert tight.stats.evicted > 0 and tight.stats.reloaded > 0
        assert tight.stats.peak_bytes <= cap + biggest
        assert len(tight.pages) == len(free.pages)
        frames = _frames()
        checked = 0
        for (_, a, ma), (_, b, mb) in zip(free.each_page(), tight.each_page(), strict=True):
            np.testing.assert_array_equal(a.points, b.points)
            np.testing.assert_array_equal(ma.seen, mb.seen)
            np.testing.assert_array_equal(ma.rgb[ma.seen], mb.rgb[mb.seen])
            np.testing.assert_array_equal(ma.time[ma.seen], mb.time[mb.seen])
            # the texel's colour is its frame's at the pixel the frustum puts it on
            for k in np.unique(mb.time[mb.seen]).astype(int):
                sel = mb.seen & (mb.time == k)
                uv, _ = frames[k][1].project(b.points[sel].astype(float))
                want = np.clip(np.column_stack([uv - 0.5, np.full(len(uv), 30 * k)]), 0, 255)
                inner = (uv[:, 0] > 1) & (uv[:, 0] < 239) & (uv[:, 1] > 1) & (uv[:, 1] < 134)
                assert np.abs(mb.rgb[sel][inner].astype(float) - want[inner]).max() <= 1.01
                checked += int(inner.sum())
        assert checked > 10_000
        assert tight.nbytes <= max(cap, biggest)
    finally:
        spill = tight.spill_dir
        tight.close()
        free.close()
    assert not spill.exists()


def test_the_least_recently_used_page_goes_first():
    paged = PagedMemory(_scene(), lambda t: np.full(len(t), 0.25), page_texels=16_384)
    try:
        for k in (0, 1, 2):
            paged.page(k)
        paged.resident_bytes = paged.nbytes  # the three fit, a fourth does not
        paged.page(0)  # used again: 1 is now the least recently used, then 2
        paged.page(3)
        order = [1, 2, 0]
        gone = sorted(paged._spilled, key=order.index)
        assert gone and gone == order[: len(gone)] and 3 not in paged._spilled
        rgb_before = paged.page(1)[1].rgb.copy()
        assert paged.stats.reloaded == 1
        np.testing.assert_array_equal(paged.page(1)[1].rgb, rgb_before)
    finally:
        paged.close()


def test_pages_fit_their_charts():
    paged = PagedMemory(_scene(), lambda t: np.full(len(t), 0.1), page_texels=65_536)
    try:
        sizes = chart_sizes(paged.triangles, paged.texels)
        assert sizes.max() <= 64  # a quarter of the page's side
        assert sum(p.texels for p in paged.pages) == int((sizes[:, 0] * sizes[:, 1]).sum())
        for page in paged.pages:
            assert page.texels <= 0.8 * 65_536 or len(page.triangles) == 1
    finally:
        paged.close()


def test_export_model_pages_at_the_videos_ground_sampling(tmp_path):
    """`geofuse export model` on the sample (8 s between frames: ten of its 80 s are enough to
    page the memory) as 3D Tiles: a tile a page, texels finer than one atlas of 4 M texels gives
    the site (0.5 m), the paging said."""
    out = tmp_path / "tiles" / "tileset.json"
    args = [sys.executable, "-m", "app", "export", "model", "assets/sample/session.toml"]
    args += ["--out", str(out), "--source", "truth", "--every-s", "8", "--memory-mb", "40"]
    done = subprocess.run(args, capture_output=True, text=True, check=True)
    assert "evicted least recently used" in done.stdout, done.stdout
    said = done.stdout.split("pages of ")[1]
    assert float(said.split(" m texels")[0]) < 0.1
    assert len(list(out.parent.glob("tileset_*.glb"))) == int(
        done.stdout.split(" pages of")[0].split()[-1]
    )
