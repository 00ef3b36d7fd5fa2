"""The projection renderer against numbers derived by hand/numpy (paper 2.2.1-2.2.2).

Scenes are built in code in ENU metres; expected pixels come from ray casting with the numpy
camera model (itself checked against hand-computed matrices in test_camera.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.settings import ProjectionSettings
from app.geodesy import rotations
from app.scene import shapes
from app.scene.mesh import MeshData

pytestmark = pytest.mark.gl

WALL_Y = 20.0
WALL_COLOR = (0.7, 0.7, 0.7, 1.0)
VIDEO_W, VIDEO_H = 64, 48
BLOCK = 8  # texels per checkerboard block


def make_renderer(ctx, prims, deferred=None):
    """deferred: None the renderer's default (the deferred projectors where the context can),
    False the forward scene pass (the full-cost path)."""
    from app.render.renderer import FusionRenderer

    return FusionRenderer(ctx, MeshData(prims), deferred=deferred)


def render(renderer, view, **settings):
    from app.render.offscreen import render_to_array

    return render_to_array(renderer, view, ProjectionSettings(**settings)).astype(int)


def wall():
    return shapes.quad([-20, WALL_Y, 0], [40, 0, 0], [0, 0, 20]).primitive(WALL_COLOR)


def projector(heading=0.0, pitch=0.0, position=(0, 0, 10)):
    return Camera.create(
        Intrinsics.from_fov(VIDEO_W, VIDEO_H, 60),
        position,
        rotations.camera_quat_from_hpr(heading, pitch, 0.0),
        near=1.0,
        far=200.0,
    )


def view_camera(eye, target, w=320, h=240):
    return Camera.create(
        Intrinsics.from_fov(w, h, 60), eye, look_at_quat(eye, target), near=0.5, far=500.0
    )


def pixel_centres(cam):
    w, h = cam.intrinsics.width, cam.intrinsics.height
    v, u = np.mgrid[0:h, 0:w]
    return np.column_stack([u.ravel() + 0.5, v.ravel() + 0.5])


def hit_plane(cam, axis, value):
    """World points where each pixel's ray meets the plane coordinate[axis] = value (NaN if not ahead)."""
    rays = cam.pixel_rays(pixel_centres(cam))
    origin = np.asarray(cam.position)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (value - origin[axis]) / rays[:, axis]
    t[~(t > 0)] = np.nan
    return origin + rays * t[:, None], t


def checkerboard():
    """VIDEO_H x VIDEO_W RGB image of 8x8-texel blocks, each block a distinct colour."""
    v, u = np.mgrid[0:VIDEO_H, 0:VIDEO_W]
    bx, by = u // BLOCK, v // BLOCK
    return np.stack([20 + 30 * bx, 20 + 40 * by, np.full_like(bx, 200)], -1).astype(np.uint8)


def test_checkerboard_texels_land_where_the_frustum_says(gl_ctx):
    r = make_renderer(gl_ctx, [wall()])
    image = checkerboard()
    r.set_video_frame(image)
    proj = projector()
    r.set_projector(proj)
    view = view_camera([4, 2, 12], [0, WALL_Y, 10])
    out = render(r, view, alpha=1.0).reshape(-1, 3)

    world, _ = hit_plane(view, 1, WALL_Y)
    uv, depth = proj.project(world)
    inside_block = (
        np.abs((uv % BLOCK) - BLOCK / 2) <= BLOCK / 2 - 1.0
    )  # >= 1 texel from block edges
    ok = (
        (depth > 0)
        & np.all(inside_block, axis=1)
        & np.all((uv >= 0) & (uv < [VIDEO_W, VIDEO_H]), axis=1)
    )
    assert ok.sum() > 5000
    texel = np.floor(uv[ok]).astype(int)
    expected = image[texel[:, 1], texel[:, 0]].astype(int)
    diff = np.abs(out[ok] - expected).max(axis=1)
    assert diff.max() <= 1, f"{(diff > 1).sum()} pixels off, worst {diff.max()}"
    r.release()


