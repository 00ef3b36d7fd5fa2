"""Cold start without GNSS (issue 52): a clip with no fix at all, given an area (`--near LAT,LON
--radius M --height M`), finds its first pose by searching the scene and carries on; an area
with no scene is refused with a message; the options are parsed and bad values refused. The
session is a short simulated drone orbit (a world that differs from its model) with every fix
removed (app.simulate.lies `outage`)."""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import replace

import numpy as np
import pytest
import shapely

from app.camera.fixes import MISSING, FixStatus
from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.cli.common import open_with_source, start_area
from app.cli.parser import build_parser, joined_negative_values
from app.core.errors import DataFormatError, GeofuseError
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.video import frames_at
from app.register import coldstart
from app.register.coldstart import ground_footprint, held_positions, scene_positions, searched
from app.register.fuse import Keyframe
from app.register.keyframe import PoseFix, posed
from app.register.solve import Registrar, RegistrationSettings, default_prior, registered_track
from app.session import open_session
from app.session.camera_track import camera_track
from app.session.start import StartArea
from app.simulate import session as sample
from app.simulate.lies import Lie, falsify
from app.simulate.sample import SAMPLE_SCENE
from app.simulate.stadium import SITE_ORIGIN
from app.solve.accuracy import true_track

DURATION_S = 2.0
HEIGHT_M = 60.0  # the orbit's, above the site's ground (app.simulate.flights)
OFF_M = 150.0  # the area's centre from the true start


@pytest.fixture(scope="module")
def no_gnss(tmp_path_factory):
    """A 2 s drone orbit with every GNSS fix removed: its manifest."""
    out = tmp_path_factory.mktemp("cold-start")
    config = replace(sample.quick_config(DURATION_S), flight="orbit", seed=11)
    sample.write_sample_session(out / "clean", SAMPLE_SCENE, config)
    return falsify(out / "clean", out / "no-gnss", Lie("outage", -1e6))


def _near(session, east_m: float, north_m: float) -> tuple[float, float]:
    """(lat, lon) of the point east_m, north_m (m) from the true start."""
    p = true_track(session).frame_camera(0).position
    lat, lon, _ = session.frame.enu_to_geodetic([p[0] + east_m, p[1] + north_m, 0.0])
    return float(lat), float(lon)


@pytest.mark.gl
def test_a_clip_without_gnss_starts_from_an_area_and_carries_on(no_gnss, gl_ctx):
    session = open_session(no_gnss)
    assert len(session.gnss.t) == 0
    with pytest.raises(DataFormatError, match="--near LAT,LON"):  # no position without an area
        session.positions()
    d = OFF_M / math.sqrt(2.0)
    session = replace(session, start=StartArea.near(*_near(session, d, d), 300.0, HEIGHT_M))
    track = registered_track(session, ctx=gl_ctx)
    poses = track.frame_poses()
    truth = true_track(session)
    true = truth.poses_at(truth.clock.media_s[poses.index])
    error = np.linalg.norm(poses.enu - true.enu, axis=1)
    # the registration's usual error: 3 pixels' footprint at the range it looks at (its checks
    # allow 2.5 px RMS) - the orbit looks at the hall's middle, 10 m up, from 110 m out, 60 m up
    i = session.intrinsics
    looked_at = float(np.linalg.norm(true.enu[0] - [0.0, 0.0, 10.0]))
    tolerance = 3.0 * looked_at / i.fx  # 0.9 m
    assert error[0] <= tolerance, error[0]
    assert np.median(error) <= tolerance / 2 and error.max() <= 2 * tolerance, error
    said = [m.text for m in session.messages.since(0) if m.text.startswith("cold start:")]
    assert len(said) == 1, said
    # "found ..., 150 m from the area's centre": the area's centre is OFF_M from the true start
    far = re.search(r"found at .* (\d+) m from the area's centre", said[0])
    assert far and abs(int(far.group(1)) - OFF_M) <= 2, said[0]
    assert re.search(r"searched \d\.\d\d km2 of scene in 300 m around", said[0]), said[0]
    assert set(poses.gnss) == {MISSING}  # no frame stands on a fix
    assert track.registration.used >= 0.8 * len(track.registration.keyframes)


