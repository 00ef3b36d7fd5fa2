"""Several projectors at once (issue 22's renderer): each its own depth test, the overlap rule
at a seam checked by pixels worked out by hand, an occluder's shadow filled by the other clip,
and eight projectors drawn together."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens, enclosing_intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.settings import OverlaySettings, ProjectionSettings
from app.io.video import rotate_for_display
from app.render.passes import AGE_SCORE_PER_S, SEAM
from app.render.still import render_still
from app.render.video_texture import YuvPlanes, yuv_to_rgb
from app.scene import shapes
from app.scene.ground_plane import ground_plane
from app.scene.mesh import MeshData

pytestmark = pytest.mark.gl

RED = np.array([255, 0, 0])
BLUE = np.array([0, 0, 255])
SIZE = 200  # the top view's pixels a side
TOP = Camera.create(
    Intrinsics.from_fov(SIZE, SIZE, 60.0),
    [0.0, 0.0, 50.0],
    look_at_quat([0.0, 0.0, 50.0], [0.0, 0.0, 0.0], (0.0, 1.0, 0.0)),
    0.5,
    500.0,
)
SETTINGS = ProjectionSettings(alpha=1.0, bias_constant_m=0.05)
NO_LINES = OverlaySettings(frustum=False, trajectory=False)


def _projector(eye, target, fov: float = 70.0) -> Camera:
    return Camera.create(
        Intrinsics.from_fov(160, 120, fov), eye, look_at_quat(eye, target), 0.5, 500.0
    )


def _solid(colour) -> np.ndarray:
    return np.broadcast_to(np.asarray(colour, np.uint8), (120, 160, 3)).copy()


def _pixel_of(point) -> tuple[int, int]:
    uv, _ = TOP.project(np.asarray(point, np.float64)[None])
    return int(uv[0, 1]), int(uv[0, 0])  # row, column


def _ground_x(row: int, col: int) -> float:
    """The ground point (x) the top view's pixel centre sees."""
    ray = TOP.pixel_rays([[col + 0.5, row + 0.5]])[0]
    return float(TOP.position[0] + ray[0] * TOP.position[2] / -ray[2])


def _score(eye, x: float, priority: float = 0.0, age_s: float = 0.0) -> float:
    """shaders/scene.frag's view_score for a level ground point (x, 0, 0)."""
    d = math.dist(eye, (x, 0.0, 0.0))
    return 10.0 * priority + eye[2] / d - d / 2000.0 - age_s * AGE_SCORE_PER_S


