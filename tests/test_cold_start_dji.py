"""A DJI clip whose subtitle has no position at all (the aircraft flew without a fix: jammed, or
indoors; DJI writes latitude and longitude 0) is searched for from an area (issue 52's cold start)
at the height the subtitle's barometer gives above take-off, straight from its files: the clip
(app.simulate.drone's weave, 3 s), its subtitle with the gimbal's angles and no fix, and the
sample site as a georeferenced tileset (--scene). What it cannot start from is said, naming the
file."""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from app.cli import main
from app.core.errors import DataFormatError, GeofuseError, ManifestError
from app.footage.clips import open_clip
from app.geodesy.enu import LocalFrame
from app.io.dji_srt import read_srt, takeoff_heights
from app.register.coldstart import platform_height
from app.scene.layers import Layer
from app.session import open_session
from app.session.start import StartArea
from app.simulate import drone
from app.simulate.sample import SAMPLE_SCENE
from app.simulate.stadium import SITE_ORIGIN
from app.simulate.tileset import write_site
from tests.conftest import run_viewer

SECONDS = 3.0
OFF_M = 150.0  # the area's centre from the true start


@pytest.fixture(scope="module")
def unfixed(tmp_path_factory):
    """(video, subtitle without a fix but with gimbal angles, the site's tileset)."""
    folder = tmp_path_factory.mktemp("dji-unfixed")
    video = drone.write_video(folder / "DJI_0001.MP4", SECONDS, (320, 180))
    srt = folder / "DJI_0001.SRT"
    srt.write_text(drone.srt_text(SECONDS, 0.0, fixed=False, gimbal=True), encoding="utf-8")
    return video, srt, write_site(folder / "site")


# the registration's usual error: 3 pixels' footprint at the range it looks at, the ground 35 m
# below along a 25 deg pitch (83 m), at 320 px over 73.7 deg (fx 213 px): 1.2 m
TOLERANCE_M = (
    3.0
    * (drone.HEIGHT_M / math.sin(math.radians(-drone.PITCH_DEG)))
    / (160.0 / math.tan(math.radians(drone.HFOV_DEG / 2)))
)


def _solved_error(out) -> np.ndarray:
    """(F,) m: each frame of a `solve` CSV against the flight; no frame stands on a fix."""
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert {r["gnss"] for r in rows} == {"missing"}
    frame = LocalFrame(*SITE_ORIGIN)
    got = frame.geodetic_to_enu(
        *(np.array([[float(r[k]) for r in rows] for k in ("latitude", "longitude", "height")]))
    )
    truth, _ = drone.flight(np.array([float(r["time_s"]) for r in rows]))
    return np.linalg.norm(got - truth, axis=1)