@pytest.mark.gl
def test_an_area_without_the_clip_is_refused_with_a_message(no_gnss, gl_ctx):
    session = open_session(no_gnss)
    session = replace(session, start=StartArea.near(*_near(session, 2000.0, 0.0), 300.0, HEIGHT_M))
    with pytest.raises(GeofuseError) as caught:
        registered_track(session, ctx=gl_ctx)
    said = str(caught.value)
    assert "cold start: searched 0.00 km2 of scene in 300 m around" in said, said
    # the scene (360 m square about the origin) lies 2 km - 180 m - 300 m off... from the
    # centre: its nearest edge is about 2000 - 180 m east of the true start's x = 0
    edge = re.search(r"the scene's nearest edge is (\d+) m from its centre", said)
    assert edge and abs(int(edge.group(1)) - (2000 - 180)) <= 5, said


@pytest.mark.gl
def test_an_attitude_turned_beyond_the_tolerance_is_taken_where_two_frames_agree(
    no_gnss, gl_ctx, monkeypatch
):
    """An IMU alone tilts its vertical in a turn (12-14 deg on the survey's turns): the platform's
    attitude turned 14 deg about the east axis, every pose the search registers lies beyond the
    10 deg it accepts; the first frame's is held, the next frame's agrees with it (the same
    offset within 3 deg, within 30 m/s of it), and that one is taken and said."""
    turn = rotations.from_rotvec([math.radians(14.0), 0.0, 0.0])  # about the east axis
    plain = coldstart.attitude_track

    def turned(*args, **kw):
        track = plain(*args, **kw)
        q = rotations.canonical(rotations.multiply(turn, track.poses.q_device))
        return replace(track, poses=replace(track.poses, q_device=q))

    monkeypatch.setattr(coldstart, "attitude_track", turned)
    session = open_session(no_gnss)
    d = OFF_M / math.sqrt(2.0)
    session = replace(session, start=StartArea.near(*_near(session, d, d), 300.0, HEIGHT_M))
    poses = registered_track(session, ctx=gl_ctx).frame_poses()
    said = [m.text for m in session.messages.since(0) if m.text.startswith("cold start:")]
    assert len(said) == 1 and "(t = 1.0 s)" in said[0], said  # the second frame searched
    found = re.search(r"turned (\d+) deg from the platform's attitude, as the pose", said[0])
    # 14 deg and the platform's own error (a few degrees): beyond the 10 deg accepted alone
    assert found and 10 < int(found.group(1)) <= 14 + 5, said[0]
    truth = true_track(session)
    error = np.linalg.norm(poses.enu - truth.poses_at(truth.clock.media_s[poses.index]).enu, axis=1)
    assert np.median(error) <= 0.45, error  # as with the platform's own attitude (above)


@pytest.mark.gl
def test_a_lost_keyframe_is_searched_for_around_where_the_track_leads(no_gnss, gl_ctx):
    """Registration lost (no fix trusted, nothing registered for 3 s) searches the keyframe's
    frame as a cold start does, over 30 m + 1/2 x 1 m/s^2 x (3 s)^2 = 34.5 m around where the
    last keyframes lead: from 20 m off the truth it finds the pose (within the orbit's 0.9 m,
    above); from 80 m off, the truth lies outside the disc and it says so."""
    session = open_session(no_gnss)
    truth = true_track(session)
    registrar = Registrar(session, RegistrationSettings(), gl_ctx)
    try:
        k = 30  # the frame at 1 s
        true = truth.frame_camera(k)
        ((_, rgb),) = frames_at(session.video, [k], registrar.settings.long_side)
        miss = PoseFix(False, "textures: 2 matches on the model (need 15)", 2, 0, np.nan)
        for off, found in ((20.0, True), (80.0, False)):
            near = posed(true, np.asarray(true.position) + [off, 0.0, 0.0], true.orientation)
            t = float(session.frame_times[k])
            radius = registrar.settings.lost_radius(3.0)
            assert radius == 34.5
            fix, solved = registrar.reacquired(rgb, true, [near], radius, t, [], miss, "lost 3 s")
            if found:
                assert solved is not None and fix.ok, fix.reason
                assert np.linalg.norm(np.asarray(solved.position) - true.position) <= 0.9
            else:
                assert solved is None and fix.reason.startswith(miss.reason), fix.reason
                assert "lost 3 s, not found within 34 m" in fix.reason, fix.reason
    finally:
        registrar.release()


