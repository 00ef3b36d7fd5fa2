"""Real lenses (issue 13): the models against OpenCV's, profiles in the gyroflow format, and a
checkerboard filmed through a fisheye lens projected on a wall with straight edges."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.lens import Lens, enclosing_intrinsics, read_profile
from app.camera.pinhole import Camera
from app.core.errors import DataFormatError
from app.geodesy import rotations
from app.scene.mesh import MeshData, Primitive

FISHEYE = Lens.create(
    "fisheye", 1920, 1080, 846.7, 846.3, 951.3, 547.6, (0.0734, -0.0208, 0.0452, -0.0252)
)
BROWN = Lens.create(
    "brown", 1280, 720, 1000.0, 1002.0, 645.0, 355.0, (-0.21, 0.08, 0.001, -0.0015, -0.01)
)


@pytest.mark.parametrize("lens", [FISHEYE, BROWN], ids=["fisheye", "brown"])
def test_the_model_matches_opencv(lens):
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(2)
    ab = rng.uniform(-0.9, 0.9, (200, 2)) * [1.0, 0.55]
    k = np.array([[lens.fx, 0, lens.cx], [0, lens.fy, lens.cy], [0, 0, 1]])
    pts = np.column_stack([ab, np.ones(len(ab))])[:, None, :]
    if lens.kind == "fisheye":
        expected, _ = cv2.fisheye.projectPoints(
            pts, np.zeros(3), np.zeros(3), k, np.array(lens.coeffs)
        )
    else:
        expected, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k, np.array(lens.coeffs))
    np.testing.assert_allclose(lens.distort(ab), expected[:, 0, :], atol=1e-6)
    np.testing.assert_allclose(lens.undistort(lens.distort(ab)), ab, atol=1e-9)


def test_a_stretch_and_a_new_resolution():
    lens = Lens.create(
        "fisheye", 1920, 1080, 846.7, 846.3, 951.3, 547.6, FISHEYE.coeffs, stretch=1.25
    )
    ab = np.array([[0.5, -0.2], [0.0, 0.0]])
    plain = FISHEYE.distort(ab)
    np.testing.assert_allclose(lens.distort(ab)[:, 0] - lens.cx, 1.25 * (plain[:, 0] - FISHEYE.cx))
    half = lens.scaled(960, 540)
    np.testing.assert_allclose(half.distort(ab), lens.distort(ab) / 2, atol=1e-9)
    np.testing.assert_allclose(half.undistort(half.distort(ab)), ab, atol=1e-9)


def test_profiles_in_the_gyroflow_format(shared_data, tmp_path):
    path = next((shared_data / "lens_profiles" / "GoPro").glob("GoPro_HERO (2014)*1920x1080*.json"))
    lens = read_profile(path)
    assert (
        lens.kind == "fisheye"
        and (lens.width, lens.height) == (1920, 1080)
        and lens.fx == pytest.approx(846.707, abs=1e-3)
    )
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"calib_dimension": {"w": 10}}))
    with pytest.raises(DataFormatError, match="bad.json"):
        read_profile(bad)


def test_the_enclosing_pinhole_sees_the_whole_image():
    intr = enclosing_intrinsics(FISHEYE)
    a0, a1, b0, b1 = FISHEYE.border_extent()
    assert intr.width / (2 * intr.fx) >= max(-a0, a1) and intr.height / (2 * intr.fy) >= max(
        -b0, b1
    )


def _checker(ab: np.ndarray, cell: float = 0.08) -> np.ndarray:
    """Black and white cells of `cell` normalised units: a board on a wall facing the camera."""
    on = (
        np.floor(ab[..., 0] / cell).astype(int) + np.floor(ab[..., 1] / cell).astype(int)
    ) % 2 == 0
    return np.where(on[..., None], 235, 20).astype(np.uint8).repeat(3, axis=-1)


def _pixels(w: int, h: int) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return np.column_stack([u.ravel(), v.ravel()])


def _renders(renderer, view: Camera, shots: list[tuple[np.ndarray, Camera]]) -> list[np.ndarray]:
    """One off-screen render of `view` per (video frame, projector), the video opaque."""
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.render.offscreen import render_to_array

    out = []
    for image, projector in shots:
        renderer.set_video_frame(image)
        renderer.set_projector(projector)
        out.append(
            render_to_array(
                renderer,
                view,
                ProjectionSettings(alpha=1.0),
                OverlaySettings(frustum=False, trajectory=False),
            )
        )
    return out


def _wall() -> MeshData:
    """A wall 80 m x 50 m, 10 m north of the origin."""
    wall = np.array([[-40, 10, -25], [40, 10, -25], [40, 10, 25], [-40, 10, 25]], np.float32)
    return MeshData(
        [
            Primitive(
                positions=wall,
                colors=np.full((4, 4), 0.5, np.float32),
                indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
            )
        ]
    )


def _cells(img: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    dark = ndimage.binary_erosion(
        img.mean(axis=2) < 110, iterations=2
    )  # cells meet only at corners: part them
    labels, n = ndimage.label(dark)
    h, w = dark.shape
    whole = [
        k + 1
        for k, (r, c) in enumerate(ndimage.find_objects(labels))
        if r.start > 0 and c.start > 0 and r.stop < h and c.stop < w
    ]
    return np.array(
        ndimage.center_of_mass(dark, labels, whole)
    )  # cells cut by the image's edge left out


@pytest.mark.gl
def test_a_fisheye_checkerboard_lands_straight_on_a_wall(gl_ctx):
    """A board filmed through a GoPro-like fisheye (its image bent), projected with the lens model
    onto a wall 10 m ahead, and seen from the camera's place through a pinhole: the cells land
    where the pinhole render of the straight board puts them (centres within 2 px). Projected
    as if pinhole, they do not."""
    from app.render.renderer import FusionRenderer

    lens = FISHEYE.scaled(640, 360)
    distorted = _checker(lens.undistort(_pixels(640, 360)).reshape(360, 640, 2))
    pin = Intrinsics(640, 360, 420.0, 420.0, 320.0, 180.0)
    straight = _checker(
        np.stack(
            np.meshgrid((np.arange(640) + 0.5 - 320) / 420, (np.arange(360) + 0.5 - 180) / 420),
            axis=-1,
        )
    )
    q = rotations.camera_quat_from_hpr(0.0, 0.0, 0.0)  # looking north, level
    view = Camera.create(pin, [0, 0, 0], q, 0.5, 100.0)
    renderer = FusionRenderer(gl_ctx, _wall())
    try:
        with_lens, as_pinhole, reference = _renders(renderer, view, [
            (distorted, Camera.create(enclosing_intrinsics(lens), [0, 0, 0], q, 0.5, 100.0, lens)),
            (distorted, Camera.create(Intrinsics(640, 360, lens.fx, lens.fy, lens.cx, lens.cy), [0, 0, 0], q, 0.5, 100.0)),
            (straight, Camera.create(pin, [0, 0, 0], q, 0.5, 100.0)),
        ])  # fmt: skip
    finally:
        renderer.release()
    ref = _cells(reference)
    assert len(ref) > 40
    for img, ok in ((with_lens, True), (as_pinhole, False)):
        got = _cells(img)
        d = np.linalg.norm(ref[:, None, :] - got[None, :, :], axis=2).min(axis=1)
        if ok:
            assert np.max(d) <= 2.0, np.max(d)
        else:
            assert np.max(d) > 5.0, np.max(d)


def test_a_gopro_clip_gets_a_lens_profile_chosen_and_said(shared_data, tmp_path):
    from app.footage.clips import open_clip

    clip = shared_data / "real" / "gopro" / "max-heromode.mp4"
    s = open_clip(clip)
    assert (
        s.lens is not None
        and s.lens.kind == "fisheye"
        and (s.lens.width, s.lens.height) == (848, 480)
    )
    assert any(w.startswith("lens: fisheye model from Max profile") for w in s.messages.items)
    assert (
        s.intrinsics.hfov_deg > 2 * np.degrees(np.arctan(848 / 2 / s.lens.fx)) - 1e-6
    )  # the depth pass encloses the image
    own = tmp_path / "mine.json"
    profile = json.loads(
        next(
            (shared_data / "lens_profiles" / "GoPro").glob("GoPro_HERO (2014)*1920x1080*.json")
        ).read_text()
    )
    own.write_text(json.dumps(profile))
    mine = open_clip(clip, lens=own)
    assert (
        mine.lens.fx == pytest.approx(846.7074163244357 * 848 / 1920)
        and own.resolve() in mine.inputs
    )
    assert open_clip(clip, hfov_deg=90.0).lens is None  # --fov: a pinhole, as asked


def _dji_mp4(path, items):
    from app.simulate.mp4meta import add_user_data
    from app.simulate.phone import write_video

    return add_user_data(write_video(path, np.arange(6) / 30.0, (96, 54), 0), items)


def test_the_dji_camera_is_read_from_the_mp4(tmp_path):
    """DJI subtitles never name the aircraft; the MP4 does, in the layouts DJI writes: a bare
    camera code, an encoder string in QuickTime text or in an iTunes-style item list. Files that
    name nothing DJI (a re-encode: Lavf) give None; a code geofuse does not know is kept."""
    from app.io.dji_mp4 import read_dji_camera
    from app.simulate.mp4meta import box, intl_text

    cam = read_dji_camera(
        _dji_mp4(tmp_path / "a.mp4", {"\xa9mdl": b"FC3411\0\0", "\xa9too": intl_text("DJIAir2S")})
    )
    assert (cam.model, cam.code, cam.encoder) == (
        "Air 2S",
        "FC3411",
        "DJIAir2S",
    ) and "FC3411" in cam.found_in
    cam = read_dji_camera(_dji_mp4(tmp_path / "b.mp4", {"\xa9too": intl_text("DJIMavic3Classic")}))
    assert (cam.model, cam.code) == ("Mavic3Classic", "") and "encoder" in cam.found_in
    ilst = box("ilst", box("\xa9too", box("data", b"\0\0\0\x01\0\0\0\0DJI Air3")))
    hdlr = box("hdlr", bytes(8) + b"mdirappl" + bytes(9))
    assert (
        read_dji_camera(_dji_mp4(tmp_path / "c.mp4", {"meta": bytes(4) + hdlr + ilst})).model
        == "Air3"
    )
    assert (
        read_dji_camera(_dji_mp4(tmp_path / "d.mp4", {})) is None
    )  # PyAV's own encoder string: Lavf...
    cam = read_dji_camera(_dji_mp4(tmp_path / "e.mp4", {"\xa9mdl": b"fc9999"}))
    assert (cam.model, cam.code) == ("", "FC9999")
    truncated = tmp_path / "f.mp4"
    data = (tmp_path / "a.mp4").read_bytes()
    truncated.write_bytes(data[: data.index(b"moov") - 4 + 100])  # cut inside the movie box
    assert read_dji_camera(truncated) is None


def test_dji_profiles_are_found_under_their_many_spellings_and_shapes():
    """The database's users spell one drone several ways ('Mavic Air 2', 'AIR2', 'Air 2'); a
    profile of another frame shape is never stretched onto the video."""
    from app.camera.profiles import choose_profile, profile_names

    for model in ("Mavic Air 2", "Air3", "Mini 3 Pro", "Mavic3Classic", "Phantom 4"):
        path, why = choose_profile("DJI", model, 3840, 2160)
        d = json.loads(path.read_text())
        assert (d["calib_dimension"]["w"] / d["calib_dimension"]["h"]) == pytest.approx(
            16 / 9, rel=0.02
        ), why
        assert any(
            n in profile_names("DJI", model)
            for n in (
                "".join(c for c in d["camera_model"].lower() if c.isalnum()).removeprefix("dji"),
            )
        )
    assert "air2" in profile_names("DJI", "Mavic Air 2") and profile_names(
        "GoPro", "GoPro Max"
    ) == {"max"}
    assert choose_profile("DJI", "Mavic 3", 3840, 2160) is None  # its profiles are all 1.90:1
    assert choose_profile("DJI", "Mavic 3", 5120, 2700) is not None
    assert choose_profile("DJI", "Spark", 1920, 1080) is None  # no profile at all


@pytest.mark.gl
def test_footprints_through_a_lens_use_its_own_border():
    """A fisheye camera 40 m over flat ground looking straight down: each exported corner lies
    where the lens's own (undistorted) corner ray meets the ground, not the enclosing pinhole's."""
    from app.export.records import FootprintCaster
    from app.geodesy.enu import LocalFrame
    from app.scene.ground_plane import ground_plane

    lens = FISHEYE.scaled(960, 540)
    frame = LocalFrame(46.05, 14.5, 300.0)
    q = rotations.camera_quat_from_hpr(0.0, -90.0, 0.0)
    cam = Camera.create(enclosing_intrinsics(lens), [0.0, 0.0, 40.0], q, lens=lens)
    caster = FootprintCaster(ground_plane(np.zeros(2), 0.0, 2000.0), frame, cam.intrinsics)
    try:
        r = caster.record(cam)
    finally:
        caster.release()
    rays = cam.pixel_rays([[0, 0], [960, 0], [960, 540], [0, 540]])
    expected = np.array([0.0, 0.0, 40.0]) + rays * (40.0 / -rays[:, 2:3])
    got = frame.geodetic_to_enu(r.corners[:, 0], r.corners[:, 1], r.corners[:, 2])
    np.testing.assert_allclose(
        got[:, :2], expected[:, :2], atol=0.25
    )  # the 1024-texel position map
    naive = 40.0 * (lens.width - lens.cx) / lens.fx  # the same focal length taken as a pinhole
    assert abs(got[1, 0]) > naive + 20.0  # the fisheye sees far wider than that


def test_fields_of_view_of_a_lens():
    pin = Lens.create("brown", 1000, 500, 500.0, 500.0, 500.0, 250.0, (0.0, 0.0, 0.0, 0.0, 0.0))
    assert pin.hfov_deg == pytest.approx(90.0) and pin.vfov_deg == pytest.approx(
        2 * np.degrees(np.arctan(0.5))
    )
    assert FISHEYE.hfov_deg > 2 * np.degrees(
        np.arctan(FISHEYE.cx / FISHEYE.fx)
    )  # wider than its focal length says


def _wall_image(
    intr: Intrinsics, q_mid: np.ndarray, turn: np.ndarray, axis=(0.0, 1.0, 0.0)
) -> np.ndarray:
    """What a rolling-shutter camera at the origin sees of a checkerboard wall 10 m north: the
    displayed pixel (u, v) read at fraction a u/W + b v/H + c of the readout (axis), exposed at
    orientation q_mid * exp(f * turn), f that fraction less 0.5 (turn: rad, camera frame, first
    row to last)."""
    w, h = intr.width, intr.height
    v, u = np.mgrid[0:h, 0:w] + 0.5
    f = (axis[0] * u / w + axis[1] * v / h + axis[2] - 0.5).ravel()
    q_row = rotations.multiply(
        np.tile(q_mid, (len(f), 1)), rotations.from_rotvec(f[:, None] * turn)
    )
    d = np.column_stack(
        [(u.ravel() - intr.cx) / intr.fx, -(v.ravel() - intr.cy) / intr.fy, -np.ones(len(f))]
    )
    world = rotations.rotate(q_row, d)
    hit = world * (10.0 / world[:, 1:2])
    on = (np.floor(hit[:, 0] / 0.8).astype(int) + np.floor(hit[:, 2] / 0.8).astype(int)) % 2 == 0
    return np.where(on, 235, 20).astype(np.uint8).reshape(h, w, 1).repeat(3, axis=2)


def _shutter_misses(
    gl_ctx, intr: Intrinsics, turn: np.ndarray, axis: tuple, undone: Camera, as_if: Camera
) -> tuple[float, float]:
    """90th percentiles (px) of how far the checkerboard cells land from a global shutter's when
    a frame read along `axis` while turning by `turn` is projected through `undone`, and through
    `as_if`. 90 %: a few cells at the frame's edge are cut by the image border (the sheared frame
    covers a slightly different part of the wall) and their centres move."""
    from app.render.renderer import FusionRenderer

    q_mid = np.asarray(undone.orientation)
    sheared = _wall_image(intr, q_mid, turn, axis)
    still = _wall_image(intr, q_mid, np.zeros(3))
    view = Camera.create(intr, [0, 0, 0], q_mid, 0.5, 100.0)
    renderer = FusionRenderer(gl_ctx, _wall())
    try:
        reference, corrected, wrong = _renders(
            renderer, view, [(still, view), (sheared, undone), (sheared, as_if)]
        )
    finally:
        renderer.release()
    ref = _cells(reference)
    assert len(ref) > 30
    return tuple(
        float(
            np.percentile(
                np.linalg.norm(ref[:, None, :] - _cells(img)[None, :, :], axis=2).min(axis=1), 90
            )
        )
        for img in (corrected, wrong)
    )


@pytest.mark.gl
def test_rolling_shutter_is_undone_row_by_row(gl_ctx):
    """A camera panning at 60 deg/s with a 30 ms readout shears a wall's checkerboard by ~20 px
    from the first row to the last. Projected with the rows' own poses (the shader's rolling
    shutter model), the cells land where a global shutter's would (within 2 px); projected as
    if every row were exposed at once, they do not."""
    intr = Intrinsics(640, 360, 420.0, 420.0, 320.0, 180.0)
    q_mid = rotations.camera_quat_from_hpr(0.0, 0.0, 0.0)
    turn = np.array([0.0, np.radians(60.0) * 0.030, 0.0])  # a pan about the camera's up axis
    undone, global_shutter = _shutter_misses(
        gl_ctx, intr, turn, (0.0, 1.0, 0.0),
        Camera.create(intr, [0, 0, 0], q_mid, 0.5, 100.0, rs_turn=turn), Camera.create(intr, [0, 0, 0], q_mid, 0.5, 100.0),
    )  # fmt: skip
    assert undone <= 2.0 and global_shutter > 5.0, (undone, global_shutter)


@pytest.mark.gl
def test_rolling_shutter_of_a_portrait_display_runs_across_its_columns(gl_ctx):
    """A phone held upright shows its landscape sensor turned 90 deg clockwise: the sensor's rows
    are read from the display's right edge to its left. A 60 deg/s tilt with a 30 ms readout,
    corrected along that axis, lands the cells where a global shutter's would (within 2 px);
    corrected along the display's rows, as for a landscape video, it does not."""
    from app.session.camera_track import readout_axis

    intr = Intrinsics(360, 640, 420.0, 420.0, 180.0, 320.0)
    q_mid = rotations.camera_quat_from_hpr(0.0, 0.0, 0.0)
    turn = np.array([0.0, np.radians(60.0) * 0.030, 0.0])
    axis = readout_axis(90)
    assert axis == (-1.0, 0.0, 1.0)
    undone, as_landscape = _shutter_misses(
        gl_ctx, intr, turn, axis,
        Camera.create(intr, [0, 0, 0], q_mid, 0.5, 100.0, rs_turn=turn, rs_axis=axis), Camera.create(intr, [0, 0, 0], q_mid, 0.5, 100.0, rs_turn=turn),
    )  # fmt: skip
    assert undone <= 2.0 and as_landscape > 5.0, (undone, as_landscape)


