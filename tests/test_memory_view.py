"""What the viewer shows of the scene memory (app.export.memory_view, app.render.gpu_scene): the
memory as it was at a moment of the timeline (its history of epochs), "seen at" on its ramp,
"changed since the model" blind to exposure and a face's light, and the memory drawn on the GPU
in place of the model's own texture, where the frustum puts it."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.settings import ProjectionSettings
from app.export.atlas import layout
from app.export.memory import SurfaceMemory
from app.export.memory_view import RAMP, Snapshot, as_at, change, grey, seen_range, view_colours
from app.render.offscreen import OffscreenTarget
from app.render.renderer import FusionRenderer
from app.scene import shapes
from app.scene.mesh import MeshData
from tests.conftest import ROOT

SIZE = (64, 48)


def _down(x: float = 0.0) -> Camera:
    """A camera 20 m above (x, 0) looking straight down; its image's top towards north."""
    w, h = SIZE
    eye = np.array([x, 0.0, 20.0])
    q = look_at_quat(eye, np.array([x, 0.0, 0.0]), (0.0, 1.0, 0.0))
    return Camera.create(Intrinsics(w, h, 40.0, 40.0, w / 2, h / 2), eye, q, far=100.0)


def _memory(rule="newest", history=(0.0, 100.0, 10)) -> SurfaceMemory:
    """Three ground samples: under the camera, 3 m east, and 200 m away (never seen)."""
    points = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    return SurfaceMemory(points, normals, rule, history)


def _paint(memory: SurfaceMemory, colour, t: float) -> int:
    """A flat frame from straight above at t s; the samples kept."""
    rgb = np.tile(np.asarray(colour, np.uint8), (SIZE[1], SIZE[0], 1))
    return memory.paint(rgb, _down(), np.full((SIZE[1], SIZE[0]), np.inf), t)


RED, GREEN, BLUE = (220, 20, 20), (20, 220, 20), (20, 20, 220)


def test_the_memory_as_it_was_at_a_moment():
    """Painted red at 5 s, green at 15 s, blue at 35 s (epochs of 10 s): at 3 s nothing is seen,
    at 10 s red, at 20 s green, at 40 s and now blue, each with its time; a sample never seen
    stays unseen."""
    m = _memory()
    for colour, t in ((RED, 5.0), (GREEN, 15.0), (BLUE, 35.0)):
        assert _paint(m, colour, t) == 2
    for at_s, colour, t in ((10.0, RED, 5.0), (20.0, GREEN, 15.0), (40.0, BLUE, 35.0), (None, BLUE, 35.0)):  # fmt: skip
        snap = as_at(m, at_s)
        assert snap.seen.tolist() == [True, True, False], at_s
        assert tuple(snap.rgb[0]) == colour and snap.time[0] == pytest.approx(t), at_s
    assert not as_at(m, 3.0).seen.any()
    assert seen_range(as_at(m, 20.0)) == pytest.approx((15.0, 15.0))


def test_within_one_epoch_the_slider_shows_the_epoch_before():
    """Green at 21 s and blue at 27 s fall in one epoch, which keeps its newest (blue): at 24 s
    the memory shows the epoch before's newest (red at 5 s), as documented; at 28 s blue."""
    m = _memory()
    for colour, t in ((RED, 5.0), (GREEN, 21.0), (BLUE, 27.0)):
        _paint(m, colour, t)
    assert tuple(as_at(m, 24.0).rgb[0]) == RED
    assert tuple(as_at(m, 28.0).rgb[0]) == BLUE


def test_the_first_rule_is_exact_at_any_moment_and_the_history_is_bounded():
    m = _memory("first")
    before = m.nbytes
    for k, colour in enumerate((RED, GREEN, BLUE) * 20):
        _paint(m, colour, 5.0 + k)
    assert m.nbytes == before  # 60 frames: the same bytes
    assert tuple(as_at(m, 100.0).rgb[0]) == RED and not as_at(m, 4.0).seen.any()
    with pytest.raises(ValueError, match="history"):
        _memory(history=(10.0, 0.0, 4))