@pytest.mark.gl
def test_a_clip_whose_gnss_begins_late_is_searched_for_around_its_first_fix(no_gnss, gl_ctx):
    """Before any keyframe registers, where no fix holds the prior (GNSS that begins late: the
    prior holds its first fix back over the clip), a keyframe that does not register is
    searched for over the disc the platform flies from the nearest fix in time: 30 m + 20 m/s
    x the seconds to it. Here the first fix comes 8 s after the clip's first frame and the
    prior stands 150 m east of the truth: the first keyframe is searched over 30 + 20 x 8 =
    190 m and found, those after it chained from it, every one within the orbit's 0.9 m
    (above). With the disc shrunk to nothing the same keyframes find nothing: the search, not
    the regular registration from 150 m off, found them (a pose it registers turned beyond the
    search's 10 deg is refused while nothing is trusted)."""
    session = open_session(no_gnss)
    truth = true_track(session)
    start = np.asarray(truth.frame_camera(0).position) + [150.0, 0.0, 0.0]
    prior = camera_track(session, default_prior(session), positions=held_positions(session, start))
    first_fix = float(session.frame_times[0]) + 8.0
    prior = replace(prior, fixes=FixStatus.all_used([first_fix, first_fix + 1.0]))
    for settings, found in ((RegistrationSettings(), True), (RegistrationSettings(unfixed_max_m=0.0), False)):  # fmt: skip
        registrar = Registrar(session, settings, gl_ctx)
        try:
            reg = registrar.run(prior)
        finally:
            registrar.release()
        solved = [k for k in reg.keyframes if k.registered]
        if not found:
            assert solved == [], [(k.time_s, k.reason) for k in reg.keyframes]
            continue
        assert reg.searched[0][1] == pytest.approx(190.0, abs=0.1) and reg.searched[0][2]
        assert len(solved) >= len(reg.keyframes) - 1, [k.reason for k in reg.keyframes]
        for k in solved:
            assert np.linalg.norm(k.position - truth.frame_camera(k.index).position) <= 0.9


def test_poses_agree_when_turned_alike_and_near_enough():
    """Offsets 2 deg apart agree, 5 deg apart do not; a pose 40 m from the held one a second
    later does not (30 m/s plus 5 m: 35 m), two seconds later it does (65 m)."""
    s = coldstart.SearchSettings()
    first = [(10.0, np.array([0.0, 0.0, 60.0]), rotations.about_z(12.0))]
    assert coldstart.agreeing(first, 11.0, [20.0, 0.0, 60.0], rotations.about_z(14.0), s)
    assert not coldstart.agreeing(first, 11.0, [20.0, 0.0, 60.0], rotations.about_z(17.0), s)
    assert not coldstart.agreeing(first, 11.0, [40.0, 0.0, 60.0], rotations.about_z(12.0), s)
    assert coldstart.agreeing(first, 12.0, [40.0, 0.0, 60.0], rotations.about_z(12.0), s)