def test_a_session_track_carries_the_rolling_shutter_turn(tmp_path):
    """camera.readout_ms in a manifest: every camera of the track carries the turn between its
    first and last rows, the track's own rotation over the readout (here a phone on a walk:
    checked against the pose track at the row times)."""
    from app.session import open_session
    from app.session.camera_track import camera_track
    from app.simulate.phone import walking_pan, write_session

    manifest = write_session(tmp_path, walking_pan(), duration_s=6.0, rotation_cw=0)
    manifest.write_text(manifest.read_text().replace("[camera]\n", "[camera]\nreadout_ms = 30.0\n"))
    s = open_session(manifest)
    assert s.readout_s == pytest.approx(0.030)
    track = camera_track(s, "truth")
    k = 90
    cam = track.frame_camera(k)
    # Independently of the track's code: the simulated motion's own attitude at the first and
    # last rows (15 ms either side of the frame's time), seen through the phone's camera mount.
    t = (
        float(s.frame_times[k]) - 1_700_000_000.0
    )  # write_session's clock starts at its start_unix_s
    q_dev = walking_pan().attitude(np.array([t - 0.015, t + 0.015]))
    q_cam = rotations.multiply(q_dev, s.camera_mount())
    expected = rotations.to_scipy(
        rotations.multiply(rotations.conjugate(q_cam[0]), q_cam[1])
    ).as_rotvec()
    np.testing.assert_allclose(cam.rs_turn, expected, atol=2e-5)  # the 100 Hz truth file, slerped
    assert np.linalg.norm(cam.rs_turn) > 1e-4  # the walk turns the phone during a readout