def test_box_shadow_keeps_model_colour_behind_occluder(gl_ctx):
    box_lo, box_hi = np.array([-3.0, 10.0, 5.0]), np.array([3.0, 12.0, 12.0])
    r = make_renderer(
        gl_ctx, [wall(), shapes.box(box_lo, box_hi, bottom=True).primitive((0.8, 0.4, 0.2, 1))]
    )
    r.set_video_frame(np.full((VIDEO_H, VIDEO_W, 3), (255, 0, 255), np.uint8))
    proj = projector()
    r.set_projector(proj)
    long_side = 256
    view = view_camera([14, -4, 9], [0, WALL_Y, 9])
    out = render(r, view, alpha=1.0, depth_long_side=long_side).reshape(-1, 3)
    is_video = (out[:, 0] > 200) & (out[:, 1] < 60) & (out[:, 2] > 200)

    world, t_wall = hit_plane(view, 1, WALL_Y)
    on_wall = (np.abs(world[:, 0]) < 19) & (world[:, 2] > 0.5) & (world[:, 2] < 19.5)
    # Exclude pixels whose view ray meets the box first (slab test, 1 px margin in world terms).
    rays = view.pixel_rays(pixel_centres(view))
    eye = np.asarray(view.position)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (box_lo - 0.3 - eye) / rays
        t1 = (box_hi + 0.3 - eye) / rays
    t_near = np.nanmax(np.minimum(t0, t1), axis=1)
    t_far = np.nanmin(np.maximum(t0, t1), axis=1)
    hits_box_first = (t_near <= t_far) & (t_near < t_wall)
    usable = on_wall & ~hits_box_first

    # Shadow polygon: the box's corners projected into the depth map, in texels.
    scale = long_side / VIDEO_W
    corners = np.array(
        [
            [x, y, z]
            for x in (box_lo[0], box_hi[0])
            for y in (box_lo[1], box_hi[1])
            for z in (box_lo[2], box_hi[2])
        ]
    )
    hull = ConvexHull(proj.project(corners)[0] * scale)
    uv, _ = proj.project(world)
    p = uv * scale
    # Signed distance to the hull (negative inside), in depth-map texels.
    eq = hull.equations  # n . x + d <= 0 inside, n unit
    signed = np.max(p @ eq[:, :2].T + eq[:, 2], axis=1)
    in_frame = np.all((uv > 2) & (uv < [VIDEO_W - 2, VIDEO_H - 2]), axis=1)

    deep_shadow = usable & in_frame & (signed < -1.0)
    lit = usable & in_frame & (signed > 2.0)
    assert deep_shadow.sum() > 300 and lit.sum() > 3000
    assert not is_video[deep_shadow].any(), (
        f"{is_video[deep_shadow].sum()} video pixels > 1 texel inside the shadow"
    )
    assert is_video[lit].mean() > 0.995
    r.release()


