"""Projectors as deferred decals (issue 31): each projector's reach on the screen worked out by
hand, and the deferred pictures checked pixel by pixel against the forward full-cost pass on the
same frame (at most one screen pixel of difference, along occlusion edges)."""

from __future__ import annotations

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.settings import OverlaySettings, ProjectionSettings
from app.render.coverage import (
    MIN_DEPTH_LONG_SIDE,
    box_planes,
    convex_hull_2d,
    coverage,
    depth_long_side,
    polygon_pixels,
    polytope_vertices,
)
from app.scene import shapes
from app.scene.ground_plane import ground_plane
from app.scene.mesh import MeshData

NO_LINES = OverlaySettings(frustum=False, trajectory=False)
SETTINGS = ProjectionSettings(alpha=1.0, bias_constant_m=0.05)
GREY = (0.5, 0.5, 0.5, 1.0)


def _camera(eye, target, w=160, h=120, fov=60.0, up=(0.0, 0.0, 1.0)) -> Camera:
    return Camera.create(
        Intrinsics.from_fov(w, h, fov), eye, look_at_quat(eye, target, up), 0.5, 500.0
    )


# -- the reach, by hand ------------------------------------------------------------------------


def test_a_box_is_its_eight_corners():
    v = polytope_vertices(box_planes([0, 0, 0], [1, 2, 3]))
    assert len(v) == 8
    corners = {tuple(c) for c in np.round(v, 9)}
    assert corners == {(x, y, z) for x in (0, 1) for y in (0, 2) for z in (0, 3)}


def test_hull_of_a_square_and_its_centre():
    hull = convex_hull_2d([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [1, 0]])
    assert len(hull) == 4 and [0.5, 0.5] not in hull.tolist()
    x, y = hull[:, 0], hull[:, 1]
    assert 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) == pytest.approx(1.0)


def test_a_projector_looking_down_reaches_its_footprint_on_the_ground():
    """A projector 20 m up looking straight down with a 90 x 90 degree view lights the ground
    square |x|, |y| <= 20 m; the scene is that ground (a thin box). Seen from straight above at
    100 m with a 60 degree view, the square's corners land at NDC +-20 / (100 tan 30 deg) = 0.346:
    the reach is that square (the frustum above the ground adds nothing the ground does not)."""
    projector = _camera([0, 0, 20], [0, 0, 0], 100, 100, 90.0, up=(0, 1, 0))
    view = _camera([0, 0, 100], [0, 0, 0], 200, 200, 60.0, up=(0, 1, 0))
    reach = coverage(projector, view, [[-500, -500, -0.1], [500, 500, 0.0]], margin_m=0.0)
    half = 20.0 / (100.0 * np.tan(np.radians(30.0)))
    lo, hi = reach.polygon.min(axis=0), reach.polygon.max(axis=0)
    np.testing.assert_allclose(lo, [-half, -half], atol=0.01)
    np.testing.assert_allclose(hi, [half, half], atol=0.01)
    assert len(reach.polygon) == 4
    # Depth from the projector over depth from the view: largest at the box's bottom, 20.1 m
    # from the projector and 100.1 m from the view.
    assert reach.ratio == pytest.approx(20.1 / 100.1, rel=1e-6)
    assert polygon_pixels(reach.polygon, 200, 200) == pytest.approx((half * 100) ** 2 * 4, rel=0.02)


def test_a_projector_away_from_the_scene_or_the_view_reaches_nothing():
    view = _camera([0, -50, 30], [0, 0, 0])
    scene = [[-10, -10, 0], [10, 10, 5]]
    looking_up = _camera([0, 0, 10], [0, 0, 60], up=(0, 1, 0))
    assert coverage(looking_up, view, scene, margin_m=0.0) is None
    behind_view = _camera([0, -80, 30], [0, -200, 0])
    assert coverage(behind_view, view, [[-30, -300, 0], [30, 10, 5]]) is None


def test_the_view_inside_the_frustum_needs_the_full_depth_map():
    projector = _camera([0, -40, 20], [0, 0, 0], fov=80.0)
    view = _camera([0, -20, 12], [0, 0, 0])
    reach = coverage(projector, view, [[-50, -50, 0], [50, 50, 20]])
    assert reach.ratio == float("inf")
    assert depth_long_side(projector, view, reach.ratio, 2048) == 2048
    # Above a low scene the eye is outside what the projector lights, but so near it that
    # nothing less than the full map will do.
    low = coverage(projector, view, [[-50, -50, 0], [50, 50, 5]])
    assert 10 < low.ratio < float("inf")
    assert depth_long_side(projector, view, low.ratio, 2048) == 2048


