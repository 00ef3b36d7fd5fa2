"""Real FMV metadata as it comes (issue 50): ST 0601 sets that leave out what has not changed
(report on change), static items sent once, presentation times that do not move, the older EG
0104 set, a sensor angle in error, and a surveillance zoom lens's narrow field of view. Every set
is encoded here from the standard (app.io.misb) around the simulator's orbit, whose camera is
known at every instant."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.errors import DataFormatError, VideoError
from app.core.messages import Messages
from app.export.records import frame_records
from app.footage.clips import open_clip
from app.geodesy import rotations
from app.io.klv_track import CARRY_LIMIT_S, KlvTrack, describe, read_klv
from app.io.misb import (
    EG0104_KEY,
    KlvError,
    camera_orientation,
    encode,
    local_set,
    parse,
    read_ber,
    read_oid,
    split,
)
from app.io.video import probe
from app.session.camera_track import camera_track
from app.simulate.feed import Orbit, orbit_set
from app.simulate.phone import write_video

ORBIT = Orbit()
SIZE = (320, 180)
VFOV = 30.0


def _items(raw: bytes) -> list[tuple[int, bytes]]:
    """A Local Set's items in order, the checksum left out."""
    length, i = read_ber(raw, 16)
    end, out = i + length, []
    while i < end:
        tag, i = read_oid(raw, i)
        n, i = read_ber(raw, i)
        out.append((tag, raw[i : i + n]))
        i += n
    return [(tag, v) for tag, v in out if tag != 1]


def _set(t: float, leave_out: tuple[int, ...] = (), replace: dict | None = None) -> bytes:
    """The orbit's set at t with some items left out and some replaced (tag: bytes)."""
    items = [(tag, v) for tag, v in _items(orbit_set(ORBIT, t, VFOV)) if tag not in leave_out]
    items = [(tag, (replace or {}).get(tag, v)) for tag, v in items]
    return local_set(items)


def _video(path, packets, seconds: float = 4.0):
    return write_video(path, np.arange(int(seconds * 30)) / 30.0, SIZE, 0, crf=35, klv=packets)


def _centre_pixel(session, k: int) -> np.ndarray:
    cam = camera_track(session, "telemetry").frame_camera(k)
    centre = session.frame.geodetic_to_enu([ORBIT.lat_deg], [ORBIT.lon_deg], [ORBIT.ground_h_m])
    return cam.project(centre)[0][0]


SENSOR_ANGLES = (18, 19, 20)
STATIC = (10, 11, 65)  # platform designation, sensor name, version: sent once


def test_items_left_out_are_carried_from_the_last_set_and_static_items_sent_once(tmp_path):
    """Every other set leaves out the sensor's angles and the field of view; only the first
    carries the version, the platform and the sensor names. Read as zeros, the angles would put
    the camera 28 deg up and 90 deg round from the orbit's centre; carried, every frame looks at
    it (the principal point), as when every set is whole."""
    packets = []
    for k in range(20):
        t = k / 5.0
        leave = (SENSOR_ANGLES + (16, 17) if k % 2 else ()) + (STATIC if k else ())
        packets.append((t, _set(t, leave)))
    path = _video(tmp_path / "on_change.ts", packets)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert track.counts.carried == 10 and track.counts.stale == 0  # the odd sets
    for t, s in zip(track.t, track.sets, strict=True):
        whole = parse(orbit_set(ORBIT, t, VFOV))
        got, want = camera_orientation(s), camera_orientation(whole)
        assert abs(float(np.dot(got, want))) == pytest.approx(1.0, abs=1e-9), t
        assert s.get("hfov_deg") == pytest.approx(ORBIT.hfov_deg, abs=0.01)
    assert "ST 0601.17" in describe(track, probe(path).pts_s)
    assert any("report on change" in m and "carried forward" in m for m in messages.items)
    session = open_clip(path)
    assert session.camera == "geofuse orbit / EO"  # names sent once, still found
    for k in (0, 37, 101):  # frames beside sets that left the angles out
        assert np.allclose(_centre_pixel(session, k), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5), k