def test_outside_frustum_and_behind_are_bit_identical_to_projection_off(gl_ctx):
    ground = shapes.quad([-80, -80, 0], [160, 0, 0], [0, 160, 0]).primitive((0.35, 0.6, 0.3, 1))
    r = make_renderer(gl_ctx, [ground, wall()])
    r.set_video_frame(checkerboard())
    # Pitched up at the wall: the mirror image of its frustum behind it points down at the ground.
    proj = projector(heading=0.0, pitch=20.0, position=(0, 0, 3))
    r.set_projector(proj)
    view = view_camera([0, -60, 50], [0, 10, 0], 400, 300)
    on = render(r, view, alpha=1.0).reshape(-1, 3)
    off = render(r, view, enabled=False).reshape(-1, 3)

    on_ground, t_ground = hit_plane(view, 2, 0.0)
    on_wall, t_wall = hit_plane(view, 1, WALL_Y)
    wall_hit = (np.abs(on_wall[:, 0]) < 20) & (on_wall[:, 2] > 0) & (on_wall[:, 2] < 20)
    use_wall = wall_hit & ~(t_ground < t_wall)
    world = np.where(use_wall[:, None], on_wall, on_ground)
    valid = (use_wall | np.all(np.abs(on_ground[:, :2]) < 79, axis=1)) & np.all(
        np.isfinite(world), axis=1
    )
    uv, depth = proj.project(world)
    behind = valid & (depth <= 0)
    margin = 1.0
    outside = (
        valid
        & (depth > 0)
        & ~np.all((uv > -margin) & (uv < [VIDEO_W + margin, VIDEO_H + margin]), axis=1)
    )
    inside = (
        use_wall
        & (depth > 1)
        & np.all((uv > margin) & (uv < [VIDEO_W - margin, VIDEO_H - margin]), axis=1)
    )
    # Behind-the-camera points whose perspective division lands inside the image in x and y:
    # the w <= 0 (and z) checks are what keep the video off them.
    clip = np.c_[world, np.ones(len(world))] @ proj.view_projection.T
    with np.errstate(divide="ignore", invalid="ignore"):
        naive = np.all(np.abs(clip[:, :2] / clip[:, 3:4]) <= 1, axis=1)
    assert (behind & naive).sum() > 1000 and outside.sum() > 5000 and inside.sum() > 1000
    np.testing.assert_array_equal(on[behind], off[behind])
    np.testing.assert_array_equal(on[outside], off[outside])
    assert (np.abs(on[inside] - off[inside]).max(axis=1) > 0).mean() > 0.95
    r.release()


def test_each_frame_draws_a_variant_holding_only_its_switches(gl_ctx):
    """The scene shader is compiled per combination of what a frame draws: with projection off
    the variant drawn has no projector uniforms at all (its code compiled out: what makes it
    cheap on a software rasteriser, which runs every branch a shader holds); switched back on,
    the variant made first is drawn again, pixel for pixel the same (the forward pass)."""
    r = make_renderer(gl_ctx, [wall()], deferred=False)
    r.set_video_frame(checkerboard())
    r.set_projector(projector())
    view = view_camera([0, -10, 10], [0, WALL_Y, 10])
    on = render(r, view, alpha=1.0)
    variant = r.scene_pass.variant
    assert variant["PROJECTION"] == 1 and variant["EXACT_VIDEO"] == 0 and variant["VIDEO_YUV"] == 0
    assert r.scene_pass.program.get("u_proj_view_proj", None) is not None
    off = render(r, view, enabled=False)
    for name in ("u_proj_view_proj", "u_depth_map", "u_video", "u_alpha"):
        assert r.scene_pass.program.get(name, None) is None, name
    again = render(r, view, alpha=1.0)
    np.testing.assert_array_equal(on, again)
    assert len(r.scene_pass.programs) == 3  # the file's defaults (made at start), on, off
    assert (np.abs(on - off).max(axis=-1) > 0).mean() > 0.3  # the video covers the view
    r.release()


def test_transparency_blends_model_and_video(gl_ctx):
    r = make_renderer(gl_ctx, [wall()])
    video_rgb = np.array([200, 40, 90])
    r.set_video_frame(np.tile(video_rgb.astype(np.uint8), (VIDEO_H, VIDEO_W, 1)))
    r.set_projector(projector())
    view = view_camera(
        [0, 5, 10], [0, WALL_Y, 10], 160, 120
    )  # wall fills the centre, all projected
    model = render(r, view, enabled=False)[40:80, 60:100].reshape(-1, 3)
    a0 = render(r, view, alpha=0.0)[40:80, 60:100].reshape(-1, 3)
    a5 = render(r, view, alpha=0.5)[40:80, 60:100].reshape(-1, 3)
    a1 = render(r, view, alpha=1.0)[40:80, 60:100].reshape(-1, 3)
    np.testing.assert_array_equal(a0, model)
    assert np.abs(a1 - video_rgb).max() <= 1
    assert np.abs(a5 - (model + video_rgb) / 2).max() <= 1
    assert np.abs(model - video_rgb).max() > 50  # the two really differ
    r.release()