def test_seen_at_runs_from_blue_to_red_and_leaves_the_unseen_grey():
    points = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    m = SurfaceMemory(points, np.tile([0.0, 0.0, 1.0], (3, 1)), "newest", (0.0, 10.0, 2))
    rgb = np.full((SIZE[1], SIZE[0], 3), 100, np.uint8)
    hole = np.full((SIZE[1], SIZE[0]), np.inf)
    assert m.paint(rgb, _down(0.0), hole, 1.0) == 1
    assert m.paint(rgb, _down(30.0), hole, 9.0) == 1
    base = np.array([[200, 100, 50]] * 3, np.uint8)
    out = view_colours(m, base, "seen")
    assert tuple(out[0]) == tuple(RAMP[0, 1:].astype(int))  # the earliest: blue
    assert tuple(out[1]) == tuple(RAMP[-1, 1:].astype(int))  # the latest: red
    assert tuple(out[2]) == tuple(grey(base[2:])[0])  # never seen: the model in grey
    assert tuple(view_colours(m, base, "seen", at_s=5.0)[1]) == tuple(grey(base[1:2])[0])
    assert view_colours(m, base, "model") is base
    with pytest.raises(ValueError, match="expected one of"):
        view_colours(m, base, "heat")


def test_changed_ignores_exposure_and_a_faces_light_and_finds_a_real_change():
    """The model's texture seen again under another exposure on one face and another light on
    a second is no change; a patch painted over on the second is."""
    rng = np.random.default_rng(3)
    n = 400
    base = rng.integers(30, 200, (n, 3)).astype(np.uint8)
    faces = np.repeat([0, 1], n // 2)
    painted = base.astype(np.float64)
    painted[faces == 0] = 1.3 * painted[faces == 0] + 10  # exposure
    painted[faces == 1] = 0.6 * painted[faces == 1] - 5  # the face in shadow today
    painted[350:360] = [250, 0, 250]  # something new on the second face
    painted = np.clip(np.round(painted), 0, 255).astype(np.uint8)
    seen = np.ones(n, bool)
    seen[-5:] = False
    snap = Snapshot(painted, seen, np.where(seen, 1.0, np.nan))
    d = change(snap, base, faces)
    assert np.median(d[:340]) < 2.0 and d[350:360].min() > 80.0 and np.all(d[-5:] == 0)
    # one fit for both faces would call the shadow a change
    assert np.median(change(snap, base)[200:340]) > 10.0


@pytest.mark.parametrize("overlay", [False, True])
def test_the_memory_is_drawn_in_place_of_the_model_where_the_frustum_says(gl_ctx, overlay):
    """A 20 x 20 m ground, grey in the model; its memory: red east of x = 0, blue west. Seen
    from straight above, the pixel over a point lands where the view's frustum projects it, with
    the memory's colour there; the model is back when the memory is hidden. Drawn in place of
    the model, or over it (as a memory holding frozen 3D Tiles is: the model and the streamed
    tiles drawn, the memory over them in the view pass alone)."""
    ground = shapes.quad([-10.0, -10.0, 0.0], [20.0, 0, 0], [0, 20.0, 0]).primitive()
    ground.colors[:] = (0.5, 0.5, 0.5, 1.0)
    mesh = MeshData([ground])
    atlas = layout(mesh, 40_000)
    colours = np.where(atlas.points[:, :1] > 0, [[255, 0, 0]], [[0, 0, 255]]).astype(np.uint8)
    renderer = FusionRenderer(gl_ctx, mesh)
    target = OffscreenTarget(gl_ctx, 160, 120)
    try:
        renderer.scene.set_memory(atlas.primitive(colours), overlay=overlay)
        w, h = 160, 120
        eye = np.array([0.0, 0.0, 30.0])
        view = Camera.create(
            Intrinsics(w, h, 100.0, 100.0, w / 2, h / 2),
            eye,
            look_at_quat(eye, np.zeros(3), (0.0, 1.0, 0.0)),
            far=100.0,
        )
        off = ProjectionSettings(enabled=False)

        def pixel(point):
            uv, _ = view.project(np.array([point], np.float64))
            renderer.draw(view, target.fbo, off)
            return target.read()[int(uv[0, 1]), int(uv[0, 0])].astype(int)

        renderer.scene.show_memory = True
        drawn = renderer.scene.drawables(view)
        assert (drawn[-1] is renderer.scene.memory) and (len(drawn) == (2 if overlay else 1))
        assert (
            renderer.scene.memory not in renderer.scene.drawables(view, key="depth") or not overlay
        )
        east, west = pixel([4.0, 2.0, 0.0]), pixel([-4.0, -2.0, 0.0])
        assert east[0] > 150 and east[2] < 60 and west[2] > 150 and west[0] < 60
        renderer.scene.write_memory_texture(atlas.texture(colours[:, ::-1].copy()))
        assert pixel([4.0, 2.0, 0.0])[2] > 150  # new texels: east is blue now
        renderer.scene.show_memory = False
        model = pixel([4.0, 2.0, 0.0])
        assert abs(model[0] - model[2]) < 20  # grey: the model's own
    finally:
        target.release()
        renderer.release()


def test_two_clips_paint_one_memory_on_one_timeline():
    """The sample clip twice on one timeline, the second 100 s after the first: both are painted
    in time order into one memory, and scrubbed to 90 s (between them) the memory is exactly the
    one the first clip alone paints."""
    from app.export.painting import ClipToPaint
    from app.session.assemble import open_session
    from app.session.camera_track import camera_track
    from app.ui.memory import MemoryPainter

    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    times = np.asarray(session.frame_times, np.float64) - float(session.frame_times[0])
    first = ClipToPaint(session, track, times)
    later = ClipToPaint(session, track, times + 100.0)

    def painted(clips):
        p = MemoryPainter(session.scene(), clips, "newest", every_s=8.0, max_texels=300_000)
        try:
            assert p.start().wait(300) and p.error is None
        finally:
            p.stop()
        return p

    both, alone = painted([later, first]), painted([first])
    assert both.frames_painted == 2 * alone.frames_painted >= 18
    m, a = both.memory, alone.memory
    assert np.nanmax(m.time) > 100.0 and np.nanmax(a.time) < 80.0
    snap = as_at(m, 90.0)
    assert np.array_equal(snap.seen, a.seen) and a.seen.sum() > 1000
    assert np.array_equal(snap.rgb[a.seen], a.rgb[a.seen])
    assert np.allclose(snap.time[a.seen], a.time[a.seen])


def test_under_the_best_rule_a_frame_that_agrees_with_the_model_wins(gl_ctx):
    """A checkered ground seen from 40 m as the model shows it, then from 20 m as noise (a
    frame misregistered, or something the model lacks): without the agreement term the nearer
    frame wins under the best rule; with it the one that agrees stays. A flat model says
    nothing to agree with."""
    from app.export.memory import agreement
    from app.export.painting import model_view, paint_one
    from app.render.views import ModelViews

    squares = (np.indices((256, 256)) // 3).sum(axis=0) % 2  # 0.47 m squares
    checker = np.where(squares[..., None] > 0, 220, 40).astype(np.uint8).repeat(3, axis=2)
    checker = np.dstack([checker, np.full((256, 256), 255, np.uint8)])
    ground = shapes.quad([-20.0, -20.0, 0.0], [40.0, 0, 0], [0, 40.0, 0])
    views = ModelViews(MeshData([ground.primitive((1, 1, 1, 1), checker)]), gl_ctx)
    try:
        w, h = 320, 240

        def above(z):
            eye = np.array([0.0, 0.0, z])
            q = look_at_quat(eye, np.zeros(3), (0.0, 1.0, 0.0))
            return Camera.create(Intrinsics(w, h, 200.0, 200.0, w / 2, h / 2), eye, q, far=100.0)

        far, near = above(40.0), above(20.0)
        agreeing = views.render(far)[0]
        noise = np.random.default_rng(1).integers(0, 256, (h, w, 3)).astype(np.uint8)
        _, model_near = model_view(views, near)
        assert np.median(agreement(agreeing, model_view(views, far)[1])) > 0.95
        assert np.median(agreement(noise, model_near)) < 0.6
        assert np.all(agreement(noise, np.full_like(model_near, 128)) == 1.0)
        xs = np.linspace(-4.0, 4.0, 9)
        points = np.array([[x, y, 0.0] for x in xs for y in xs])
        normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
        weighed, blind = (
            SurfaceMemory(points, normals, "best"),
            SurfaceMemory(points, normals, "best"),
        )
        for t, (frame, cam) in enumerate(((agreeing, far), (noise, near)), start=1):
            paint_one(weighed, views, frame, cam, float(t))
            blind.paint(frame, cam, model_view(views, cam)[0], float(t))
        assert weighed.seen.all() and blind.seen.all()
        assert np.mean(weighed.time == 1.0) > 0.9  # the agreeing frame kept
        assert np.all(blind.time == 2.0)  # nearer, so better, when agreement is not asked
    finally:
        views.release()


def test_the_viewer_paints_a_3d_tiles_scene_from_the_tiles_its_clip_needs(tmp_path):
    """The sample scene as 3D Tiles: the painter freezes the tiles the clip's cameras select
    and paints them; its atlas covers the streamed layer (which the memory view then stands
    for) and the clip paints its facade."""
    import shutil

    from app.export.painting import ClipToPaint
    from app.geodesy.enu import LocalFrame
    from app.scene.tiles import write as tjw
    from app.scene.tiles.tileset import Tileset
    from app.session.assemble import open_session
    from app.session.camera_track import camera_track
    from app.simulate.sample import SAMPLE_DIR, SAMPLE_ORIGIN
    from app.ui.memory import MemoryPainter

    frame = LocalFrame(*SAMPLE_ORIGIN)
    shutil.copy(SAMPLE_DIR / "scene.glb", tmp_path / "scene.glb")
    root = {
        "boundingVolume": {"box": tjw.box_of([-300, -300, -5], [300, 300, 60])},
        "geometricError": 0.0,
        "transform": tjw.column_major(tjw.enu_to_ecef_matrix(frame)),
        "content": {"uri": "scene.glb"},
    }
    tjw.write_json(
        tmp_path / "tileset.json",
        {"asset": {"version": "1.1"}, "geometricError": 50.0, "root": root},
    )
    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    times = np.asarray(session.frame_times, np.float64) - float(session.frame_times[0])
    mesh = MeshData([], [Tileset(str(tmp_path / "tileset.json"), frame)])
    p = MemoryPainter(mesh, [ClipToPaint(session, track, times)], "newest", 8.0, 300_000)
    try:
        assert p.start().wait(300) and p.error is None, p.error
    finally:
        p.stop()
    assert p.covers_tiles and len(p.atlas.triangles) == session.scene().triangle_count
    assert p.memory.seen.sum() > 1000


def test_a_memory_larger_than_the_atlas_is_paged_and_drawn_where_the_single_atlas_draws_it(
    gl_ctx,
):
    """The sample clip (a frame every 8 s) painted twice: into one atlas, and with the atlas
    capped far below what the video's sampling asks for, so that the viewer pages it (pages made
    where frames met them, spilled to disk past 40 MB and read back, at most 8 MB of page textures
    on the GPU: the nearest pages fine, the farther coarse). Seen through a painting frame's own
    camera, the pages the view meets are composed and drawn over the model: where the memory
    differs from the model the two renderings agree (same colours within 40 levels in 80 % of
    those pixels), and the paged one is nearer the atlas's than the model is. Out of view, a
    page is let go."""
    from app.export.paged import pages_in_view
    from app.export.painting import ClipToPaint
    from app.session.assemble import open_session
    from app.session.camera_track import camera_track
    from app.ui.memory import COARSE, MemoryPainter

    session = open_session(ROOT / "assets/sample/session.toml")
    track = camera_track(session, "truth")
    times = np.asarray(session.frame_times, np.float64) - float(session.frame_times[0])
    clips = [ClipToPaint(session, track, times)]
    one = MemoryPainter(session.scene(), clips, "newest", 8.0, 300_000)
    paged = MemoryPainter(
        session.scene(), clips, "newest", 8.0, 20_000, resident_mb=40.0, gpu_mb=8.0
    )
    for p in (one, paged):
        assert p.start().wait(300) and p.error is None, p.error
    renderer = FusionRenderer(gl_ctx, session.scene())
    target = OffscreenTarget(gl_ctx, 320, 180)
    try:
        assert one.boxes is None and one.atlas is not None and paged.boxes is not None
        stats = paged.page_stats
        assert stats.made > 10 and stats.evicted > 0 and stats.reloaded > 0, stats.said()
        assert paged.memory.nbytes <= 40e6  # the bound
        assert paged.fine_pages < paged.max_pages
        view = track.frame_camera(int(np.searchsorted(times, 32.0))).pinhole(320 / 640)
        scene = renderer.scene
        off = ProjectionSettings(enabled=False)

        def drawn() -> np.ndarray:
            renderer.draw(view, target.fbo, off)
            return target.read()[..., :3].astype(int)

        model = drawn()
        one.request("memory", None)
        texture = None
        for _ in range(600):
            texture = one.take() if texture is None else texture
            if texture is not None:
                break
            one.wait(0.05)
            time.sleep(0.05)
        scene.set_memory(one.atlas.primitive(one.atlas.base))
        scene.write_memory_texture(texture)
        scene.show_memory = True
        atlas_view = drawn()
        scene.set_memory(None)

        wanted = pages_in_view(view, *paged.boxes, paged.max_pages)
        assert wanted
        paged.request("memory", None, wanted)
        held = {}
        for _ in range(600):
            taken = paged.take_pages()
            if taken is not None:
                held.update(taken[0])
                for k, prim in taken[0].items():
                    scene.put_memory_page(k, prim)
                scene.keep_memory_pages(taken[1])
            if paged.current():
                break
            time.sleep(0.05)
        assert paged.current() and scene.memory_pages
        assert set(scene.memory_pages) <= set(wanted)
        assert scene.memory_pages_bytes <= 8e6
        sizes = {k: held[k].texture.shape[0] * held[k].texture.shape[1] for k in held}
        if len(wanted) > paged.fine_pages:  # a far page is coarse
            far = [k for k in wanted[paged.fine_pages :] if k in sizes]
            assert all(sizes[k] <= 512 * 512 // COARSE**2 for k in far)
        paged_view = drawn()
        changed = np.abs(atlas_view - model).max(axis=2) > 40
        assert changed.mean() > 0.1
        agree = np.abs(paged_view - atlas_view).max(axis=2)[changed] <= 40
        assert agree.mean() > 0.8, agree.mean()
        assert (
            np.abs(paged_view - atlas_view)[changed].mean()
            < np.abs(model - atlas_view)[changed].mean()
        )

        scene.show_memory = False  # hidden: the model again
        assert np.array_equal(drawn(), model)
        scene.show_memory = True
        paged.request("memory", None, ())  # the view meets no page: all let go
        for _ in range(200):
            taken = paged.take_pages()
            if taken is not None and not taken[1]:
                scene.keep_memory_pages(taken[1])
                break
            time.sleep(0.05)
        assert not scene.memory_pages
    finally:
        one.stop()
        paged.stop()
        target.release()
        renderer.release()


def test_under_the_best_rule_the_better_posed_frame_wins():
    """Two frames of the ground from the same place: red posed by the sensors (3 m, 2 deg of
    uncertainty), blue registered (0.3 m, 0.1 deg). Under the best rule blue is kept whichever
    came first, its quality the incidence's cosine over (1 + range / 100 m) and over (1 + the
    metres the pose's uncertainty explains at 20 m: hypot(0.3, 20 tan 0.1 deg))."""
    frame = np.full((SIZE[1], SIZE[0], 3), 0, np.uint8)
    far = np.full((SIZE[1], SIZE[0]), np.inf)
    sensors, registered = (3.0, 2.0), (0.3, 0.1)
    for first, second in ((RED, sensors), (BLUE, registered)), ((BLUE, registered), (RED, sensors)):
        m = _memory("best", None)
        for t, (colour, sigmas) in enumerate((first, second)):
            m.paint(frame + np.uint8(colour), _down(), far, float(t), None, sigmas)
        assert tuple(m.rgb[0]) == BLUE, (first, m.rgb[0])
        off = np.hypot(0.3, 20.0 * np.radians(0.1))
        assert m.quality[0] == pytest.approx(1.0 / (1.0 + 0.2) / (1.0 + off), rel=1e-4)
    newest = _memory("newest", None)  # the rule that ignores quality: the later frame
    for t, (colour, sigmas) in enumerate(((BLUE, registered), (RED, sensors))):
        newest.paint(frame + np.uint8(colour), _down(), far, float(t), None, sigmas)
    assert tuple(newest.rgb[0]) == RED


def test_a_registered_frames_uncertainty_grows_away_from_its_keyframes():
    """app.solve.uncertainty.frame_sigmas: a source without registration has the prior's
    everywhere (the sample's GNSS fixes' own accuracy, 2.5 m); a registered one the registered
    pose's (0.3 m) at a used keyframe, and gap s from the nearest one the prior's plus
    (0.3 m - the prior's) exp(-gap / 30 s) (the fusion's hold time)."""
    from app.register.fuse import Keyframe
    from app.register.solve import Registration
    from app.session.assemble import open_session
    from app.session.camera_track import camera_track
    from app.solve.uncertainty import REGISTERED_SIGMA_M, frame_sigmas

    session = open_session(ROOT / "assets/sample/session.toml")
    phone = camera_track(session, "phone")
    frames = np.array([0, 300, 1200, 2100])
    t = phone.clock.session_time(np.asarray(session.video.pts_s)[frames])
    gnss = float(np.nanmedian(session.gnss.h_acc))
    pos, att = frame_sigmas(session, phone, frames)
    assert np.allclose(pos, gnss) and gnss == pytest.approx(2.5, abs=0.5)
    assert np.allclose(att, 2.0)

    def kf(time_s: float) -> Keyframe:
        z = np.zeros(3)
        q = np.array([1.0, 0, 0, 0])
        return Keyframe(0, time_s, True, "", 100, 90, 1.0, 3, z, q, z, q)

    reg = Registration("phone", (kf(t[0]), kf(t[1])), {})
    registered = replace(phone, source="registered", registration=reg)
    pos, att = frame_sigmas(session, registered, frames)
    assert pos[:2] == pytest.approx([REGISTERED_SIGMA_M] * 2)
    gap = t[2] - t[1]
    expected = gnss + (REGISTERED_SIGMA_M - gnss) * np.exp(-gap / 30.0)
    assert pos[2] == pytest.approx(expected, rel=1e-6)
    assert pos[3] > pos[2] > pos[1] and att[3] > att[0]
