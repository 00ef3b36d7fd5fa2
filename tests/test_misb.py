"""MISB ST 0601 Local Sets read back: values within their integer mapping's step, the standard's
error codes as gaps, a failed checksum refused, sets found in a run of bytes, and the camera's
orientation composed from the platform's and the sensor's rotations, checked against cases
worked by hand."""

import math
import struct

import numpy as np
import pytest

from app.geodesy import rotations
from app.io.misb import (
    TAGS,
    KlvError,
    LocalSet,
    ber_length,
    ber_oid,
    camera_orientation,
    checksum,
    decode,
    encode,
    local_set,
    parse,
    read_ber,
    split,
)

VALUES = {
    5: 271.5,
    6: -3.25,
    7: 12.0,
    13: 34.801234,
    14: 113.531234,
    15: 1234.5,
    16: 66.0,
    17: 39.5,
    18: 10.0,
    19: -45.0,
    20: 2.0,
    21: 1500.0,
    23: 34.79,
    24: 113.52,
    25: 101.0,
    75: 1210.25,
    78: 80.0,
    90: -3.25,
    91: 12.0,
}


def _step(tag: int) -> float:
    """One integer step of a tag's mapping, in its unit."""
    m = TAGS[tag]
    return (m.high - m.low) / (2 ** (8 * m.size) - 1)


def test_every_mapped_value_reads_back_within_one_step():
    when = 1_700_000_000_123_456
    packet = local_set(
        [(2, struct.pack(">Q", when)), (65, bytes([17]))]
        + [(tag, encode(tag, v)) for tag, v in VALUES.items()]
    )
    s = parse(packet)
    assert s.time_us == when and s.version == 17 and s.other == {}
    for tag, v in VALUES.items():
        assert s.get(TAGS[tag].name) == pytest.approx(v, abs=_step(tag)), TAGS[tag].name


def test_error_codes_are_gaps_and_a_shorter_integer_scales():
    # The most negative integer of a signed mapping is "out of range": NaN, not -90 deg.
    assert math.isnan(decode(13, b"\x80\x00\x00\x00"))
    assert math.isnan(decode(19, encode(19, math.nan)))
    assert decode(13, b"\x7f\xff\xff\xff") == pytest.approx(90.0)
    # A heading written in 1 byte instead of 2: 255 is 360 deg, 64 is 90.35 deg.
    assert decode(5, b"\xff") == pytest.approx(360.0)
    assert decode(5, b"\x40") == pytest.approx(64 * 360.0 / 255)
    s = parse(local_set([(5, encode(5, 90.0)), (19, encode(19, math.nan))]))
    assert s.get("platform_heading_deg") == pytest.approx(90.0, abs=0.01)
    assert camera_orientation(s) is None  # an angle in error: no pose


def test_a_set_failing_its_checksum_is_refused_and_others_are_found_around_it():
    good = local_set([(5, encode(5, 45.0))])
    bad = bytearray(local_set([(5, encode(5, 46.0))]))
    bad[-5] ^= 0x01  # a bit of the heading flipped in transit
    with pytest.raises(KlvError, match="checksum"):
        parse(bytes(bad))
    with pytest.raises(KlvError, match="wrong key"):
        parse(b"\x00" * 20)
    found = list(split(b"junk" + good + bytes(bad) + good[:-3]))  # the last one cut off
    assert found == [good, bytes(bad)]
    assert parse(found[0]).get("platform_heading_deg") == pytest.approx(45.0, abs=0.01)


def test_ber_lengths_both_forms_and_the_checksum_by_hand():
    assert ber_length(5) == b"\x05" and ber_length(127) == b"\x7f"
    assert ber_length(128) == b"\x81\x80" and ber_length(300) == b"\x82\x01\x2c"
    assert read_ber(b"\x82\x01\x2c", 0) == (300, 3)
    with pytest.raises(KlvError):
        read_ber(b"\x82\x01", 0)
    # Even-offset bytes are the high byte: 0x0102 + 0x0304 + 0x0500 = 0x0906.
    assert checksum(b"\x01\x02\x03\x04\x05") == 0x0906
    assert ber_oid(1) == b"\x01" and ber_oid(143) == b"\x81\x0f" and ber_oid(300) == b"\x82\x2c"
    # a tag past 127 and long-form lengths: 2 + 2 + 150 bytes, and 4 of checksum: 158 = 0x9e
    long_set = local_set([(143, bytes(150))])
    s = parse(long_set)
    assert s.other == {143: bytes(150)} and long_set[16:21] == b"\x81\x9e\x81\x0f\x81"


def _camera(**angles: float) -> np.ndarray:
    names = {
        "heading": "platform_heading_deg",
        "pitch": "platform_pitch_full_deg",
        "roll": "platform_roll_full_deg",
        "az": "sensor_azimuth_deg",
        "el": "sensor_elevation_deg",
        "sroll": "sensor_roll_deg",
    }
    q = camera_orientation(LocalSet(None, None, {names[k]: v for k, v in angles.items()}))
    assert q is not None
    return rotations.to_matrix(q)


def _axes(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(line of sight, image up) in ENU of a camera -> ENU matrix."""
    return -r[:, 2], r[:, 1]


def test_camera_orientation_worked_by_hand():
    # Level aircraft heading east, sensor straight ahead: looks east, image up is up.
    look, up = _axes(_camera(heading=90.0))
    np.testing.assert_allclose(look, [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
    # Heading east, sensor looking straight down: looks down, the image's top toward the nose.
    look, up = _axes(_camera(heading=90.0, el=-90.0))
    np.testing.assert_allclose(look, [0, 0, -1], atol=1e-9)
    np.testing.assert_allclose(up, [1, 0, 0], atol=1e-9)
    # Heading north, sensor turned 90 deg right (azimuth clockwise from the nose): looks east.
    look, _ = _axes(_camera(heading=0.0, az=90.0))
    np.testing.assert_allclose(look, [1, 0, 0], atol=1e-9)
    # Heading north, right wing 30 deg down, sensor pointing right: it looks east, 30 deg low.
    look, _ = _axes(_camera(heading=0.0, roll=30.0, az=90.0))
    np.testing.assert_allclose(look, [math.cos(math.radians(30)), 0, -0.5], atol=1e-9)
    # Nose 10 deg up, sensor 25 deg down: the line of sight is 15 deg below the horizon.
    look, _ = _axes(_camera(heading=0.0, pitch=10.0, el=-25.0))
    np.testing.assert_allclose(look, [0, math.cos(math.radians(15)), -math.sin(math.radians(15))])


@pytest.mark.parametrize("hpr", [(0.0, 0.0, 0.0), (123.0, -35.0, 8.0), (300.0, -89.0, -20.0)])
def test_a_gimbal_carrying_pitch_and_roll_is_the_camera_of_that_heading_pitch_roll(hpr):
    """What `geofuse export klv` writes (platform heading = the optical axis's, the sensor's
    relative elevation and roll its pitch and roll) reads back as that camera."""
    h, p, r = hpr
    got = _camera(heading=h, el=p, sroll=r % 360.0)
    want = rotations.camera_matrix_from_hpr(h, p, r)
    np.testing.assert_allclose(got, want, atol=1e-9)