def test_depth_map_size_gives_a_texel_a_screen_pixel_at_the_worst_point():
    """One depth texel must span at most one window pixel: the depth map's focal length (texels)
    >= the view's (pixels) times the largest depth ratio; quantised up to 2^(k/4)."""
    projector = _camera([0, 0, 20], [0, 30, 0], w=400, h=300, fov=60.0)
    view = _camera([0, -100, 50], [0, 30, 0], w=800, h=600, fov=60.0)
    f_view = view.intrinsics.fx
    for ratio in (0.1, 0.3, 0.5):
        side = depth_long_side(projector, view, ratio, 4096)
        focal_texels = projector.intrinsics.fx * side / projector.intrinsics.width
        assert focal_texels >= f_view * ratio - 1e-6
        assert focal_texels <= f_view * ratio * 2**0.25 + 1e-6 or side == MIN_DEPTH_LONG_SIDE
    assert depth_long_side(projector, view, 10.0, 2048) == 2048
    assert depth_long_side(projector, view, 1e-4, 2048) == MIN_DEPTH_LONG_SIDE


# -- deferred against forward, pixel by pixel --------------------------------------------------


def _labels(rgb: np.ndarray, colours: list) -> np.ndarray:
    """Which source each pixel shows: the index of the nearest of `colours` (the model grey
    first, then each clip's solid colour), or -1 where none is within 40."""
    d = np.stack([np.abs(rgb - np.asarray(c)).max(axis=-1) for c in colours])
    out = d.argmin(axis=0)
    out[d.min(axis=0) > 40] = -1
    return out


def _near_an_edge(labels: np.ndarray) -> np.ndarray:
    """Pixels within one pixel (8-neighbourhood) of a place where the label changes."""
    pad = np.pad(labels, 1, mode="edge")
    h, w = labels.shape
    edge = np.zeros_like(labels, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            edge |= pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] != labels
    return edge


def _both_paths(gl_ctx, mesh, first, extras, view, settings=SETTINGS, priority=0.0):
    """The same frame through the forward pass and the deferred decals: (forward, deferred) RGB,
    and the deferred renderer's first depth-map size against the forward one's."""
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer

    out, sizes = [], []
    for deferred in (False, True):
        r = FusionRenderer(gl_ctx, mesh, deferred=deferred)
        try:
            assert r.deferred is deferred
            r.set_video_frame(first[0])
            r.set_projector(first[1], priority)
            r.set_extra_projectors([(cam, img, prio) for img, cam, prio in extras])
            out.append(render_to_array(r, view, settings, NO_LINES).astype(int))
            sizes.append(r.depth.size)
        finally:
            r.release()
    return out[0], out[1], sizes


def _solid(colour, w=160, h=120) -> np.ndarray:
    return np.broadcast_to(np.asarray(colour, np.uint8), (h, w, 3)).copy()


def _assert_same_but_edges(forward, deferred, colours, at_least=2000):
    lf, ld = _labels(forward, colours), _labels(deferred, colours)
    assert (lf >= 0).all() and (ld >= 0).all()
    differ = lf != ld
    assert (lf > 0).sum() > at_least  # the clips cover much of the view
    assert not np.any(differ & ~_near_an_edge(lf)), np.argwhere(differ & ~_near_an_edge(lf))[:5]
    return differ.sum()


@pytest.mark.gl
def test_two_clips_with_an_occluder_match_the_full_cost_path(gl_ctx):
    """Two clips from either side light a wall with a pillar in front: each keeps the pillar's
    shadow and the other fills it (the higher priority where both see). Deferred and forward
    agree but for pixels at most one screen pixel from an occlusion edge, with the deferred
    depth maps smaller (sized to what the view shows of them)."""
    wall = shapes.quad([-20, 20, 0], [40, 0, 0], [0, 0, 20]).primitive(GREY)
    pillar = shapes.box([-1.0, 12.0, 0.0], [1.0, 14.0, 16.0], bottom=True).primitive(GREY)
    mesh = MeshData([wall, pillar])
    red, blue = (255, 0, 0), (0, 0, 255)
    west = _camera([-8, 0, 8], [0, 20, 8], fov=70.0)
    east = _camera([8, 0, 8], [0, 20, 8], fov=70.0)
    view = _camera([0, -25, 12], [0, 20, 8], w=400, h=300, fov=50.0)
    forward, deferred, sizes = _both_paths(
        gl_ctx, mesh, (_solid(red), west), [(_solid(blue), east, 1.0)], view
    )
    colours = [_model_grey(forward, red, blue), red, blue, _sky(forward)]
    differ = _assert_same_but_edges(forward, deferred, colours)
    assert sizes[1][0] < sizes[0][0], sizes
    assert differ < 0.01 * forward.shape[0] * forward.shape[1]
    # Both clips are seen, and the pillar's shadows: red and blue both cover pixels.
    labels = _labels(deferred, colours)
    assert (labels == 1).sum() > 1000 and (labels == 2).sum() > 1000


