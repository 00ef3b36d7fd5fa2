"""Real-device traps (issue 11), each on files written here: GNSS fixes that are not positions, a
hovering drone's course, a drone's own yaw, phones without a magnetometer or a scene, a glTF with
its ECEF offset in Y-up."""

from __future__ import annotations

import numpy as np
import pytest

from app.attitude.heading import COURSE_HOLD_SPEED_MPS, course_headings
from app.camera.trajectory import estimate_velocity
from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.streams import GnssTrack, plausible_fixes, with_accuracy
from app.session import open_session
from app.simulate.phone import walking_pan, write_session


def _track(t, enu, frame=LocalFrame(46.0, 14.0, 300.0)):
    llh = frame.enu_to_geodetic(np.asarray(enu, float))
    return GnssTrack(np.asarray(t, float), llh[:, 0], llh[:, 1], llh[:, 2], None, None, "track.csv")


def test_fixes_that_are_not_positions_are_dropped_counted_and_said():
    t = np.arange(20.0)
    enu = np.column_stack([1.2 * t, np.zeros(20), np.zeros(20)])
    g = _track(t, enu)
    lat, lon, h = g.lat.copy(), g.lon.copy(), g.h.copy()
    lat[0], lon[0] = 0.0, 0.0  # before the receiver had a lock
    lat[7] += 0.01  # 1.1 km off for one second: a jump
    h[12] = 1e38
    messages = Messages()
    kept = plausible_fixes(GnssTrack(t, lat, lon, h, None, None, "track.csv"), messages)
    assert list(np.setdiff1d(t, kept.t)) == [0.0, 7.0, 12.0]
    (note,) = messages.items
    assert (
        "1 at 0 N 0 E" in note
        and "1 jumps" in note
        and "1 with impossible heights" in note
        and "17 of 20 kept" in note
    )


def test_a_bad_first_fix_does_not_condemn_the_rest():
    t = np.arange(10.0)
    enu = np.column_stack([np.zeros(10), 1.0 * t, np.zeros(10)])
    enu[0] = [5000.0, 0.0, 0.0]  # a stale fix far away, then good ones
    kept = plausible_fixes(_track(t, enu), Messages())
    assert list(kept.t) == list(t[1:])


@pytest.mark.parametrize("jump_at_s", [8.0, 16.0])
def test_a_step_that_holds_is_kept_for_the_checks_to_name(jump_at_s):
    """A receiver spoofed 200 m east from jump_at_s of a 24 s track at 30 Hz (a DJI subtitle):
    every fix is kept, on either side of the median, and the note says so, not a jump: which
    side lies is for the checks against the scene and the IMU to tell. Dropping them as jumps had kept
    the median's side and condemned the other's fixes for 1.4 s around the step (honest ones,
    where the lie held the median). A 200 m spike of 1 s is still a jump."""
    t = np.arange(0.0, 24.0, 1.0 / 30.0)
    enu = np.column_stack([9.0 * t, np.zeros(len(t)), np.zeros(len(t))])
    enu[t >= jump_at_s, 0] += 200.0
    messages = Messages()
    kept = plausible_fixes(_track(t, enu), messages)
    assert len(kept.t) == len(t)
    (note,) = messages.items
    assert (
        f"step faster than 150 m/s 1 time(s) and hold there (first at t = {jump_at_s:.1f} s" in note
    )
    spiked = enu.copy()
    spiked[(t >= 4.0) & (t < 5.0), 0] += 200.0
    messages = Messages()
    kept = plausible_fixes(_track(t, spiked), messages)
    assert len(kept.t) == len(t) - 30 and "30 jumps" in " ".join(messages.items)
    # a 1 Hz receiver's glitch of 3 fixes (2 s) is a spike, not a step
    slow = np.arange(20.0)
    glitch = np.column_stack([9.0 * slow, np.zeros(20), np.zeros(20)])
    glitch[8:11, 0] += 500.0
    kept = plausible_fixes(_track(slow, glitch), Messages())
    assert list(np.setdiff1d(slow, kept.t)) == [8.0, 9.0, 10.0]


