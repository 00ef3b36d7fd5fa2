"""MPEG-TS files with MISB ST 0601 KLV opened as clips (pose source `telemetry`): written here by
the orbit simulator (app.simulate.feed) and by `geofuse export klv`, synchronous and
asynchronous, with the faults real files have."""

from __future__ import annotations

import csv
import math
from fractions import Fraction

import numpy as np
import pytest

from app.cli import main
from app.core.errors import VideoError
from app.core.messages import Messages
from app.footage.clips import open_clip
from app.geodesy import rotations
from app.geodesy.geoid import undulation
from app.io.klv_track import KlvTrack, has_klv, read_klv
from app.io.misb import encode, local_set
from app.io.video import probe
from app.session.camera_track import camera_track
from app.simulate.feed import UTC_START_S, Orbit, orbit_set, write_feed
from app.simulate.phone import write_video
from app.simulate.sample import SAMPLE_DIR

ORBIT = Orbit()
SIZE = (320, 180)


@pytest.fixture(scope="module")
def async_feed(tmp_path_factory):
    """4 s at 30 fps with KLV at 7 Hz, its own presentation times (none on a frame's)."""
    path = tmp_path_factory.mktemp("klv") / "flight.ts"
    return write_feed(path, 4.0, SIZE, klv_hz=7.0)


def _centre_pixel(session, k: int) -> np.ndarray:
    """Where the orbit's centre (the frame centre every set names) lands in frame k."""
    cam = camera_track(session, "telemetry").frame_camera(k)
    centre = session.frame.geodetic_to_enu([ORBIT.lat_deg], [ORBIT.lon_deg], [ORBIT.ground_h_m])
    return cam.project(centre)[0][0]


def test_an_asynchronous_klv_clip_places_its_camera_on_the_orbit_and_looks_at_the_centre(
    async_feed,
):
    session = open_clip(async_feed)
    notes = " ".join(session.messages.items)
    assert "28 Local Sets at 7.0 Hz, asynchronous" in notes
    assert session.camera == "geofuse orbit / EO" and "telemetry" in session.recorded
    assert session.utc_at_zero_s == pytest.approx(UTC_START_S, abs=1e-3)
    # The aircraft's own position at a frame between two sets (frame 50 at 1.667 s; sets at
    # 1.571 and 1.714 s): interpolated, the chord of a 150 m circle over 0.14 s is 2 mm.
    track = camera_track(session, "telemetry")
    k = 50
    t = session.video.pts_s[k]
    want = ORBIT.frame().enu_to_ecef(ORBIT.position(t))
    got = session.frame.enu_to_ecef(np.asarray(track.frame_camera(k).position))
    assert np.linalg.norm(np.asarray(got) - np.asarray(want)) < 0.35  # heights: 0.3 m steps
    # Every set aims the sensor at the orbit's centre, so at every frame the centre lands on the
    # principal point (W/2, H/2), with the platform banked 8 deg and pitched 2 deg.
    for k in (0, 50, 119):
        px = _centre_pixel(session, k)
        assert np.allclose(px, [SIZE[0] / 2, SIZE[1] / 2], atol=0.5), (k, px)
    # 28 deg down: the camera's pitch is atan(80 / 150)
    hpr = rotations.hpr_from_camera_quat(track.frame_camera(0).orientation)
    assert hpr[1] == pytest.approx(-math.degrees(math.atan2(80, 150)), abs=0.05)
    assert "KLV consistency: the frame centre lies 0.0" in notes  # the centre agrees with the pose


def test_a_synchronous_klv_clip_has_a_set_per_frame_and_solves_from_the_cli(tmp_path, capsys):
    path = write_feed(tmp_path / "sync.ts", 2.0, SIZE)
    out = tmp_path / "poses.csv"
    assert main(["solve", str(path), "--out", str(out)]) == 0
    assert "60 Local Sets at 30.0 Hz, synchronous (a set per frame)" in capsys.readouterr().err
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 60
    heading, _, _, *_ = ORBIT.angles(1.0)
    # The optical axis points at the centre: 90 deg left of the aircraft's heading.
    assert float(rows[30]["heading"]) == pytest.approx((heading - 90.0) % 360.0, abs=0.05)
    # The ground is the frame centre's height, so the camera flies 80 m over it.
    assert float(rows[0]["U"]) == pytest.approx(80.0, abs=0.5)


def test_klv_exported_from_a_session_reopens_as_a_clip_with_the_same_poses(tmp_path):
    """export klv writes the sample's gd-ahrs poses; the TS opened again gives them back: each
    frame's angles within the 16-bit heading step, positions within the 0.3 m height step."""
    from app.export.records import frame_records
    from app.session import open_session

    out = tmp_path / "sample.ts"
    assert main(["export", "klv", str(SAMPLE_DIR / "session.toml"), "--out", str(out)]) == 0
    source = open_session(SAMPLE_DIR / "session.toml")
    records = frame_records(source, "gd-ahrs", 40)
    clip = open_clip(out)
    track = camera_track(clip, "telemetry")
    assert len(clip.video.pts_s) == len(source.video.pts_s)
    for r in records:
        cam = track.frame_camera(r.index)
        err = rotations.angle_between(
            np.asarray(cam.orientation), rotations.camera_quat_from_hpr(*r.hpr)
        )
        assert np.degrees(err) < 0.01
        lat, lon, h = clip.frame.enu_to_geodetic(np.asarray(cam.position)[None, :]).T
        assert float(lat[0]) == pytest.approx(r.sensor[0], abs=1e-7)
        assert float(lon[0]) == pytest.approx(r.sensor[1], abs=1e-7)
        assert float(h[0]) == pytest.approx(r.sensor[2], abs=0.35)