def test_neighbourhood_rule_trims_the_occlusion_edge(gl_ctx):
    """With the nine-case rule off, video reaches closer to the shadow edge than with it on."""
    box_lo, box_hi = np.array([-3.0, 10.0, 5.0]), np.array([3.0, 12.0, 12.0])
    r = make_renderer(
        gl_ctx, [wall(), shapes.box(box_lo, box_hi, bottom=True).primitive((0.8, 0.4, 0.2, 1))]
    )
    r.set_video_frame(np.full((VIDEO_H, VIDEO_W, 3), (255, 0, 255), np.uint8))
    r.set_projector(projector())
    view = view_camera([14, -4, 9], [0, WALL_Y, 9])
    count = {}
    for rule in (True, False):
        out = render(r, view, alpha=1.0, depth_long_side=128, neighbourhood=rule).reshape(-1, 3)
        count[rule] = int(((out[:, 0] > 200) & (out[:, 1] < 60) & (out[:, 2] > 200)).sum())
    assert count[False] > count[True]
    r.release()


@pytest.mark.parametrize("deferred", [False, True])
def test_depth_map_redrawn_only_when_the_pose_changes(gl_ctx, deferred):
    r = make_renderer(gl_ctx, [wall()], deferred=deferred)
    r.set_video_frame(checkerboard())
    view = view_camera([0, 0, 10], [0, WALL_Y, 10], 64, 48)
    r.set_projector(projector())
    render(r, view)
    render(r, view)
    assert r.depth.renders == 1
    r.set_projector(projector(heading=1.0))
    render(r, view)
    assert r.depth.renders == 2
    if not deferred:  # default: 2048 on the long side, the video's aspect
        assert r.depth.size == (2048, 1536)
    else:  # what a 64x48 view needs of it (app.render.coverage.depth_long_side)
        assert r.depth.size[0] < 2048 and r.depth.size[0] * 3 == r.depth.size[1] * 4
    r.release()


def test_vertex_at_known_latitude_longitude_appears_where_geo_says(gl_ctx, tmp_path):
    import trimesh

    from app.geodesy.enu import LocalFrame
    from app.scene import load_scene

    frame = LocalFrame(34.80, 113.53, 110.0)
    marker = (34.8009, 113.5311, 112.0)  # ~100 m north, ~101 m east, 2 m up
    centre_enu = frame.geodetic_to_enu(*marker)
    # Write the marker (a 4 m square) and the ground as ECEF, as exported 3D Tiles content is.
    square = centre_enu + np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]])
    ground = np.array([[-300, -300, 0], [300, -300, 0], [300, 300, 0], [-300, 300, 0]], float)
    verts = frame.enu_to_ecef(np.vstack([square, ground]))
    faces = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    colors = np.array([[255, 0, 0, 255]] * 4 + [[60, 60, 60, 255]] * 4, np.uint8)
    path = tmp_path / "ecef.obj"
    trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=colors, process=False).export(
        path, digits=6
    )
    mesh = load_scene(path, frame)

    r = make_renderer(gl_ctx, mesh.primitives)
    cam = Camera.create(
        Intrinsics.from_fov(400, 400, 60),
        [0, 0, 400],
        rotations.camera_quat_from_hpr(0, -90, 0),
        near=1,
        far=1000,
    )
    out = render(r, cam, enabled=False)
    red = (out[:, :, 0] > 120) & (out[:, :, 1] < 40)
    assert red.sum() > 4
    v, u = np.nonzero(red)
    expected_uv, _ = cam.project(centre_enu)
    assert np.hypot(u.mean() + 0.5 - expected_uv[0, 0], v.mean() + 0.5 - expected_uv[0, 1]) < 1.0
    assert centre_enu[0] == pytest.approx(101.6, abs=1) and centre_enu[1] == pytest.approx(
        99.8, abs=1
    )
    r.release()