def test_an_item_last_reported_too_long_ago_is_not_carried_and_is_said(tmp_path):
    """A set 12 s after the last one that gave the sensor's angles leaves them out: more than
    CARRY_LIMIT_S old, they are a gap (no attitude there), named in a warning."""
    assert 12.0 > CARRY_LIMIT_S
    packets = [(k / 5.0, _set(k / 5.0)) for k in range(10)]  # 0-1.8 s, whole
    packets += [(13.8 + k / 5.0, _set(13.8 + k / 5.0, SENSOR_ANGLES)) for k in range(5)]
    path = _video(tmp_path / "stale.ts", packets, seconds=15.0)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert track.counts.stale == 5
    assert all("sensor_azimuth_deg" not in s.values for s in track.sets[10:])
    said = " ".join(messages.items)
    assert "sensor_azimuth_deg, sensor_elevation_deg, sensor_roll_deg" in said
    assert f"more than {CARRY_LIMIT_S:g} s before: not carried" in said


def test_sets_that_share_one_presentation_time_are_placed_by_their_time_stamps(tmp_path):
    """An encoder that stamps every KLV packet with the same PTS (0): the sets' Precision Time
    Stamps (tag 2) place them instead, 0.2 s apart as they were sent, and the clip poses as the
    orbit says."""
    packets = [(0.0, _set(k / 5.0)) for k in range(20)]
    path = _video(tmp_path / "frozen.ts", packets)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert track.t == pytest.approx([k / 5.0 for k in range(20)], abs=1e-6)
    assert any(
        "one presentation time: placed by their Precision Time Stamps" in m for m in messages.items
    )
    session = open_clip(path)
    assert np.allclose(_centre_pixel(session, 60), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5)


def test_sets_with_one_presentation_time_and_no_moving_stamp_are_refused_in_a_line(
    tmp_path, capsys
):
    stamp = _items(orbit_set(ORBIT, 0.0, VFOV))[0][1]  # every set the same tag 2
    packets = [(0.0, _set(k / 5.0, replace={2: stamp})) for k in range(10)]
    path = _video(tmp_path / "stuck.ts", packets)
    with pytest.raises(VideoError, match="stuck.ts.*cannot be placed in time"):
        read_klv(path, probe(path), Messages())
    assert main(["telemetry", str(path)]) == 2
    err = capsys.readouterr().err
    assert "stuck.ts" in err and "cannot be placed in time" in err and "Traceback" not in err


def _eg0104_packet() -> bytes:
    """An EG 0104 Universal Metadata Set: its key, a BER length and one item (a 16-byte key,
    a length, an 8-byte IEEE double: the device latitude of the older standard)."""
    item = bytes.fromhex("060E2B34010101030701020102020000") + bytes([8]) + b"\x40\x41" + bytes(6)
    return EG0104_KEY + bytes([len(item)]) + item


def test_eg0104_metadata_is_named_alone_and_beside_st0601(tmp_path, capsys):
    path = _video(tmp_path / "predator.ts", [(k / 5.0, _eg0104_packet()) for k in range(10)])
    with pytest.raises(VideoError, match="predator.ts.*EG 0104"):
        read_klv(path, probe(path), Messages())
    assert main(["telemetry", str(path)]) == 2
    assert "EG 0104" in capsys.readouterr().err
    both = [(k / 5.0, _set(k / 5.0)) for k in range(20)] + [(0.1, _eg0104_packet())]
    path = _video(tmp_path / "both.ts", both)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert len(track.sets) == 20 and track.counts.eg0104 == 1
    assert any("1 KLV packet(s) hold EG 0104" in m for m in messages.items)


def test_a_sensor_angle_in_error_in_every_set_is_named_not_the_heading(tmp_path):
    packets = [(k / 5.0, _set(k / 5.0, replace={19: encode(19, math.nan)})) for k in range(10)]
    path = _video(tmp_path / "elevation.ts", packets)
    with pytest.raises(DataFormatError) as caught:
        open_clip(path)
    text = str(caught.value)
    assert "tag 19 (sensor elevation) is the error code in 10 of 10 sets" in text
    assert "tag 5" not in text