def test_the_receivers_own_fix_type_and_dop_are_used():
    t = np.arange(6.0)
    g = _track(t, np.column_stack([t, t, np.zeros(6)]))
    messages = Messages()
    kept = plausible_fixes(
        g, messages, fix_type=[3, 3, 2, 3, 3, 3], dop=[1.0, 1.0, 1.0, 9.0, 1.0, 1.0]
    )
    assert list(kept.t) == [0, 1, 4, 5]
    assert "1 2D fixes" in messages.items[0] and "1 with DOP above 5" in messages.items[0]


def test_no_fix_in_range_is_an_error_naming_the_file():
    g = GnssTrack(np.arange(3.0), np.full(3, 95.0), np.zeros(3), np.zeros(3), None, None, "bad.csv")
    with pytest.raises(DataFormatError, match="bad.csv field 'lat': no fix has a latitude"):
        plausible_fixes(g, Messages())


def test_a_hovering_drone_keeps_its_heading():
    """GNSS noise of a hovering drone (0.7 m RMS at 1 Hz) makes apparent speeds of ~1 m/s in
    random directions; below COURSE_HOLD_SPEED_MPS the course heading is held, not followed."""
    rng = np.random.default_rng(4)
    t = np.arange(60.0)
    east = np.concatenate([4.0 * t[:20], np.full(40, 76.0)])  # flies east for 20 s, then hovers
    enu = np.column_stack([east, np.zeros(60), np.full(60, 80.0)]) + rng.normal(0, 0.7, (60, 3)) * [
        1,
        1,
        0,
    ]
    v = estimate_velocity(t, enu)
    assert (
        np.hypot(v[25:, 0], v[25:, 1]).max() > COURSE_HOLD_SPEED_MPS
    )  # raw fix-to-fix speeds exceed it
    heading = course_headings(t, v)
    assert np.all(
        np.abs(rotations.wrap_degrees(heading[2:] - 90.0)) < 20.0
    )  # east all along, no flips


def test_a_drone_subtitle_with_its_own_yaw_gives_the_course_heading(tmp_path):
    """No gimbal angles, but the aircraft's yaw ([Drone: Yaw ...]): the course source takes it."""
    from app.footage.clips import open_clip
    from app.simulate.phone import write_video
    from app.solve.track import solve_frames

    lines = []
    for k in range(12):
        lines.append(
            f"{k + 1}\n00:00:{k:02d},000 --> 00:00:{k + 1:02d},000\n"
            f"[latitude: {46.0 + 1e-5 * k:.6f}] [longitude: 14.000000] [rel_alt: 50.0 abs_alt: 350.0] "
            f"[Drone: Yaw:{200.0 + k:.1f}, Pitch:0.0, Roll:0.0]\n"
        )
    (tmp_path / "c.srt").write_text("\n".join(lines))
    video = write_video(tmp_path / "c.mp4", np.arange(330) / 30.0, (96, 54), 0)
    s = open_clip(video)
    assert s.sources == ["course"] and "heading from the aircraft's yaw" in s.heading_note
    poses = solve_frames(s, "course")
    assert poses.hpr[0, 0] == pytest.approx(200.0, abs=0.01)  # not north, the direction of travel
    assert poses.hpr[150, 0] == pytest.approx(205.0, abs=0.05)
    assert poses.hpr[0, 1] == pytest.approx(-30.0, abs=0.01)


@pytest.fixture(scope="module")
def phone_without_magnetometer(tmp_path_factory):
    d = tmp_path_factory.mktemp("nomag")
    return write_session(d, walking_pan(), duration_s=8.0, with_mag=False)