def _sky(rgb: np.ndarray) -> np.ndarray:
    """The background colour (the top-left corner sees no model in these views)."""
    return rgb[0, 0]


def _model_grey(rgb, *clips) -> np.ndarray:
    """The most common colour that is neither a clip's nor the sky's (the lit model)."""
    flat = rgb.reshape(-1, 3)
    keep = np.ones(len(flat), bool)
    for c in (*clips, _sky(rgb)):
        keep &= np.abs(flat - np.asarray(c)).max(axis=1) > 40
    values, counts = np.unique(flat[keep], axis=0, return_counts=True)
    return values[counts.argmax()]


@pytest.mark.gl
def test_eight_clips_by_priority_match_the_full_cost_path(gl_ctx):
    """Eight clips in a ring over the ground, overlapping, each a colour and a priority: where
    several see the ground the highest priority wins on both paths (priority overrides the view
    score), so the pictures agree but along edges."""
    colours = [
        (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0),
        (255, 0, 255), (0, 255, 255), (255, 128, 0), (128, 0, 255),
    ]  # fmt: skip
    views = []
    for k, colour in enumerate(colours):
        angle = 2 * np.pi * k / 8
        centre = (12.0 * np.cos(angle), 12.0 * np.sin(angle), 0.0)
        eye = (centre[0] * 1.2, centre[1] * 1.2, 25.0)
        views.append((_solid(colour), _camera(eye, centre, fov=50.0), float(k)))
    top = _camera([0, 0, 60], [0, 0, 0], 240, 240, 60.0, up=(0, 1, 0))
    mesh = ground_plane(np.zeros(2), 0.0, 200.0)
    pillar = shapes.box([-2, -2, 0], [2, 2, 10], bottom=True).primitive(GREY)
    mesh = MeshData([*mesh.primitives, pillar])
    first, extras = views[0], views[1:]
    forward, deferred, _ = _both_paths(
        gl_ctx, mesh, (first[0], first[1]), extras, top, priority=first[2]
    )
    palette = [_model_grey(forward, *colours), *colours, _sky(forward)]
    _assert_same_but_edges(forward, deferred, palette)
    seen = set(np.unique(_labels(deferred, palette)).tolist())
    assert set(range(1, 9)) <= seen  # every clip shows somewhere


@pytest.mark.gl
def test_deferred_drawing_in_a_viewport_lands_where_a_whole_target_does(gl_ctx):
    """The window draws the scene into a rectangle of its framebuffer (the panels beside it):
    the deferred frame drawn into a viewport offset by (37, 21) px equals the same view drawn
    into a target of its own size (the pixel rays and the copy follow the viewport)."""
    from app.render.offscreen import OffscreenTarget
    from app.render.renderer import FusionRenderer

    mesh = ground_plane(np.zeros(2), 0.0, 200.0)
    projector = _camera([0, -20, 15], [0, 10, 0], fov=60.0)
    view = _camera([10, -40, 25], [0, 10, 0], w=200, h=150)
    image = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    r = FusionRenderer(gl_ctx, mesh, deferred=True)
    whole = OffscreenTarget(gl_ctx, 200, 150)
    big = OffscreenTarget(gl_ctx, 300, 200)
    try:
        r.set_video_frame(image)
        r.set_projector(projector)
        r.draw(view, whole.fbo, SETTINGS, NO_LINES)
        alone = whole.read().astype(int)
        big.fbo.use()
        big.fbo.clear(0.0, 0.0, 0.0, 1.0)
        big.fbo.viewport = (37, 21, 200, 150)
        r.draw(view, big.fbo, SETTINGS, NO_LINES)
        inside = big.read().astype(int)[200 - 21 - 150 : 200 - 21, 37 : 37 + 200]
        assert r.deferred_pass.drawn == 1
        # The same pixels; the linear video filter may round a pixel's ray (computed from the
        # fragment's position less the viewport's) a level apart.
        assert np.abs(inside - alone).max() <= 1
        assert (np.abs(alone - alone[0, 0]).max(axis=-1) > 0).mean() > 0.3  # the drape shows
    finally:
        whole.release()
        big.release()
        r.release()


def test_software_rasterisers_are_told_from_gpus():
    from app.render.context import software_rasteriser

    assert software_rasteriser("llvmpipe (LLVM 15.0.6, 256 bits)")
    assert software_rasteriser("softpipe")
    assert not software_rasteriser("NVIDIA H100 80GB HBM3/PCIe/SSE2")
    assert not software_rasteriser("AMD Radeon RX 7900 XTX (radeonsi, navi31, LLVM 15.0.6)")
    assert not software_rasteriser("Mesa Intel(R) UHD Graphics 620 (KBL GT2)")