@pytest.mark.parametrize("hfov", [0.365, 0.2])
def test_a_long_lens_field_of_view_is_taken_not_refused(tmp_path, hfov):
    """A surveillance zoom at its longest: 0.365 deg (a real EO sample) and 0.2 deg."""
    vfov = hfov * SIZE[1] / SIZE[0]
    packets = [
        (k / 5.0, _set(k / 5.0, replace={16: encode(16, hfov), 17: encode(17, vfov)}))
        for k in range(20)
    ]
    path = _video(tmp_path / "zoom.ts", packets)
    session = open_clip(path)
    assert session.intrinsics.hfov_deg == pytest.approx(hfov, abs=0.003)
    # The optical axis still points at the orbit's centre, within what the standard's 2-byte
    # heights allow (0.30 m steps: half a step at the sensor and at the centre, 0.3 m over the
    # 170 m range, 0.10 deg), and the centre is in the picture.
    cam = camera_track(session, "telemetry").frame_camera(60)
    centre = session.frame.geodetic_to_enu([ORBIT.lat_deg], [ORBIT.lon_deg], [ORBIT.ground_h_m])
    to_centre = centre[0] - np.asarray(cam.position)
    axis = -rotations.to_matrix(cam.orientation)[:, 2]
    off = math.degrees(math.acos(axis @ to_centre / np.linalg.norm(to_centre)))
    assert off < 0.11
    px = _centre_pixel(session, 60)
    assert 0 <= px[0] <= SIZE[0] and 0 <= px[1] <= SIZE[1], px
    out = tmp_path / "poses.csv"
    assert main(["solve", str(path), "--out", str(out)]) == 0 and out.is_file()