def test_a_phone_without_magnetometer_takes_heading_from_the_course(phone_without_magnetometer):
    s = open_session(phone_without_magnetometer)
    assert s.heading_from_course and s.heading_note.startswith("heading from the GNSS course")
    assert any("no magnetometer" in w for w in s.messages.items)
    assert s.sources[0] == "gd-imu"


def test_a_phone_without_magnetometer_shows_its_own_orientation_first(
    phone_without_magnetometer, tmp_path
):
    import shutil

    d = tmp_path / "s"
    shutil.copytree(phone_without_magnetometer.parent, d)
    shutil.copy(d / "truth.csv", d / "phone.csv")
    manifest = d / "session.toml"
    manifest.write_text(
        manifest.read_text().replace(
            'gyr = "gyr.csv"\n', 'gyr = "gyr.csv"\norientation = "phone.csv"\n'
        )
    )
    s = open_session(manifest)
    assert s.sources[0] == "phone" and "phone's own orientation is shown first" in s.heading_note


def test_a_session_without_a_scene_projects_on_the_assumed_ground(tmp_path):
    from app.solve.track import solve_frames

    manifest = write_session(tmp_path, walking_pan(), duration_s=6.0)
    text = manifest.read_text()
    start, end = text.index("[scene]"), text.index("[video]")
    manifest.write_text(text[:start] + text[end:])
    s = open_session(manifest)
    assert s.scene_path is None and any("assumed flat ground" in w for w in s.messages.items)
    lo, hi = s.scene().bounds()
    track = s.frame.geodetic_to_enu(s.gnss.lat, s.gnss.lon, s.gnss.h)
    assert np.all(track[:, :2] > lo[:2]) and np.all(track[:, :2] < hi[:2])
    assert np.all(np.abs(track[:, 2] - 1.5 - lo[2]) < 0.5)  # the ground is the first fix less 1.5 m
    assert np.isfinite(solve_frames(s, "gd-ahrs").enu).all()


def test_a_gltf_with_y_up_ecef_lands_where_it_belongs(tmp_path):
    """The official 3D Tiles tools write the ECEF offset into a node translation in glTF's Y-up
    axes and leave the Y-up -> Z-up turn to the runtime. geofuse reads both ways and takes the
    one near the session, so a triangle at the origin lands at the origin, not 6,000 km away."""
    import trimesh

    from app.scene import load_scene

    frame = LocalFrame(34.8, 113.53, 110.0)
    local = np.array([[-5.0, -5.0, 0.0], [5.0, -5.0, 0.0], [0.0, 5.0, 0.0]])  # ENU metres
    ecef = frame.enu_to_ecef(local)
    centre = ecef.mean(axis=0)
    y_up = lambda p: np.column_stack([p[:, 0], p[:, 2], -p[:, 1]])  # noqa: E731  (Z-up -> Y-up)
    scene = trimesh.Scene()
    mesh = trimesh.Trimesh(vertices=y_up(ecef - centre), faces=[[0, 1, 2]], process=False)
    scene.add_geometry(
        mesh, transform=trimesh.transformations.translation_matrix(y_up(centre[None])[0])
    )
    path = tmp_path / "tile.glb"
    scene.export(path)
    placed = load_scene(path, frame)
    np.testing.assert_allclose(placed.primitives[0].positions, local, atol=0.01)


def test_a_stated_accuracy_fills_only_the_fixes_that_state_none():
    t = np.arange(4.0)
    g = _track(t, np.column_stack([t, t, np.zeros(4)]))
    filled, n = with_accuracy(g, 2.0)
    assert n == 4 and list(filled.h_acc) == [2.0] * 4
    g = GnssTrack(g.t, g.lat, g.lon, g.h, None, np.array([0.8, np.nan, 0.0, 3.0]), g.path)
    filled, n = with_accuracy(g, 2.0)
    assert n == 2 and list(filled.h_acc) == [0.8, 2.0, 2.0, 3.0]
    assert with_accuracy(filled, 9.0) == (filled, 0)