@pytest.mark.parametrize(
    "ages",
    [(0.0, 0.0), (0.0, 1 / 30), (1 / 30, 0.0)],
    ids=["same age", "west younger", "east younger"],
)
def test_the_overlap_rule_at_a_seam(ages):
    """Two projectors 20 m either side of the origin, 10 m up, both looking at it: east of the
    origin the east one is nearer and more head-on, so its blue wins; west, the red; across the
    seam the two blend as exp((score - best) / SEAM) says, pixel by pixel. At x = 0 their views
    tie (mirror images): there, with one frame a 30 fps interval older than the other
    (AGE_SCORE_PER_S / 30 = one SEAM of score), the younger takes about e / (1 + e)."""
    west, east = (-20.0, 0.0, 10.0), (20.0, 0.0, 10.0)
    rgb = render_still(
        ground_plane(np.zeros(2), 0.0, 200.0),
        _solid(RED),
        _projector(west, (0.0, 0.0, 0.0)),
        TOP,
        SETTINGS,
        NO_LINES,
        extras=[(_solid(BLUE), _projector(east, (0.0, 0.0, 0.0)), 0.0)],
        ages_s=list(ages),
    ).rgb.astype(float)
    assert AGE_SCORE_PER_S / 30 == pytest.approx(SEAM)
    row = SIZE // 2
    checked = 0
    for col in range(SIZE // 2 - 30, SIZE // 2 + 30, 3):
        x = _ground_x(row, col)
        sw, se = _score(west, x, age_s=ages[0]), _score(east, x, age_s=ages[1])
        w_east = 1.0 / (1.0 + math.exp((sw - se) / SEAM))
        expected = (1.0 - w_east) * RED + w_east * BLUE
        assert np.abs(rgb[row, col] - expected).max() <= 6.0, (col, x, rgb[row, col], expected)
        checked += 1
    assert checked == 20
    assert rgb[row, SIZE // 2 - 40, 0] > 250 and rgb[row, SIZE // 2 + 40, 2] > 250
    # On the tie (the column whose ground point is nearest x = 0, within 0.2 m): about half each
    # at the same age; e / (1 + e) = 0.73 for the younger.
    col = min(range(SIZE), key=lambda c: abs(_ground_x(row, c)))
    assert abs(_ground_x(row, col)) < 0.2
    red = rgb[row, col, 0] / 255.0
    if ages[0] == ages[1]:
        assert 0.4 < red < 0.6, red
    else:
        share = red if ages[0] < ages[1] else 1.0 - red
        assert 0.65 < share < 0.82, share


def test_each_projector_keeps_its_own_shadow_and_the_other_fills_it():
    """A 4 m box 10 m west of the origin stands in front of the west (red, priority 1: it wins
    wherever it sees) projector: on the ground in its shadow (x from -9 to -1.7 m along y = 0)
    the east (blue) projector's video shows; outside the shadow the red one's."""
    west, east = (-20.0, 0.0, 10.0), (20.0, 0.0, 10.0)
    box = shapes.box([-11.0, -1.0, 0.0], [-9.0, 1.0, 4.0]).primitive((0.5, 0.5, 0.5, 1.0))
    mesh = MeshData([*ground_plane(np.zeros(2), 0.0, 200.0).primitives, box])
    rgb = render_still(
        mesh,
        _solid(RED),
        _projector(west, (0.0, 0.0, 0.0), 90.0),
        TOP,
        SETTINGS,
        NO_LINES,
        extras=[(_solid(BLUE), _projector(east, (-5.0, 0.0, 0.0), 90.0), 0.0)],
        priority=1.0,
    ).rgb
    shadow = rgb[_pixel_of((-4.0, 0.0, 0.0))]
    beside = rgb[_pixel_of((-4.0, 4.0, 0.0))]  # outside the shadow (it is 1.7 m wide there)
    east_of_it = rgb[_pixel_of((1.0, 0.0, 0.0))]
    assert shadow[2] > 240 and shadow[0] < 15, shadow  # blue: the red one is occluded
    assert beside[0] > 240 and beside[2] < 15, beside
    assert east_of_it[0] > 240 and east_of_it[2] < 15, east_of_it
    # with the east one removed, the shadow shows no video at all (the model's own grey ground)
    alone = render_still(
        mesh, _solid(RED), _projector(west, (0.0, 0.0, 0.0), 90.0), TOP, SETTINGS, NO_LINES
    ).rgb
    grey = alone[_pixel_of((-4.0, 0.0, 0.0))]
    assert grey[0] < 240 and abs(int(grey[0]) - int(grey[2])) < 30


def _ring(colours: list) -> list[tuple[np.ndarray, Camera, tuple]]:
    """Projectors on a ring of 12 m, each 8 m straight above its own patch of ground with a
    solid image of its colour: (image, camera, the patch's centre) each."""
    views = []
    for k, colour in enumerate(colours):
        a = 2 * math.pi * k / len(colours)
        centre = (12.0 * math.cos(a), 12.0 * math.sin(a), 0.0)
        eye = (centre[0], centre[1], 8.0)
        cam = Camera.create(
            Intrinsics.from_fov(160, 120, 30.0),
            eye,
            look_at_quat(eye, centre, (0.0, 1.0, 0.0)),
            0.5,
            500.0,
        )
        views.append((_solid(colour), cam, centre))
    return views


def _ring_still(views: list, ages_s: list[float] | None = None):
    """The still of a ring of projectors (`_ring`) seen from TOP over a ground plane: the first
    as the session's projector, the rest as further ones."""
    (first_img, first_cam, _), *rest = views
    return render_still(
        ground_plane(np.zeros(2), 0.0, 200.0),
        first_img,
        first_cam,
        TOP,
        SETTINGS,
        NO_LINES,
        extras=[(img, cam, 0.0) for img, cam, _ in rest],
        ages_s=ages_s,
    )


def test_eight_projectors_drawn_together():
    """Eight projectors on a ring, each straight down on its own patch of ground with its own
    colour: each patch shows its colour."""
    colours = [
        (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0),
        (255, 0, 255), (0, 255, 255), (255, 128, 0), (128, 0, 255),
    ]  # fmt: skip
    views = _ring(colours)
    rgb = _ring_still(views).rgb
    for img, _, centre in views:
        assert np.abs(rgb[_pixel_of(centre)].astype(int) - img[0, 0]).max() <= 3, centre


FAR = (100.0, 0.0, 0.0)  # ground the top view does not see


def _top_with(extras: list) -> np.ndarray:
    """The top view of a wide ground (int RGB) with `extras` (frame, camera, priority) as further
    projectors; the first looks at ground out of view, so that only the further ones show."""
    return render_still(
        ground_plane(np.zeros(2), 0.0, 300.0),
        _solid((0, 0, 255)),
        _projector((100.0, 5.0, 10.0), FAR),
        TOP,
        SETTINGS,
        NO_LINES,
        extras=extras,
    ).rgb.astype(int)


FISHEYE = Lens.create(
    "fisheye", 1920, 1080, 846.7, 846.3, 951.3, 547.6, (0.0734, -0.0208, 0.0452, -0.0252)
).scaled(320, 180)


@pytest.mark.parametrize("fisheye_at", [0, 1])
def test_further_projectors_each_through_their_own_lens(fisheye_at):
    """Two further projectors beside the first, one pinhole and one through a fisheye lens (the
    shader variant knows which, by their order): the fisheye's video is a gradient whose red
    counts its columns and green its rows, and ground points seen from the top show the colour
    of the pixel the lens model (app.camera.lens) puts them at, where the pinhole's would be tens of
    levels off."""
    eye = (0.0, 0.0, 10.0)
    fish = Camera.create(
        enclosing_intrinsics(FISHEYE),
        eye,
        look_at_quat(eye, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        0.5,
        500.0,
        FISHEYE,
    )
    u, v = np.meshgrid(np.arange(320) + 0.5, np.arange(180) + 0.5)
    gradient = np.stack([u / 320 * 255, v / 180 * 255, np.full_like(u, 128)], -1)
    gradient = np.round(gradient).astype(np.uint8)
    pinhole = (_solid((255, 0, 0)), _projector((100.0, 0.0, 10.0), FAR), 0.0)  # out of view
    extras = [pinhole, pinhole]
    extras[fisheye_at] = (gradient, fish, 0.0)
    rgb = _top_with(extras)
    as_pinhole = Camera.create(
        Intrinsics(320, 180, FISHEYE.fx, FISHEYE.fy, FISHEYE.cx, FISHEYE.cy),
        fish.position,
        fish.orientation,
        0.5,
        500.0,
    )
    off_by = []
    for x, y in [(2.0, 1.0), (-6.0, 3.0), (9.0, -4.0), (-12.0, -5.0), (14.0, 6.0)]:
        row, col = _pixel_of((x, y, 0.0))
        ray = TOP.pixel_rays([[col + 0.5, row + 0.5]])[0]
        seen = TOP.position + ray * (TOP.position[2] / -ray[2])  # the pixel centre's ground point
        uv, _ = fish.project(seen[None])
        assert 5 < uv[0, 0] < 315 and 5 < uv[0, 1] < 175, (x, y, uv)
        expected = np.array([uv[0, 0] / 320 * 255, uv[0, 1] / 180 * 255, 128])
        assert np.abs(rgb[row, col] - expected).max() <= 4, (x, y, rgb[row, col], expected)
        pin_uv, _ = as_pinhole.project(seen[None])
        off_by.append(np.abs(pin_uv[0] / [320, 180] * 255 - expected[:2]).max())
    assert max(off_by) > 20, off_by


@pytest.mark.parametrize("rotation", [0, 90, 270])
def test_a_further_clips_playback_frame_matches_its_rgb_still(rotation):
    """A further projector given a playback frame as stored (Y, U, V planes, turned and converted
    to RGB on the GPU, as the viewer hands them) shows what the same frame converted and turned
    on the CPU (the reference conversion) shows as an RGB still, to the conversion's rounding."""
    rng = np.random.default_rng(rotation)
    h, w = (48, 64) if rotation % 180 == 0 else (64, 48)  # stored so that the display is 64x48
    y = np.kron(rng.integers(40, 220, (h // 8, w // 8)), np.ones((8, 8))).astype(np.uint8)
    u = np.kron(rng.integers(60, 200, (h // 8, w // 8)), np.ones((4, 4))).astype(np.uint8)
    v = np.kron(rng.integers(60, 200, (h // 8, w // 8)), np.ones((4, 4))).astype(np.uint8)
    eye = (0.0, 0.0, 40.0)  # its image covers most of the top view
    cam = Camera.create(
        Intrinsics.from_fov(64, 48, 60.0),
        eye,
        look_at_quat(eye, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        0.5,
        500.0,
    )
    # an RGB still first, out of view: the planes are the second further projector's
    still = (_solid((0, 255, 0)), _projector((100.0, -5.0, 10.0), FAR), 0.0)
    from_planes = _top_with([still, (YuvPlanes(y, u, v, rotation, bt709=False), cam, 0.0)])
    from_rgb = _top_with([still, (rotate_for_display(yuv_to_rgb(y, u, v), rotation), cam, 0.0)])
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    rays = TOP.pixel_rays(np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5]))
    ground = TOP.position + rays * (TOP.position[2] / -rays[:, 2:3])
    uv, depth = cam.project(ground)
    inner = np.minimum(uv % 8, 8 - uv % 8).min(axis=1) >= 2.5  # away from the blocks' edges
    inside = (depth > 0) & np.all((uv > 0) & (uv < [64, 48]), axis=1) & inner
    assert inside.sum() > 2000
    diff = np.abs(from_planes - from_rgb).reshape(-1, 3).max(axis=1)[inside]
    assert np.median(diff) <= 1 and np.percentile(diff, 99) <= 3
    # and the frame is there: the blocks' colours differ across the image
    assert from_planes.reshape(-1, 3)[inside].std(axis=0).min() > 10


def test_further_projectors_beyond_the_drivers_samplers_are_left_out_and_said(gl_ctx):
    """A driver that lets a shader sample fewer textures than the projectors need (GL guarantees
    16; llvmpipe has 32): the further projectors that fit are drawn, first ones first, and the
    rest are left out and said, instead of a shader that fails to link."""
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer

    views = _ring([(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)])
    r = FusionRenderer(gl_ctx, ground_plane(np.zeros(2), 0.0, 200.0), deferred=False)
    try:
        r.set_video_frame(views[0][0])
        r.set_projector(views[0][1])
        r.set_extra_projectors([(cam, img, 0.0) for img, cam, _ in views[1:]])
        r.scene_pass.max_samplers = 6 + 2 * 2 + 1  # the first's six, and two further stills
        rgb = render_to_array(r, TOP, SETTINGS, NO_LINES).astype(int)
        assert r.scene_pass.left_out == 1 and r.scene_pass.variant["EXTRA_COUNT"] == 2
        assert r.scene_pass.left_out_message == (
            "1 further clip(s) not drawn: this OpenGL driver lets a shader sample 11 textures at most"
        )
        for img, _, centre in views[:3]:
            assert np.abs(rgb[_pixel_of(centre)] - img[0, 0]).max() <= 3, centre
        last = rgb[_pixel_of(views[3][2])]
        assert np.abs(last - views[3][0][0, 0]).max() > 100  # the model's colour there
        r.scene_pass.max_samplers = 32
        rgb = render_to_array(r, TOP, SETTINGS, NO_LINES).astype(int)
        assert r.scene_pass.left_out == 0 and r.scene_pass.left_out_message is None
        assert np.abs(rgb[_pixel_of(views[3][2])] - views[3][0][0, 0]).max() <= 3
    finally:
        r.release()


def test_render_pairs_images_and_poses_by_order(tmp_path, capsys):
    """`geofuse render` with two --image and two --pose (one --fov for both): the red image
    lands west of the seam and the blue east, as in the seam test; a third --pose is refused."""
    from PIL import Image

    from app.cli import main
    from app.geodesy.enu import LocalFrame

    ground = tmp_path / "ground.obj"
    ground.write_text("v -200 -200 0\nv 200 -200 0\nv 200 200 0\nv -200 200 0\nf 1 2 3\nf 1 3 4\n")
    origin = (46.05, 14.5, 300.0)
    frame = LocalFrame(*origin)
    images, poses = [], []
    for name, colour, eye in (("red", RED, (-20.0, 0.0, 10.0)), ("blue", BLUE, (20.0, 0.0, 10.0))):
        path = tmp_path / f"{name}.png"
        Image.fromarray(_solid(colour)).save(path)
        lat, lon, h = frame.enu_to_geodetic(np.array([eye]))[0]
        heading = 90.0 if eye[0] < 0 else 270.0
        pitch = -math.degrees(math.atan2(eye[2], abs(eye[0])))
        images += ["--image", str(path)]
        poses += ["--pose", f"{lat},{lon},{h},{heading},{pitch},0"]
    out = tmp_path / "two.png"
    base = ["render", "--scene", str(ground), "--origin", ",".join(map(str, origin))]
    view = ["--view-from", "0,0,50", "--look-at", "0,0.001,0", "--size", "200x200", "--alpha", "1"]
    args = base + images + poses + ["--fov", "70"] + view + ["--out", str(out)]
    assert main(args) == 0, capsys.readouterr().err
    assert "2 images projected" in capsys.readouterr().out
    rgb = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert rgb[100, 60, 0] > 240 and rgb[100, 60, 2] < 15  # west: red
    assert rgb[100, 140, 2] > 240 and rgb[100, 140, 0] < 15  # east: blue
    extra = poses[-2:]
    assert main(base + images + poses + extra + ["--fov", "70", "--out", str(out)]) == 2
    assert "--pose: give one for each --image (2), got 3" in capsys.readouterr().err