def test_a_single_set_is_read_and_solving_it_says_why_it_cannot(tmp_path, capsys):
    """One set in the whole file: `telemetry` reads it (one attitude holds at every time), and
    `solve` refuses in one line (two fixes are needed to place a moving camera)."""
    path = _video(tmp_path / "one.ts", [(0.5, _set(0.5))], seconds=2.0)
    assert main(["telemetry", str(path)]) == 0
    assert "MISB ST 0601 KLV" in capsys.readouterr().out
    assert main(["solve", str(path), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "one.ts" in err and "at least 2 fixes" in err and "Traceback" not in err


def test_of_two_klv_streams_the_one_with_sets_is_used_and_the_other_said(tmp_path):
    """A file with two KLV data streams: a first that holds only sets failing their checksum,
    and a second with the flight's sets. The second poses the clip; both are named."""
    broken = []
    for k in range(5):
        raw = bytearray(_set(k / 5.0))
        raw[-1] ^= 0xFF
        broken.append((k / 5.0, bytes(raw)))
    good = [(k / 5.0, _set(k / 5.0)) for k in range(20)]
    path = write_video(
        tmp_path / "two.ts", np.arange(120) / 30.0, SIZE, 0, crf=35, klv=broken, more_klv=[good]
    )
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert len(track.sets) == 20
    said = " ".join(messages.items)
    assert "2 KLV data streams" in said and "(20 Local Sets) is used, not #1 (0 sets)" in said
    session = open_clip(path)
    assert np.allclose(_centre_pixel(session, 60), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5)


def test_a_long_gap_between_sparse_sets_is_crossed_straight_and_said(tmp_path):
    """KLV every 10 s with a 98 s gap (20 s to 118 s) round the 150 m orbit: inside the gap the
    camera lies on the straight line between the fixes around it (a cubic through those fixes'
    velocities strays far off it), and the gap is said with its length and start."""
    times = [0.0, 10.0, 20.0, 118.0, 128.0, 138.0]
    path = write_video(
        tmp_path / "sparse.ts",
        np.arange(0.0, 140.0, 0.5),
        SIZE,
        0,
        crf=35,
        klv=[(t, _set(t)) for t in times],
    )
    session = open_clip(path)
    said = " ".join(session.messages.items)
    assert "1 gap(s) between positions, the longest 98.0 s from t = 20.0 s" in said
    track = camera_track(session, "telemetry")
    pts = session.video.pts_s
    a, b = (
        np.asarray(track.frame_camera(int(np.searchsorted(pts, t))).position) for t in (20.0, 118.0)
    )
    for t in (30.0, 69.0, 100.0):
        p = np.asarray(track.frame_camera(int(np.searchsorted(pts, t))).position)
        s = (t - 20.0) / 98.0
        assert np.linalg.norm(p - ((1 - s) * a + s * b)) < 0.5, t


def test_frame_centres_off_their_own_ray_are_not_taken_for_the_ground(tmp_path):
    """Every other set names a frame centre 600 m to the side and 40 m above the real one (an
    encoder that computes it from a stale pose): those lie far off the optical axis their own
    angles give, are said, and the assumed ground is the good centres' height, not theirs."""
    wrong_lat = encode(23, ORBIT.lat_deg + 600.0 / 111_000.0)
    packets = []
    for k in range(20):
        t = k / 5.0
        bad = {23: wrong_lat, 78: encode(78, ORBIT.ground_h_m + 40.0)} if k % 2 else {}
        packets.append((t, _set(t, replace=bad)))
    session = open_clip(_video(tmp_path / "centres.ts", packets))
    said = " ".join(session.messages.items)
    assert "10 of 20 KLV frame centres lie more than 2 deg off their own optical axis" in said
    ground = float(said.split("the KLV frame centre's median height (")[1].split(" m")[0])
    assert ground == pytest.approx(ORBIT.ground_h_m, abs=0.3)


@pytest.mark.parametrize("suffix", [".klv", ".bin"])
def test_a_raw_klv_file_is_read_as_telemetry_on_its_time_stamps(tmp_path, capsys, suffix):
    """Local Sets back to back with no video (what `ffmpeg -map 0:d -f data` writes), named
    .klv or .bin (where raw GoPro GPMF also goes): read as KLV, placed by their Precision Time
    Stamps, the first at 0 s."""
    path = tmp_path / f"flight{suffix}"
    path.write_bytes(b"".join(_set(k / 5.0) for k in range(20)))
    assert main(["telemetry", str(path)]) == 0
    out = capsys.readouterr().out
    assert "MISB ST 0601 KLV, raw" in out
    assert "Local Sets: 20 samples, 5.00 Hz, 0.000..3.800 s" in out
    assert "positions: 20 fixes" in out


def test_raw_eg0104_is_named(tmp_path, capsys):
    path = tmp_path / "predator.bin"
    path.write_bytes(_eg0104_packet() * 5)
    assert main(["telemetry", str(path)]) == 2
    err = capsys.readouterr().err
    assert "predator.bin" in err and "EG 0104" in err and "Traceback" not in err


def test_a_zoom_is_drawn_frame_by_frame_in_the_camera_and_the_footprints(tmp_path):
    """The field of view (tags 16, 17) narrows from 40 to 4 deg over 4 s, every set aimed at the
    orbit's centre: each frame's camera has the field of view of its moment (linear between the
    sets), and each footprint's half-width across the centre row is the slant range times
    tan(hfov / 2) of its own frame, so the last frame's is tan(2.15 deg) / tan(20 deg) of the
    first's (the range is the orbit's at both; edge to edge, so that the camera's 2 deg roll
    cancels to first order)."""

    def hfov(t: float) -> float:
        return 40.0 - 9.0 * t  # 40 deg at 0 s to 4 deg at 4 s

    packets = []
    for k in range(21):
        t = k / 5.0
        h = hfov(t)
        v = math.degrees(2 * math.atan(math.tan(math.radians(h) / 2) * SIZE[1] / SIZE[0]))
        packets.append((t, _set(t, replace={16: encode(16, h), 17: encode(17, v)})))
    path = _video(tmp_path / "zoom.ts", packets, seconds=4.0)
    session = open_clip(path)
    assert any("a zoom): every frame is drawn with its own" in m for m in session.messages.items)
    track = camera_track(session, "telemetry")
    for k in (0, 31, 64, 119):
        t = float(session.video.pts_s[k])
        assert track.frame_camera(k).intrinsics.hfov_deg == pytest.approx(hfov(t), abs=0.01), k
        # aimed at the centre, within the 0.10 deg the 2-byte heights allow (see above)
        px_per_deg = SIZE[0] / hfov(t)
        tol = max(0.6, 0.11 * px_per_deg)
        assert np.allclose(_centre_pixel(session, k), [SIZE[0] / 2, SIZE[1] / 2], atol=tol), k
    records = {r.index: r for r in frame_records(session, "telemetry", every=119, track=track)}
    widths = {}
    for k, r in records.items():
        gh, gw = r.ground.shape[:2]
        left, right = (
            session.frame.geodetic_to_enu([p[0]], [p[1]], [ORBIT.ground_h_m])[0][:2]
            for p in (r.ground[gh // 2, 0], r.ground[gh // 2, gw - 1])
        )
        widths[k] = float(np.linalg.norm(right - left)) / 2  # both sides: the roll cancels
        assert r.hfov_deg == pytest.approx(track.frame_camera(k).intrinsics.hfov_deg, abs=1e-9)
    t_last = float(session.video.pts_s[119])
    want = math.tan(math.radians(hfov(t_last) / 2)) / math.tan(math.radians(20.0))
    assert widths[119] / widths[0] == pytest.approx(want, rel=0.01)


def test_a_dji_subtitle_whose_focal_length_changes_is_drawn_frame_by_frame(tmp_path):
    """A DJI subtitle's focal length (35 mm equivalent, `[focal_len : 240]` in tenths) going
    from 24 to 48 mm over the 2 s clip: each frame's field of view is 2 atan(18 / f) of its
    moment's focal length (36 mm the full frame's width)."""
    from app.simulate import drone

    entries = drone.srt_text(2.0, 0.0).split("\n\n")
    focal = [24.0 + 24.0 * k / (len(entries) - 1) for k in range(len(entries))]
    text = "\n\n".join(
        e.replace("[focal_len : 240]", f"[focal_len : {10 * f:.0f}]")
        for e, f in zip(entries, focal, strict=True)
    )
    folder = tmp_path / "dji"
    folder.mkdir()
    video = write_video(folder / "DJI_0001.MP4", np.arange(60) / 30.0, SIZE, 0, crf=35)
    (folder / "DJI_0001.SRT").write_text(text, encoding="utf-8")
    session = open_clip(video)
    assert any("a zoom): every frame is drawn with its own" in m for m in session.messages.items)
    track = camera_track(session, session.sources[0])
    for k in (0, 29, 59):
        want = math.degrees(2 * math.atan(18.0 / focal[k]))
        assert track.frame_camera(k).intrinsics.hfov_deg == pytest.approx(want, abs=0.05), k


REAL = Path(__file__).parent / "data" / "klv"  # real samples: tests/data/klv/README.md


def test_the_st0902_example_packet_reads_as_the_standard_prints_it():
    """MISB ST 0902's 'dynamic only' example, as a KLV library ships it: every value as the
    standard's example lists it (to the integer mapping's step)."""
    s = parse((REAL / "dyn_only.bin").read_bytes())
    assert s.time_us == 1_231_798_102_000_000  # 2009-01-12 22:08:22 UTC
    want = {
        "platform_heading_deg": 159.9744,
        "platform_pitch_deg": -0.4315,
        "platform_roll_deg": 3.4058,
        "sensor_latitude_deg": 60.1768229,
        "sensor_longitude_deg": 128.4267598,
        "sensor_msl_m": 14190.72,
        "hfov_deg": 144.5713,
        "vfov_deg": 152.6436,
        "sensor_azimuth_deg": 160.7192,
        "sensor_elevation_deg": -168.7923,
    }
    for name, value in want.items():
        assert s.get(name) == pytest.approx(value, abs=3e-4 * max(1.0, abs(value) / 100)), name


def test_the_st0902_example_whose_printed_checksum_is_wrong_is_refused():
    with pytest.raises(KlvError, match="checksum 3e1e, the set says aa43"):
        parse((REAL / "dyn_const.bin").read_bytes())


def test_a_real_survey_flight_reads_whole_and_its_angles_aim_at_its_own_frame_centres(capsys):
    """A Cessna 208B's 85 s of KLV (407 sets, none failing its checksum): as raw telemetry, and
    every set's composed optical axis (platform then sensor angles, ST 0601's definitions) points
    at the frame centre the same set names, 0.11 deg at the median and 1.3 at worst (the sensor
    slews while the centre is computed)."""
    assert main(["telemetry", str(REAL / "cheyenne.bin")]) == 0
    out = capsys.readouterr().out
    assert "Local Sets: 407 samples" in out and "0.000..84.894 s" in out
    track = KlvTrack(str(REAL / "cheyenne.bin"))
    track.add((REAL / "cheyenne.bin").read_bytes(), None)
    track.finish()
    assert track.counts.bad == 0 and track.text(10) == "C208B"
    off = track.centre_offsets_deg()
    assert np.isfinite(off).all()
    assert np.median(off) < 0.15 and off.max() < 1.3
    fov = track.values("hfov_deg")
    assert fov.min() == pytest.approx(0.574, abs=0.01) and fov.max() == pytest.approx(
        40.51, abs=0.01
    )


def test_a_real_zooming_flight_beside_a_video_draws_each_frame_with_its_own_field_of_view(
    tmp_path,
):
    """The survey's sets muxed beside a video on their own times (from their time stamps): each
    frame's camera has the field of view the KLV gives at its moment (linear between sets), from
    0.57 deg to 40.5 deg, and the narrowest frames open and solve."""
    raw = (REAL / "cheyenne.bin").read_bytes()
    sets = list(split(raw))
    t0 = parse(sets[0]).time_us
    packets = [((parse(s).time_us - t0) / 1e6, s) for s in sets]
    times = np.arange(0.0, 84.5, 0.5)
    path = write_video(tmp_path / "cessna.ts", times, SIZE, 0, crf=40, klv=packets)
    session = open_clip(path)
    assert session.camera.startswith("C208B")
    track = camera_track(session, "telemetry")
    t_klv = np.array([t for t, _ in packets])
    fov = np.array([parse(s).get("hfov_deg") for _, s in packets])
    got = np.array([track.frame_camera(k).intrinsics.hfov_deg for k in range(len(times))])
    media = np.asarray(session.video.pts_s)
    want = np.interp(media, t_klv, fov)
    assert np.allclose(got, want, atol=0.01)
    assert got.min() < 0.7 and got.max() > 40.0


def test_a_raw_klv_file_beside_a_video_poses_it_by_time_stamps_and_creation_time(tmp_path, capsys):
    """The video and its KLV kept apart (a raw .klv written by a KLV tool): given with --klv,
    the sets are placed on the video's clock by their Precision Time Stamps and the video's
    creation time (UTC), and every frame looks at the orbit's centre as when the KLV rides in
    the video; found beside it as CLIP.klv with no creation time, the first set goes to the
    first frame, said."""
    from datetime import UTC, datetime

    from app.simulate.feed import UTC_START_S

    raw = tmp_path / "flight.klv"
    raw.write_bytes(b"".join(_set(k / 5.0) for k in range(20)))
    when = datetime.fromtimestamp(UTC_START_S, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    video = write_video(
        tmp_path / "video.mp4", np.arange(120) / 30.0, SIZE, 0, crf=35, creation_time=when
    )
    session = open_clip(video, raw)
    said = " ".join(session.messages.items)
    assert "raw KLV placed on the video by its creation time" in said
    assert raw.resolve() in session.inputs
    for k in (0, 50, 119):
        assert np.allclose(_centre_pixel(session, k), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5), k
    out = tmp_path / "poses.csv"
    assert main(["solve", str(video), "--klv", str(raw), "--out", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 121
    capsys.readouterr()

    beside = tmp_path / "beside"
    beside.mkdir()
    clip = write_video(beside / "CLIP.mp4", np.arange(60) / 30.0, SIZE, 0, crf=35)
    (beside / "CLIP.klv").write_bytes(raw.read_bytes())
    session = open_clip(clip)
    assert any(
        "no creation time: its first set is placed at the first frame" in m
        for m in session.messages.items
    )
    assert np.allclose(_centre_pixel(session, 30), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5)


def test_frame_centres_off_the_scenes_ground_are_said(tmp_path):
    """A DEM 60 m above the ground the KLV's frame centres name (the orbit's): the clip is
    draped on the DEM and the disagreement said, in metres; at the centres' own height, nothing
    is said."""
    from app.geodesy import geoid
    from app.scene.layers import Layer
    from app.simulate.terrain import write_geotiff

    path = _video(tmp_path / "over_dem.ts", [(k / 5.0, _set(k / 5.0)) for k in range(20)])
    n = float(geoid.undulation(ORBIT.lat_deg, ORBIT.lon_deg))
    step = 1.0 / 3600
    for above, said in ((60.0, True), (0.0, False)):
        dem = write_geotiff(
            tmp_path / f"dem{above:.0f}.tif",
            np.full((100, 100), ORBIT.ground_h_m - n + above),  # heights above EGM96's geoid
            "EPSG:4326+5773",
            ORBIT.lon_deg - 50 * step,
            ORBIT.lat_deg + 50 * step,
            step,
            step,
        )
        session = open_clip(path, layers=(Layer.of(dem),))
        notes = [m for m in session.messages.items if "from the scene's ground under them" in m]
        if said:
            assert len(notes) == 1 and "lie -60 m (median)" in notes[0]
        else:
            assert not notes
