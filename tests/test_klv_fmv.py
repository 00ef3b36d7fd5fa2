"""Real FMV metadata as it comes (issue 50): ST 0601 sets that leave out what has not changed
(report on change), static items sent once, presentation times that do not move, the older EG
0104 set, a sensor angle in error, and a surveillance zoom lens's narrow field of view. Every set
is encoded here from the standard (app.io.misb) around the simulator's orbit, whose camera is
known at every instant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.cli import main
from app.core.errors import DataFormatError, VideoError
from app.core.messages import Messages
from app.footage.clips import open_clip
from app.geodesy import rotations
from app.io.klv_track import CARRY_LIMIT_S, describe, read_klv
from app.io.misb import (
    EG0104_KEY,
    camera_orientation,
    encode,
    local_set,
    parse,
    read_ber,
    read_oid,
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