def test_border_texels_with_fewer_neighbours_still_take_the_video(gl_ctx):
    """Edge and corner texels have fewer than eight neighbours; those outside the image are not
    cases that can fail. A wall filling the frustum, seen through the projector, is all video."""
    r = make_renderer(
        gl_ctx, [shapes.quad([-60, WALL_Y, -40], [120, 0, 0], [0, 0, 100]).primitive(WALL_COLOR)]
    )
    r.set_video_frame(np.full((VIDEO_H, VIDEO_W, 3), (255, 0, 255), np.uint8))
    proj = projector()
    r.set_projector(proj)
    view = Camera.create(
        proj.intrinsics.scaled(4 * VIDEO_W, 4 * VIDEO_H),
        proj.position,
        proj.orientation,
        near=1.0,
        far=200.0,
    )
    out = render(r, view, alpha=1.0, depth_long_side=VIDEO_W)
    assert (np.abs(out - [255, 0, 255]).max(axis=2) <= 1).all()
    r.release()


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_yuv_playback_frame_matches_the_rgb_still(gl_ctx, rotation):
    """A stored YUV frame turned by the shader lands exactly where the same frame, turned on the
    CPU and given as an RGB still, lands (to the YUV conversion's rounding)."""
    from app.io.video import rotate_for_display
    from app.render.video_texture import yuv_to_rgb

    rng = np.random.default_rng(rotation)
    h, w = (48, 64) if rotation % 180 == 0 else (64, 48)  # stored so that the display is 64x48
    y = np.kron(rng.integers(40, 220, (h // 8, w // 8)), np.ones((8, 8))).astype(np.uint8)
    u = np.kron(rng.integers(60, 200, (h // 8, w // 8)), np.ones((4, 4))).astype(np.uint8)
    v = np.kron(rng.integers(60, 200, (h // 8, w // 8)), np.ones((4, 4))).astype(np.uint8)
    r = make_renderer(gl_ctx, [wall()])
    r.set_projector(projector())
    view = view_camera([0, 5, 10], [0, WALL_Y, 10], 160, 120)
    r.set_video_yuv(y, u, v, rotation, bt709=False)
    from_yuv = render(r, view, alpha=1.0)
    r.set_video_frame(rotate_for_display(yuv_to_rgb(y, u, v), rotation))
    from_rgb = render(r, view, alpha=1.0)
    # Compare away from block edges: there, bilinear filtering of half-resolution chroma planes
    # and of CPU-upsampled RGB legitimately differ within a couple of texels.
    world, _ = hit_plane(view, 1, WALL_Y)
    uv, depth = r.projector.project(world)
    inner = np.minimum(uv % 8, 8 - uv % 8).min(axis=1) >= 2.5
    inside = (depth > 0) & np.all((uv > 0) & (uv < [VIDEO_W, VIDEO_H]), axis=1) & inner
    assert inside.sum() > 2000
    diff = np.abs(from_yuv - from_rgb).reshape(-1, 3).max(axis=1)[inside]
    assert np.median(diff) <= 1 and np.percentile(diff, 99) <= 3
    r.release()


def test_error_overlay_colours_the_projection_error_in_metres(gl_ctx):
    """The true camera 2 m east of the estimated one, both facing the wall: every covered wall
    point is off by exactly 2 m, half of a 4 m scale: yellow."""
    from app.core.settings import OverlaySettings

    r = make_renderer(gl_ctx, [wall()])
    r.set_video_frame(np.full((VIDEO_H, VIDEO_W, 3), 128, np.uint8))
    est = projector()
    r.set_projector(est)
    view = view_camera([0, 5, 10], [0, WALL_Y, 10], 160, 120)
    from app.render.offscreen import render_to_array

    def colour(truth_offset):
        r.set_truth(
            Camera.create(
                est.intrinsics,
                np.asarray(est.position) + truth_offset,
                est.orientation,
                est.near,
                est.far,
            )
        )
        out = render_to_array(
            r,
            view,
            ProjectionSettings(alpha=1.0),
            OverlaySettings(frustum=False, trajectory=False, error_map=True, error_scale_m=4.0),
        )
        return out[50:70, 70:90].reshape(-1, 3).astype(int)

    same = colour([0.0, 0.0, 0.0])
    off = colour([2.0, 0.0, 0.0])
    # 70 % of the ramp colour over the video's grey 128: green at 0 m, yellow at 2 m of 4.
    np.testing.assert_allclose(
        np.median(same, axis=0), 0.3 * 128 + 0.7 * np.array([0.10, 0.80, 0.25]) * 255, atol=3
    )
    np.testing.assert_allclose(
        np.median(off, axis=0), 0.3 * 128 + 0.7 * np.array([1.00, 0.85, 0.10]) * 255, atol=3
    )
    r.release()


@pytest.mark.gl
def test_ground_at_grazing_angles_takes_the_video_without_striping(gl_ctx):
    """A camera 1.5 m above flat ground looking 2 deg down (a hand-held clip on the assumed
    ground): the ground it sees runs out to tens of metres at incidences of 1-3 deg, where one
    depth texel spans metres of ground. Every ground fragment inside its frustum, out to 80 m,
    must take the video: no bands of model colour (the nine-case rule's neighbours lie metres
    nearer there; the slope-scaled bias must follow the incidence that far)."""
    ground = shapes.quad([-200, -200, 0], [400, 0, 0], [0, 400, 0]).primitive((0.1, 0.1, 0.8, 1.0))
    r = make_renderer(gl_ctx, [ground])
    try:
        cam = Camera.create(
            Intrinsics.from_fov(VIDEO_W, VIDEO_H, 60),
            [0, 0, 1.5],
            rotations.camera_quat_from_hpr(0.0, -2.0, 0.0),
            near=0.5,
            far=2000.0,
        )
        r.set_video_frame(np.full((VIDEO_H, VIDEO_W, 3), 255, np.uint8))  # white video
        r.set_projector(cam)
        view = view_camera([0, -20, 40], [0, 40, 0], 400, 300)
        out = render(r, view, alpha=1.0)
        hit, _ = hit_plane(view, 2, 0.0)  # where each view pixel meets the ground, ENU m
        uv, depth = cam.project(hit)
        inside = (
            (depth > 0.6)
            & (uv[:, 0] > 2)
            & (uv[:, 0] < VIDEO_W - 2)
            & (uv[:, 1] > 2)
            & (uv[:, 1] < VIDEO_H - 2)
        )
        near = inside & (np.linalg.norm(hit[:, :2], axis=1) < 80.0)
        pixels = out.reshape(-1, 3)[near]
        assert near.sum() > 2000
        assert np.mean(pixels.min(axis=1) > 200) > 0.99  # white (the video), not the model's blue
    finally:
        r.release()


def test_a_private_context_leaves_the_callers_context_current(gl_ctx, tmp_path):
    """A job that makes and releases its own context (a sample video rendered, a still) on the
    thread of a caller holding another: afterwards the caller's clears and draws still reach its
    own framebuffer. Without keep_current the caller's clear landed nowhere and its read gave
    whatever memory the renderbuffer was allocated over (the flaky ortho test of stop 41)."""
    from app.render.context import create_offscreen_context, keep_current
    from app.simulate.video import render_video

    size = (32, 24)
    color = gl_ctx.renderbuffer(size, 4, dtype="f4")
    fbo = gl_ctx.framebuffer([color])
    try:
        with keep_current():
            other = create_offscreen_context()
            other.clear(0.0, 0.0, 1.0, 1.0)
            other.release()
        fbo.use()
        fbo.clear(1.0, 0.5, 0.25, 1.0)
        data = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(-1, 4)
        assert np.all(data == [1.0, 0.5, 0.25, 1.0])

        ground = shapes.quad([-5.0, -5.0, 0.0], [10.0, 0, 0], [0, 10.0, 0])
        eye = np.array([[0.0, 0.0, 10.0]])
        q = look_at_quat(eye[0], np.zeros(3), (0.0, 1.0, 0.0))
        intr = Intrinsics(32, 24, 20.0, 20.0, 16.0, 12.0)
        out = render_video(
            tmp_path / "v.mp4", MeshData([ground.primitive()]), intr, eye, q[None], np.zeros(1)
        )
        assert out.stat().st_size > 0
        fbo.use()
        fbo.clear(0.0, 1.0, 0.0, 1.0)
        data = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(-1, 4)
        assert np.all(data == [0.0, 1.0, 0.0, 1.0])
    finally:
        fbo.release()
        color.release()
