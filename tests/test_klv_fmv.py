"""Real FMV metadata as it comes (issue 50): ST 0601 sets that leave out what has not changed
(report on change), static items sent once, presentation times that do not move, the older EG
0104 set, a sensor angle in error, and a surveillance zoom lens's narrow field of view. Every set
is encoded here from the standard (app.io.misb) around the simulator's orbit, whose camera is
known at every instant."""

from __future__ import annotations

import csv
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.errors import DataFormatError, VideoError
from app.core.messages import Messages
from app.export.records import frame_records
from app.footage.clips import open_clip
from app.geodesy import rotations
from app.geodesy.geoid import undulation
from app.io.klv_track import CARRY_LIMIT_S, KlvTrack, describe, read_klv
from app.io.misb import (
    EG0104_KEY,
    KlvError,
    ber_length,
    camera_orientation,
    encode,
    local_set,
    parse,
    parse_any,
    read_ber,
    read_oid,
    split,
)
from app.io.video import probe
from app.session.camera_track import camera_track
from app.simulate.feed import UTC_START_S, Orbit, orbit_set
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


# EG 0104.5's items as producers write them: each a 16-byte universal key (the version byte the
# SMPTE dictionary gives it), numbers as big-endian IEEE 754 floats (positions 8 bytes, the
# rest 4), the time stamp microseconds since 1970 in 8 bytes, names as text.
EG = {
    "time": "060E2B34010101030702010101050000",
    "heading": "060E2B34010101070701100106000000",
    "pitch": "060E2B34010101070701100105000000",
    "roll": "060E2B34010101070701100104000000",
    "lat": "060E2B34010101030701020102040200",
    "lon": "060E2B34010101030701020102060200",
    "alt": "060E2B34010101010701020102020000",  # above sea level
    "hfov": "060E2B34010101020420020101080000",
    "vfov": "060E2B340101010704200201010A0100",
    "north": "060E2B34010101010701100102000000",  # Angle to North
    "obliquity": "060E2B34010101010701100103000000",
    "sroll": "060E2B34010101010701100101000000",  # Sensor Roll Angle
    "clat": "060E2B34010101010701020103020000",
    "clon": "060E2B34010101010701020103040000",
    "celev": "060E2B340101010A0701020103160000",  # above sea level
    "device": "060E2B34010101010101200100000000",
    "sensor": "060E2B34010101010420010201010000",
}
SENSOR_ROLL = 3.0  # deg: the EG 0104 camera's roll about its line of sight


def _eg0104(items: dict[str, bytes]) -> bytes:
    """An EG 0104 Universal Metadata Set: its key, a BER length, then each item's key, BER
    length and value (no checksum: the standard has none)."""
    body = b"".join(bytes.fromhex(EG[k]) + ber_length(len(v)) + v for k, v in items.items())
    return EG0104_KEY + ber_length(len(body)) + body


def _los(t: float) -> tuple[float, float]:
    """The orbit's line of sight to its centre at t s: azimuth clockwise from north and
    elevation above the horizon (deg)."""
    d = -ORBIT.position(t) / np.linalg.norm(ORBIT.position(t))  # ENU, to the centre
    return math.degrees(math.atan2(d[0], d[1])) % 360.0, math.degrees(math.asin(d[2]))


def _eg0104_set(t: float, leave_out: tuple[str, ...] = (), replace: dict | None = None) -> bytes:
    """The orbit's camera at t s as an EG 0104 set: the aircraft's position (height above sea
    level through EGM2008) and attitude, and the sensor's line of sight on the orbit's centre as
    EG 0104 gives it (Angle to North: its azimuth; Obliquity: 180 deg minus its elevation; roll
    SENSOR_ROLL about it)."""
    frame = ORBIT.frame()
    lat, lon, h = (float(v) for v in frame.enu_to_geodetic(ORBIT.position(t)))
    heading, pitch, bank, *_ = ORBIT.angles(t)
    az, el = _los(t)
    f4, f8 = (lambda v: struct.pack(">f", v)), (lambda v: struct.pack(">d", v))
    msl = h - float(undulation(lat, lon))
    centre_msl = ORBIT.ground_h_m - float(undulation(ORBIT.lat_deg, ORBIT.lon_deg))
    items = {
        "time": struct.pack(">Q", int(round((UTC_START_S + t) * 1e6))),
        "device": b"Predator",
        "sensor": b"EO Nose",
        "heading": f4(heading),
        "pitch": f4(pitch),
        "roll": f4(bank),
        "lat": f8(lat),
        "lon": f8(lon),
        "alt": f4(msl),
        "hfov": f4(ORBIT.hfov_deg),
        "vfov": f4(VFOV),
        "north": f4(az),
        "obliquity": f4(180.0 - el),
        "sroll": f4(SENSOR_ROLL),
        "clat": f8(ORBIT.lat_deg),
        "clon": f8(ORBIT.lon_deg),
        "celev": f4(centre_msl),
    }
    items = {k: (replace or {}).get(k, v) for k, v in items.items() if k not in leave_out}
    return _eg0104(items)