def test_the_options_are_parsed_and_bad_values_refused(capsys, tmp_path):
    parser = build_parser()
    argv = ["solve", "s.toml", "--out", "o.csv", "--near", "-33.9,18.4", "--radius", "500"]
    args = parser.parse_args(joined_negative_values([*argv, "--height", "80"]))
    area = start_area(args)
    assert area.centre == (-33.9, 18.4) and area.radius_m == 500.0 and area.height_m == 80.0
    assert start_area(parser.parse_args(["solve", "s.toml", "--out", "o.csv"])) is None
    default = start_area(parser.parse_args(["render", "--out", "o.png", "--near", "1,2"]))
    assert default.radius_m == 300.0 and default.height_m is None
    for bad, said in (
        (["--near", "34.8,113.5", "--radius", "0"], "--radius: expected a finite number in (0"),
        (["--near", "34.8,113.5", "--radius", "-5"], "--radius: expected a finite number in (0"),
        (["--near", "95,113.5"], "--near: latitude 95 is outside [-90, 90]"),
        (["--near", "34.8"], "--near: expected 2 comma-separated finite numbers"),
        (["--near", "34.8,113.5", "--height", "0"], "--height: expected a finite number in (0"),
        (["--near", "34.8,113.5", "--start-area", "a.geojson"], "not allowed with argument"),
    ):
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args(["export", "footprints", "s.toml", "--out", "o.geojson", *bad])
        assert exit_.value.code == 2
        assert said in capsys.readouterr().err
    for alone in (["--radius", "300"], ["--height", "60"]):
        with pytest.raises(GeofuseError, match="goes with --near"):
            start_area(parser.parse_args(["solve", "s.toml", "--out", "o.csv", *alone]))
    polygon = tmp_path / "area.geojson"
    ring = [[113.52, 34.79], [113.54, 34.79], [113.54, 34.81], [113.52, 34.81], [113.52, 34.79]]
    polygon.write_text(json.dumps({"type": "Polygon", "coordinates": [ring]}))
    area = start_area(
        parser.parse_args(["solve", "s.toml", "--out", "o.csv", "--start-area", str(polygon)])
    )
    assert area.polygon is not None and area.centre == pytest.approx((34.80, 113.53))
    with pytest.raises(GeofuseError, match="--radius goes with --near"):
        start_area(
            parser.parse_args(
                ["solve", "s.toml", "--out", "o.csv", "--start-area", str(polygon), "--radius", "9"]
            )
        )


def test_solve_with_near_opens_the_session_on_registered_from_the_area(no_gnss):
    args = argparse.Namespace(
        srt=None, fov=None, lens=None, scene=None, dem=None, buildings=None, ortho=None,
        dem_vertical=None, dem_error=0.5, world=None, imagery=None, terrain=None, out=None,
        source=None, near=(34.8, 113.53), start_area=None, radius=250.0, height=60.0,
    )  # fmt: skip
    session, source = open_with_source(no_gnss, args, (".csv",))
    assert source == "registered"
    assert session.start == StartArea.near(34.8, 113.53, 250.0, 60.0)
    assert searched(session)
    # the same clip with its GNSS: the area is not searched, and that is said (the simulator's
    # fixes begin 2 s before its clock's start, the manifest's video 80 ms after it)
    clean, _ = open_with_source(no_gnss.parent.parent / "clean" / "session.toml", args, (".csv",))
    assert not searched(clean)
    said = [m.text for m in clean.messages.since(0) if "not searched" in m.text]
    assert said == [
        "250 m around 34.80000, 113.53000: not searched, the clip has GNSS (from t = -2.1 s)"
    ]