def test_damaged_klv_sets_are_dropped_and_counted_error_codes_are_gaps(tmp_path):
    """Sets failing their checksum are dropped (counted, said once); a set whose latitude is the
    standard's error code adds no position; heights only above sea level go through EGM2008."""
    orbit = Orbit()
    packets = []
    for k in range(20):
        t = k / 5.0
        raw = bytearray(orbit_set(orbit, t, 30.0, msl_only=True))
        if k in (3, 11):
            raw[-6] ^= 0x40  # a bit flipped in transit: the checksum no longer matches
        packets.append((t, bytes(raw)))
    bad_position = local_set(
        [(5, encode(5, 10.0)), (13, encode(13, math.nan)), (14, encode(14, 113.53))]
    )
    packets.append((2.1, bad_position))
    path = write_video(tmp_path / "damaged.ts", np.arange(120) / 30.0, SIZE, 0, crf=35, klv=packets)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert track.counts.bad == 2 and len(track.sets) == 19
    said = " ".join(messages.items)
    assert "2 KLV set(s) failed their checksum" in said
    gnss = track.gnss()
    assert gnss is not None and len(gnss.t) == 18  # the set in error is a gap
    lat, lon = gnss.lat[0], gnss.lon[0]
    n = float(undulation(lat, lon))
    want = orbit.frame().enu_to_geodetic(orbit.position(0.0)[None, :])[0, 2]
    assert gnss.h[0] == pytest.approx(want, abs=0.35) and -20 < n < -19
    session = open_clip(path)
    assert any("1 of 19 KLV sets have no valid position" in m for m in session.messages.items)


def test_untimed_sets_take_their_precision_time_stamps():
    orbit = Orbit()
    track = KlvTrack("x")
    track.add(orbit_set(orbit, 0.0, 30.0), 10.0)
    track.add(orbit_set(orbit, 1.0, 30.0), 11.0)
    track.add(orbit_set(orbit, 0.5, 30.0), None)  # a PES without a PTS
    track.add(local_set([(5, encode(5, 1.0))]), None)  # neither: dropped, counted
    track.finish()
    assert track.t == pytest.approx([10.0, 10.5, 11.0])
    assert track.counts.untimed == 1


def test_a_video_without_klv_or_telemetry_is_refused_with_what_was_looked_for(tmp_path):
    path = write_video(tmp_path / "plain.ts", np.arange(10) / 30.0, SIZE, 0)
    assert not has_klv(path)
    with pytest.raises(Exception, match="plain.ts"):
        open_clip(path)
    with pytest.raises(VideoError, match="no KLV data stream"):
        read_klv(path, probe(path), Messages())


def test_telemetry_and_render_take_a_klv_clip(async_feed, tmp_path, capsys):
    out = tmp_path / "track.csv"
    assert main(["telemetry", str(async_feed), "--csv", str(out)]) == 0
    said = capsys.readouterr().out
    assert "28 Local Sets at 7.0 Hz, asynchronous" in said and "platform: geofuse orbit" in said
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 28 and float(rows[0]["pitch"]) == pytest.approx(-28.07, abs=0.05)
    png = tmp_path / "frame.png"
    args = ["render", "--session", str(async_feed), "--time", "1", "--out", str(png)]
    assert main([*args, "--size", "160x90"]) == 0  # 1: nothing of the drape drawn
    assert png.is_file()


def test_export_klv_gives_every_frame_its_set_on_an_mp4_time_base_with_b_frames(tmp_path):
    """A DJI clip as cameras write it (MP4 time base 1/15360, B-frames, 30 fps; the subtitle's
    times truncated to the millisecond): every frame gets its Local Set, at its own presentation
    time. Before, the sets' times were read from packets the muxer had already rebased to 1/90000,
    so 10 s of video got ~51 sets (60 s: 308 of 1,800), or the muxer refused times going back."""
    import av

    from app.simulate import drone

    video = tmp_path / "DJI_0004.MP4"
    with av.open(str(video), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 64, 36, "yuv420p"
        s.options = {"bf": "2", "g": "30"}
        for i in range(300):
            img = np.full((36, 64, 3), (i * 7) % 255, np.uint8)
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    with av.open(str(video)) as c:
        assert c.streams.video[0].time_base == Fraction(1, 15360)

    def truncated(s: float) -> str:
        ms = int(s * 1000)
        return f"00:00:{ms // 1000 % 60:02d},{ms % 1000:03d}"

    entries = drone.srt_text(10.0, 0.0).split("\n\n")
    for k, e in enumerate(entries):
        lines = e.split("\n")
        lines[1] = f"{truncated(k / 30)} --> {truncated((k + 1) / 30)}"
        entries[k] = "\n".join(lines)
    (tmp_path / "DJI_0004.SRT").write_text("\n\n".join(entries) + "\n", encoding="utf-8")
    out = tmp_path / "klv.ts"
    assert main(["export", "klv", str(video), "--out", str(out)]) == 0
    info = probe(out)
    track = read_klv(out, info, Messages())
    assert len(info.pts_s) == 300 and len(track.sets) == 300
    assert track.synchronous(info.pts_s)
    np.testing.assert_allclose(track.times(), info.pts_s, atol=1.5e-5)