def test_an_eg0104_set_reads_as_the_camera_it_describes():
    """At t = 0 the aircraft is 150 m east of the orbit's centre and 80 m above it: its line of
    sight points due west (Angle to North 270 deg), atan(80 / 150) = 28.07 deg down (Obliquity
    180 + 28.07 = 208.07 deg): the camera's heading, pitch and roll are 270, -28.07 and the
    sensor's 3 deg, whatever the platform's own heading (0 deg, flying north) and bank."""
    s = parse_any(_eg0104_set(0.0))
    assert s.standard == "EG 0104" and s.time_us == int(UTC_START_S * 1e6)
    assert s.get("los_azimuth_deg") == pytest.approx(270.0, abs=1e-4)
    assert s.get("los_obliquity_deg") == pytest.approx(208.0725, abs=1e-4)
    assert s.get("platform_heading_deg") == pytest.approx(0.0, abs=1e-4)
    assert s.other[10] == b"Predator" and s.other[11] == b"EO Nose"
    hpr = rotations.hpr_from_camera_quat(camera_orientation(s)[None])[0]
    assert hpr == pytest.approx([270.0, -28.0725, SENSOR_ROLL], abs=1e-3)


def test_an_eg0104_clip_poses_every_frame_as_its_camera(tmp_path, capsys):
    """20 EG 0104 sets at 5 Hz beside a 4 s video: read into the same track as ST 0601's, every
    frame (between sets too) looks at the orbit's centre (the principal point), its roll the
    sensor's, the names the set gives; solved without a word of refusal."""
    packets = [(k / 5.0, _eg0104_set(k / 5.0)) for k in range(20)]
    path = _video(tmp_path / "predator.ts", packets)
    messages = Messages()
    track = read_klv(path, probe(path), messages)
    assert len(track.sets) == 20 and track.counts.eg0104 == 20 and track.counts.bad == 0
    assert "EG 0104 (UAV Basic Universal Metadata Set)" in describe(track, probe(path).pts_s)
    assert any("20 KLV set(s) are EG 0104" in m for m in messages.items)
    session = open_clip(path)
    assert session.camera == "Predator / EO Nose"
    cameras = camera_track(session, "telemetry")
    for k in (0, 37, 101):
        assert np.allclose(_centre_pixel(session, k), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5), k
        roll = rotations.hpr_from_camera_quat(
            np.asarray(cameras.frame_camera(k).orientation)[None]
        )[0][2]
        assert roll == pytest.approx(SENSOR_ROLL, abs=0.05), k
    assert main(["solve", str(path), "--out", str(tmp_path / "poses.csv")]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_eg0104_and_st0601_sets_in_one_stream_pose_one_track(tmp_path):
    """Sets alternate between ST 0601 and EG 0104 (an encoder mid-upgrade), the EG 0104 ones
    leaving out what has not changed every other time (the sensor's roll about its line of
    sight, the fields of view, the names: report on change, carried from the last EG 0104 set,
    not from ST 0601's relative roll, 0): one track, every frame on the centre, rolled 3 deg
    wherever an EG 0104 set poses it."""
    packets = []
    for k in range(20):
        t = k / 5.0
        if k % 2 == 0:
            packets.append((t, _set(t)))
        else:
            leave = ("sroll", "hfov", "vfov", "device", "sensor") if k % 4 == 3 else ()
            packets.append((t, _eg0104_set(t, leave)))
    path = _video(tmp_path / "mixed.ts", packets)
    track = read_klv(path, probe(path), Messages())
    assert len(track.sets) == 20 and track.counts.eg0104 == 10
    assert track.counts.carried == 5  # the EG 0104 sets at k = 3, 7, 11, 15, 19
    assert "ST 0601.17 and 10 EG 0104 sets" in describe(track, probe(path).pts_s)
    assert all(s.get("los_roll_deg") == pytest.approx(SENSOR_ROLL) for s in track.sets[1::2])
    session = open_clip(path)
    for k in (0, 21, 45, 90):  # frames beside both kinds
        assert np.allclose(_centre_pixel(session, k), [SIZE[0] / 2, SIZE[1] / 2], atol=0.5), k


def test_eg0104_with_a_float_of_the_wrong_length_names_the_item(tmp_path, capsys):
    """Every set's Angle to North written in 3 bytes (no IEEE 754 float has that): each set is
    dropped, and the refusal names the file, the item and what was expected, in one line."""
    bad = {"north": b"\x43\x87\x00"}
    path = _video(
        tmp_path / "short.ts", [(k / 5.0, _eg0104_set(k / 5.0, replace=bad)) for k in range(10)]
    )
    with pytest.raises(VideoError) as caught:
        read_klv(path, probe(path), Messages())
    text = str(caught.value)
    assert "short.ts" in text and "EG 0104 Angle to North" in text
    assert "has 3 bytes, expected a 4- or 8-byte IEEE 754 float" in text
    assert main(["telemetry", str(path)]) == 2
    err = capsys.readouterr().err
    assert "EG 0104 Angle to North" in err and "Traceback" not in err


def test_eg0104_without_its_line_of_sight_is_refused_naming_it(tmp_path):
    packets = [(k / 5.0, _eg0104_set(k / 5.0, ("obliquity",))) for k in range(10)]
    with pytest.raises(DataFormatError) as caught:
        open_clip(_video(tmp_path / "no_obliquity.ts", packets))
    assert "EG 0104 Obliquity Angle is missing from 10 of 10 sets" in str(caught.value)


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


def test_a_long_gap_between_sparse_sets_is_crossed_straight_said_once_and_marked(tmp_path, capsys):
    """KLV every 10 s with a 98 s gap (20 s to 118 s) round the 150 m orbit: inside the gap the
    camera lies on the straight line between the fixes around it (a cubic through those fixes'
    velocities strays far off it). The gap is said once, when the clip is solved, with its span
    in clip time ("no GNSS from t = 20.0 s to 118.0 s (98 s)", not again in other words when
    it is opened), and every frame inside it is marked `missing` in the solve's gnss column:
    frames at 20.5 to 117.5 s (195 of them, every 0.5 s), while the frames at 20.0 s and
    118.0 s, on a fix, and every other frame are `used`."""
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
    assert not any("gap" in m for m in session.messages.items)  # said by the solve alone
    track = camera_track(session, "telemetry")
    pts = session.video.pts_s
    a, b = (
        np.asarray(track.frame_camera(int(np.searchsorted(pts, t))).position) for t in (20.0, 118.0)
    )
    for t in (30.0, 69.0, 100.0):
        p = np.asarray(track.frame_camera(int(np.searchsorted(pts, t))).position)
        s = (t - 20.0) / 98.0
        assert np.linalg.norm(p - ((1 - s) * a + s * b)) < 0.5, t
    out = tmp_path / "poses.csv"
    assert main(["solve", str(path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "98" in line and ("gap" in line or "GNSS" in line)]
    assert said == [
        "warning: no GNSS from t = 20.0 s to 118.0 s (98 s): positions there run straight between the fixes around it"
    ]
    rows = list(csv.DictReader(out.open()))
    t = np.array([float(r["time_s"]) for r in rows])
    gnss = np.array([r["gnss"] for r in rows])
    inside = (t > 20.0) & (t < 118.0)
    assert inside.sum() == 195 and (gnss[inside] == "missing").all()
    assert (gnss[~inside] == "used").all()


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


def test_raw_eg0104_is_read_as_telemetry(tmp_path, capsys):
    """EG 0104 sets back to back in a .bin (no video): raw KLV, placed by their time stamps."""
    path = tmp_path / "predator.bin"
    path.write_bytes(b"".join(_eg0104_set(k / 5.0) for k in range(10)))
    assert main(["telemetry", str(path)]) == 0
    out = capsys.readouterr().out
    assert "MISB ST 0601 KLV, raw" in out and "Local Sets: 10 samples, 5.00 Hz" in out
    assert "positions: 10 fixes" in out


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


def test_a_real_eg0104_packet_points_at_its_own_frame_centre(capsys):
    """A Predator-era EO sensor's EG 0104.5 packet (jmisb's, tests/data/klv/README.md): the
    sensor at 3233.5 m above sea level, its line of sight 49.41 deg from north (Angle to North)
    and 21.33 deg down (Obliquity 201.33), rolled -1.45 deg. From the positions alone the frame
    centre lies 49.47 deg from north, 8.26 km away: the composed axis passes within 15 m of it
    (0.06 deg) and meets the ground there 11 m above sea level, the coastal plain north of
    Adelaide. Read as ST 0601's relative azimuth (plus the platform's 20.01 deg heading) it
    would miss by 20 deg. Its Frame Center Elevation (1001.7 m) is no such ground: its centre
    lies 6.2 deg off the ray (a frame centre as a check: said, not taken for the ground). Its
    four corners fall upper left, upper right, lower right and lower left of the composed
    camera's picture, 0.78 deg apart across (its field of view: 0.75 deg)."""
    from app.geodesy.enu import LocalFrame

    raw = (REAL / "eg0104_jmisb.bin").read_bytes()
    s = parse_any(raw)
    assert s.standard == "EG 0104" and s.time_us == 1_112_376_646_437_500
    assert s.other[11] == b"EO Nose"
    v = s.values
    lat, lon = v["sensor_latitude_deg"], v["sensor_longitude_deg"]
    frame = LocalFrame(lat, lon, v["sensor_msl_m"] + float(undulation(lat, lon)))
    r = rotations.to_matrix(camera_orientation(s))
    axis = -r[:, 2]
    centre = frame.geodetic_to_enu([v["centre_latitude_deg"]], [v["centre_longitude_deg"]], [0.0])
    centre = centre[0]
    assert math.degrees(math.atan2(centre[0], centre[1])) == pytest.approx(49.47, abs=0.01)
    assert np.hypot(*centre[:2]) == pytest.approx(8263, abs=5)
    reach = axis * np.hypot(*centre[:2]) / np.hypot(*axis[:2])  # the axis over the centre
    assert np.linalg.norm(reach[:2] - centre[:2]) < 15.0
    ground = frame.enu_to_geodetic(reach)
    assert 0.0 < ground[2] - float(undulation(ground[0], ground[1])) < 30.0  # m above sea level
    relative = math.degrees(math.atan2(*axis[:2])) + v["platform_heading_deg"]
    assert relative - 49.47 == pytest.approx(20.0, abs=0.1)
    track = KlvTrack(str(REAL / "eg0104_jmisb.bin"), raw=True)
    track.add(raw, None)
    track.finish()
    assert track.centre_offsets_deg()[0] == pytest.approx(6.2, abs=0.1)
    corners = [
        (-34.78845688650273, 138.6373263435172),  # upper left
        (-34.78928792493697, 138.6381960623174),  # upper right
        (-34.79081399767026, 138.6359928154702),  # lower right
        (-34.79000491430295, 138.6351460736271),  # lower left
    ]
    seen = []
    for c in corners:
        x, y, z = r.T @ frame.geodetic_to_enu([c[0]], [c[1]], [ground[2]])[0]
        seen.append((math.degrees(math.atan2(x, -z)), math.degrees(math.atan2(y, -z))))
    (ulx, uly), (urx, ury), (lrx, lry), (llx, lly) = seen
    assert ulx < 0 < urx and llx < 0 < lrx and uly > 0 > lly and ury > 0 > lry
    assert urx - ulx == pytest.approx(0.78, abs=0.02)
    assert main(["telemetry", str(REAL / "eg0104_jmisb.bin")]) == 0
    assert "EG 0104 (UAV Basic Universal Metadata Set)" in capsys.readouterr().out


def _dji_entry(layout: str, k: int, ratio: float) -> str:
    """Subtitle entry k (1/30 s each) in one DJI firmware's words, as real files write them, with
    a digital zoom `ratio`; the aircraft 35 m above take-off, flying north 0.1 m a frame."""
    start, end = k / 30.0, (k + 1) / 30.0

    def stamp(s: float) -> str:
        return f"00:00:{int(s):02d},{round(1000 * (s % 1)):03d}"

    lat, lon = 34.8 + k * 1e-6, 113.53
    head = f"{k + 1}\n{stamp(start)} --> {stamp(end)}\n"
    when = f"2025-12-04 16:36:{51 + k // 30:02d}.{(k % 30) * 33:03d}"
    if layout == "mini3":  # [dzoom_ratio: 10000, delta:0]: ten-thousandths, one line
        return head + (
            f'<font size="28">SrtCnt : {k + 1}, DiffTime : 33ms\n{when}\n'
            f"[iso : 100] [shutter : 1/125.0] [fnum : 170] [ev : 0] [ct : 5289] [color_md : default] [focal_len : 240] "
            f"[dzoom_ratio: {round(10000 * ratio)}, delta:0],[latitude: {lat:.6f}] [longitude: {lon:.6f}] [rel_alt: 35.000 abs_alt: 145.000] </font>\n"
        )
    if layout == "mini4":  # [dzoom: 1.50], and [dzoom_ratio: 15000, ...] after a blank line
        return head + (
            f'<font size="28">FrameCnt: {k + 1}, DiffTime: 33ms\n{when}\n'
            f"[iso: 150] [shutter: 1/30.0] [fnum: 2.8] [ev: 0.7] [focal_len: 24.00] [dzoom: {ratio:.2f}]\n"
            f"[latitude: {lat:.6f}] [longitude: {lon:.6f}] [rel_alt: 35.000 abs_alt: 145.000]\n"
            f"[drone_speedx: 0.0 drone_speedy: 3.0 drone_speedz: 0.0]\n"
            f"[drone_yaw: 0.0 drone_pitch: 0.0 drone_roll: 0.0]\n"
            f"[gb_yaw: 0.0 gb_pitch: -30.0 gb_roll: 0.0]\n\n"
            f"0\n[ae_meter_md : 0] [dzoom_ratio: {round(10000 * ratio)}, delta:0] [color_md : default]</font>\n"
        )
    # "m3t": a thermal camera's [dzoom_ratio: 1.50], the ratio itself
    return head + (
        f'<font size="28">FrameCnt: {k}, DiffTime: 33ms\n{when}\n'
        f"[focal_len: 52.70] [dzoom_ratio: {ratio:.2f}], [latitude: {lat:.6f}] [longitude: {lon:.6f}]\n"
        f"[rel_alt: 35.000 abs_alt: 145.000] [gb_yaw: 0.0 gb_pitch: -30.0 gb_roll: 0.0] [ir_gain_mode: 0]</font>\n"
    )


@pytest.mark.parametrize(("layout", "focal_mm"), [("mini3", 24.0), ("mini4", 24.0), ("m3t", 52.7)])
def test_a_dji_digital_zoom_narrows_each_frame_as_its_entry_says(tmp_path, layout, focal_mm):
    """The digital zoom going from 1x to 2x over a 2 s clip, written as each firmware writes it:
    each frame's field of view is 2 atan(18 mm / (focal_len x ratio)) of its own entry (36 mm
    the full frame's width): 24 mm at 1x is 73.74 deg, at 1.49x (frame 29) 53.5 deg, at 2x
    (frame 59) 41.11 deg; the thermal camera's 52.7 mm: 37.72 deg at 1x, 19.38 deg at 2x."""
    ratios = [1.0 + k / 59 for k in range(60)]
    folder = tmp_path / layout
    folder.mkdir()
    video = write_video(folder / "DJI_0001.MP4", np.arange(60) / 30.0, SIZE, 0, crf=35)
    text = "\n".join(_dji_entry(layout, k, r) for k, r in enumerate(ratios))
    (folder / "DJI_0001.SRT").write_text(text, encoding="utf-8")
    session = open_clip(video)
    said = " ".join(session.messages.items)
    assert "with a digital zoom of 1 to 2x, a zoom): every frame is drawn with its own" in said
    track = camera_track(session, session.sources[0])
    for k in (0, 29, 59):
        ratio = round(ratios[k], 2)  # as written (mini3: to 1/10000, the others to 1/100)
        want = math.degrees(2 * math.atan(18.0 / (focal_mm * ratio)))
        assert track.frame_camera(k).intrinsics.hfov_deg == pytest.approx(want, abs=0.05), k
    assert track.frame_camera(0).intrinsics.hfov_deg == pytest.approx(
        {24.0: 73.74, 52.7: 37.72}[focal_mm], abs=0.01
    )


def test_a_dji_digital_zoom_no_camera_has_is_said_and_not_applied(tmp_path):
    """An entry whose `[dzoom: 0.50]` (a zoom that would widen the picture) is said, naming the
    field and what was expected, and left out; the others still zoom."""
    from app.io.dji_srt import read_srt

    text = "\n".join(_dji_entry("mini4", k, 1.0 + k / 9) for k in range(10))
    text = text.replace("[dzoom: 1.44]", "[dzoom: 0.50]")
    path = tmp_path / "DJI_0002.SRT"
    path.write_text(text, encoding="utf-8")
    messages = Messages()
    track = read_srt(path, messages)
    assert np.isnan(track.dzoom[4]) and track.dzoom[9] == pytest.approx(2.0)
    assert any(
        "DJI_0002.SRT: 1 entries give a digital zoom (dzoom) of 0.5" in m
        and "expected a ratio from 1 to 200" in m
        for m in messages.items
    )