def test_an_area_in_the_sessions_frame():
    """A circle's ENU polygon: its area pi r^2 (to its 256 segments' 0.01 %), centred where
    the centre lies; a polygon's: the degrees' box in metres (pyproj's ENU, to 0.1 %)."""
    frame = LocalFrame(*SITE_ORIGIN)
    circle = StartArea.near(34.801, 113.531, 300.0)
    enu = circle.enu_area(frame)
    assert enu.area == pytest.approx(math.pi * 300.0**2, rel=2e-4)
    e, n, _ = frame.geodetic_to_enu(34.801, 113.531, SITE_ORIGIN[2])
    assert (enu.centroid.x, enu.centroid.y) == pytest.approx((e, n), abs=0.01)
    np.testing.assert_allclose(circle.centre_enu(frame), [e, n], atol=1e-6)
    square = shapely.box(113.52, 34.79, 113.54, 34.81)
    box = StartArea.within(square).enu_area(frame)
    corners = frame.geodetic_to_enu([34.79, 34.81], [113.52, 113.54], [110.0, 110.0])
    width, height = corners[1, 0] - corners[0, 0], corners[1, 1] - corners[0, 1]
    assert box.area == pytest.approx(width * height, rel=1e-3)
    with pytest.raises(ValueError, match="radius must be positive"):
        StartArea.near(34.8, 113.5, 0.0)
    with pytest.raises(ValueError, match="not latitude, longitude"):
        StartArea.near(95.0, 113.5, 10.0)


def test_a_cameras_footprint_on_the_ground():
    """Straight down from 70 m with a 66 deg field across 640 x 360: a rectangle 2 x 70 tan 33
    deg = 90.9 m across and 51.1 m down (the vertical field from the aspect); looking level,
    what lies beyond the range cap (the rays at and above the horizon) stops at it."""
    intr = Intrinsics.from_fov(640, 360, 66.0)
    eye = np.array([10.0, -20.0, 70.0])
    down = Camera.create(intr, eye, look_at_quat(eye, eye - [0.0, 0.0, 1.0]))
    fp = ground_footprint(down, 0.0, 1000.0)
    w = 2 * 70 * math.tan(math.radians(33.0))
    h = w * 360 / 640
    assert fp.bounds == pytest.approx((10 - w / 2, -20 - h / 2, 10 + w / 2, -20 + h / 2), abs=1e-6)
    level = Camera.create(intr, eye, look_at_quat(eye, eye + [0.0, 1.0, 0.0]))
    fp = ground_footprint(level, 0.0, 1000.0)
    vfov = 2 * math.atan(math.tan(math.radians(33.0)) * 360 / 640)
    assert fp.bounds == pytest.approx(
        (
            10 - 1000.0 * math.sin(math.radians(33.0)),  # the left column's level ray, capped
            -20 + 70 / math.tan(vfov / 2),  # the bottom row meets the ground
            10 + 1000.0 * math.sin(math.radians(33.0)),
            -20 + 1000.0,  # straight ahead at the cap
        ),
        abs=1e-6,
    )


def test_the_scenes_own_track_drops_a_keyframe_registered_wrongly(no_gnss):
    """Keyframes every 0.5 s along a straight 6 m/s line, one registered 6 m off: the track
    through them leaves that one out, goes through the others exactly, and is carried on at
    their velocity to the clip's ends (for at most 3 s)."""
    session = open_session(no_gnss)
    t0 = float(session.frame_times[0])
    ts = t0 + 0.25 + 0.5 * np.arange(5)

    def line(t: np.ndarray) -> np.ndarray:
        return np.column_stack([6.0 * (t - t0), np.full(len(t), -110.0), np.full(len(t), 60.0)])

    p = line(ts)
    p[2, 0] += 6.0
    keyframes = [
        Keyframe(i, float(t), True, "", 30, 30, 0.5, 2, p[i], np.array([1.0, 0, 0, 0]), p[i], np.array([1.0, 0, 0, 0]))
        for i, t in enumerate(ts)
    ]  # fmt: skip
    track = scene_positions(session, keyframes)
    assert ts[2] not in track.t
    at = np.array([t0, ts[1], ts[2], ts[3], float(session.frame_times[-1])])
    geo = track.geodetic_at(at)
    enu = session.frame.geodetic_to_enu(geo[:, 0], geo[:, 1], geo[:, 2])
    np.testing.assert_allclose(enu, line(at), atol=0.01)