def _viewed(display, unfixed, near: tuple[float, float], tmp_path, steps: str) -> dict:
    """The viewer's state (a script's `state`) after `geofuse view CLIP --scene SITE --near`
    and the script's steps once `registered` is solved (or failed); the viewer must exit 0."""
    video, _, site = unfixed
    state, script = tmp_path / "v.json", tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait registered\n{steps + chr(10) if steps else ''}0.2 state {state}\n0.3 quit\n"
    )
    result = run_viewer(
        display, str(video), "--scene", str(site), "--near", f"{near[0]},{near[1]}",
        "--script", str(script), "--size", "640x360",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(state.read_text())


def _near(east_m: float, north_m: float) -> tuple[float, float]:
    """(lat, lon) of the point east_m, north_m (m) from the flight's true start."""
    start, _ = drone.flight(np.array([0.0]))
    lat, lon, _ = LocalFrame(*SITE_ORIGIN).enu_to_geodetic(start[0] + [east_m, north_m, 0.0])
    return float(lat), float(lon)


@pytest.mark.gl
def test_a_dji_clip_without_a_fix_is_found_from_an_area_at_its_subtitles_height(
    unfixed, tmp_path, capsys
):
    video, srt, site = unfixed
    d = OFF_M / math.sqrt(2.0)
    lat, lon = _near(d, d)
    out = tmp_path / "solved.csv"
    argv = ["solve", str(video), "--scene", str(site), "--near", f"{lat},{lon}", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "DJI_0001.SRT: none of the 90 entries has a position" in err, err
    said = re.search(r"cold start: .*", err)
    assert said, err
    # searched at the subtitle's 35 m above take-off (the flight's height over the site's ground)
    assert f"searched at {drone.HEIGHT_M:.0f} m: the subtitle's height above take-off" in said[0]
    far = re.search(r"(\d+) m from the area's centre", said[0])
    assert far and abs(int(far.group(1)) - OFF_M) <= 2, said[0]
    error = _solved_error(out)
    assert error[0] <= TOLERANCE_M and np.median(error) <= TOLERANCE_M / 2, error
    assert error.max() <= 2 * TOLERANCE_M, error


def test_the_platforms_height_is_the_subtitles_unless_given(unfixed, tmp_path):
    video, srt, site = unfixed
    area = StartArea.near(*_near(0.0, 0.0), 300.0)
    session = open_clip(video, srt, layers=(Layer.of(site),), start=area)
    assert len(session.gnss.t) == 0 and session.start == area
    assert platform_height(session) == (
        pytest.approx(drone.HEIGHT_M),
        "the subtitle's height above take-off",
    )
    given = replace(session, start=replace(area, height_m=50.0))
    assert platform_height(given) == (50.0, "")
    # a clip that begins on the ground (1.2 m above take-off) is too low to search from
    low = tmp_path / "low.SRT"
    low.write_text(srt.read_text().replace("rel_alt: 35.000", "rel_alt: 1.200"))
    grounded = open_clip(video, low, layers=(Layer.of(site),), start=area)
    with pytest.raises(
        GeofuseError,
        match=r"height above take-off is 1\.2 m at the clip's start, too low .* give --height M",
    ):
        platform_height(grounded)


def test_a_dji_clip_without_a_fix_says_what_it_lacks(unfixed, tmp_path, capsys):
    video, srt, site = unfixed
    area = StartArea.near(*_near(0.0, 0.0), 300.0)
    with pytest.raises(
        DataFormatError,
        match=r"DJI_0001\.SRT.*none of the 90 entries has a position .*0, 0 is no fix",
    ):
        open_clip(video, srt, layers=(Layer.of(site),))  # no area
    with pytest.raises(DataFormatError, match=r"DJI_0001\.SRT.*no scene is given"):
        open_clip(video, srt, start=area)
    bare = tmp_path / "DJI_0001.SRT"
    bare.write_text(drone.srt_text(SECONDS, 0.0, fixed=False), encoding="utf-8")
    with pytest.raises(DataFormatError, match=r"DJI_0001\.SRT.*nor the gimbal's angles"):
        open_clip(video, bare, layers=(Layer.of(site),), start=area)
    # the command line says it and exits with an error, no traceback
    assert main(["solve", str(video), "--scene", str(site), "--out", str(tmp_path / "o.csv")]) != 0
    err = capsys.readouterr().err
    assert "none of the 90 entries has a position" in err and "Traceback" not in err
    assert not (tmp_path / "o.csv").exists()


def test_a_subtitle_at_0_0_has_no_position_and_keeps_its_barometer(tmp_path):
    path = tmp_path / "nofix.SRT"
    path.write_text(
        "1\n00:00:00,000 --> 00:00:01,000\n[latitude: 0.000000] [longitude: 0.000000] [rel_alt: 12.5 abs_alt: 0.0]\n\n"
        "2\n00:00:01,000 --> 00:00:02,000\n[latitude: 0.000000] [longitude: 0.000000] [rel_alt: 14.0 abs_alt: 0.0]\n"
    )
    with pytest.raises(DataFormatError, match=r"none of the 2 entries has a position"):
        read_srt(path)
    track = read_srt(path, positioned=False)
    assert not track.has_position.any()
    t, h = takeoff_heights(track, 100.0)
    np.testing.assert_allclose(t, [100.0, 101.0])
    np.testing.assert_allclose(h, [12.5, 14.0])
    # a manifest with an origin opens it: no fix, the barometer's heights kept for a cold start
    lat, lon, h0 = SITE_ORIGIN
    video = drone.write_video(tmp_path / "DJI_0002.MP4", 2.0, (160, 90))
    (tmp_path / "DJI_0002.SRT").write_text(
        drone.srt_text(2.0, 0.0, fixed=False, gimbal=True), encoding="utf-8"
    )
    manifest = tmp_path / "s.toml"
    manifest.write_text(
        f'[scene]\npath = "{SAMPLE_SCENE}"\norigin = [{lat}, {lon}, {h0}]\nup_axis = "Y"\n\n'
        f'[video]\npath = "{video}"\nstart_time = 1000.0\n\n[camera]\nhfov_deg = {drone.HFOV_DEG}\n\n'
        f'[sensors]\nformat = "none"\n\n[gnss]\npath = "{tmp_path / "DJI_0002.SRT"}"\n'
    )
    bare = tmp_path / "bare.toml"  # the same without its scene (its origin kept): nothing to search
    rest = manifest.read_text().split("[video]", 1)[1]
    bare.write_text(f"[origin]\nlat = {lat}\nlon = {lon}\nh = {h0}\n\n[video]{rest}")
    with pytest.raises(ManifestError, match="no GNSS fix at all and no scene"):
        open_session(bare)
    session = open_session(manifest)
    assert len(session.gnss.t) == 0
    t, h = session.platform_heights.t, session.platform_heights.h
    assert t[0] == pytest.approx(1000.0) and np.all(h == drone.HEIGHT_M)
    assert "telemetry" in session.recorded


@pytest.mark.gl
def test_the_viewer_opens_a_dji_clip_without_a_fix_on_the_pose_found(unfixed, display, tmp_path):
    """`geofuse view CLIP --scene SITE --near LAT,LON`: the viewer opens on `registered`, the
    projector at the frame shown stands where the flight was (within the registration's error),
    and the picture is drawn."""
    video, _, site = unfixed
    lat, lon = _near(OFF_M, 0.0)
    out = tmp_path / "v.png"
    s = _viewed(
        display, unfixed, (lat, lon), tmp_path, f"0 seek 1.5\n0 pause\n0.2 screenshot {out}"
    )
    assert s["source"] == "registered" and s["errors"] == [], s
    frame = s["frame"]
    session = open_clip(video, layers=(Layer.of(site),), start=StartArea.near(lat, lon, 300.0))
    truth, _ = drone.flight(np.array([session.frame_times[frame] - session.frame_times[0]]))
    lat_t, lon_t, h_t = LocalFrame(*SITE_ORIGIN).enu_to_geodetic(truth[0])
    expected = session.frame.geodetic_to_enu(lat_t, lon_t, h_t)
    assert np.linalg.norm(np.asarray(s["projector"]["position"]) - expected) <= 1.2, s["projector"]
    img = np.asarray(Image.open(out).convert("RGB"), int)
    x, y, w, h = s["view_rect"]
    assert img[y : y + h, x : x + w].std() > 15


@pytest.fixture(scope="module")
def unplaced_klv(tmp_path_factory):
    """The same weave as an MPEG-TS whose KLV never places the sensor (no tags 13, 14: a
    platform without a fix that still knows its height above the ellipsoid, tag 75)."""
    sets = drone.klv_sets(SECONDS, 0.0)
    folder = tmp_path_factory.mktemp("klv-unplaced")
    return drone.write_video(folder / "downlink.ts", SECONDS, (320, 180), klv=sets), write_site(
        folder / "site"
    )


@pytest.mark.gl
def test_klv_that_never_places_the_sensor_is_found_from_an_area_at_its_height(
    unplaced_klv, tmp_path, capsys
):
    """Its height is ellipsoidal: the search stands at it over the scene's ground at the area's
    centre (the site's flat ground, 35 m below the flight)."""
    video, site = unplaced_klv
    lat, lon = _near(-OFF_M, 0.0)
    with pytest.raises(DataFormatError, match="no KLV set places the sensor .*give --near"):
        open_clip(video, layers=(Layer.of(site),))
    with pytest.raises(DataFormatError, match="no scene is given"):
        open_clip(video, start=StartArea.near(lat, lon, 300.0))
    out = tmp_path / "solved.csv"
    argv = ["solve", str(video), "--scene", str(site), "--near", f"{lat},{lon}", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    said = re.search(r"cold start: .*", err)
    assert said and "the KLV's sensor height" in said[0], err
    assert re.search(
        r"searched at 35 m: the KLV's sensor height \(\d+ m\) over the scene's ground", said[0]
    )
    error = _solved_error(out)
    assert np.median(error) <= TOLERANCE_M / 2 and error.max() <= 2 * TOLERANCE_M, error


@pytest.mark.gl
def test_the_viewer_says_an_area_with_no_scene_and_keeps_running(unfixed, display, tmp_path):
    """The same clip given an area 2 km from the scene: the search finds no scene there; the
    viewer says so (the Attitude panel, in red: `registered` failed and why) and keeps running
    (the script goes on to its end)."""
    lat, lon = _near(2000.0, 0.0)
    s = _viewed(display, unfixed, (lat, lon), tmp_path, "")
    assert "the area holds no scene" in s["failed"]["registered"], s["failed"]
    assert s["source"] == "registered" and s["errors"] == []  # nothing else went wrong
