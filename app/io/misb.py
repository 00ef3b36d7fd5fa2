"""MISB ST 0601 (UAS Datalink Local Set) KLV: the bytes both ways, and the camera it describes.

A Local Set is the 16-byte UAS Datalink universal key, a BER length, then tag-length-value items
(tags BER-OID, lengths BER) ending with the checksum (tag 1): the 16-bit running sum of the packet
from the key's first byte through the checksum's own tag and length, even-offset bytes as the
high byte. A set that fails it is refused (KlvError), never half-read.

Values are ST 0601's integer mappings: a quantity of range [low, high] over an N-byte unsigned
integer is low + v (high - low) / (2^(8N) - 1); a signed one of span S over an N-byte signed
integer is v S / (2^(8N-1) - 1), the most negative integer being the standard's reserved "out of
range" code, read as NaN (a gap, not a pose). Every version in use is read: older sets without
the version tag (65), sets that write a shorter integer than the nominal length (the mapping
scales with the length found), the full-range platform pitch and roll (90, 91) preferred to the
short ones (6, 7), the ellipsoid height (75) preferred to the true altitude above sea level (15).

Angles are degrees; the platform's heading is clockwise from true north, its pitch positive nose
up and roll positive right wing down; the sensor's relative azimuth is clockwise from the nose
seen from above, its relative elevation positive above the platform's longitudinal-transverse
plane, its relative roll clockwise about the line of sight looking out (`camera_orientation`
composes them).

EG 0104 (MISB EG 0104.5, the older Predator "UAV Basic Universal Metadata Set", still in archives
and some encoders) is read into the same LocalSet (`parse_eg0104`): its key, a BER length, then
items each keyed by a 16-byte SMPTE universal key (the key's version byte, byte 7, any) with a
BER length; numbers are IEEE 754 floats (4 or 8 bytes), the User Defined Time Stamp microseconds
since 1970 (UTC) as an 8-byte integer, names text; there is no checksum. The platform's angles,
the sensor's position (height above sea level), the fields of view, slant range and frame centre
take the names ST 0601's tags have. The sensor's pointing is EG 0104's own, not ST 0601's: the
Angle to North is the line of sight's azimuth clockwise from true north (ST 0601's relative
azimuth is it minus the platform's heading), the Obliquity Angle O runs 180 deg level ahead, 270
deg straight down, 0 deg level behind (the line of sight's elevation above the horizon is
180 - O), and the Sensor Roll Angle turns the picture about the line of sight (clockwise looking
out, as ST 0601's relative roll). A real EG 0104 packet (tests/data/klv/eg0104_jmisb.bin) bears
this out: its Angle to North is the azimuth from its sensor to its frame centre within 0.06 deg,
where taken as relative to the platform it would be 20 deg off.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from app.geodesy import rotations

UAS_LOCAL_SET_KEY = bytes.fromhex("060E2B34020B01010E01030101000000")
# EG 0104, the older Predator "UAV Basic Universal Metadata Set": its items are keyed by 16-byte
# universal keys (EG0104_ITEMS), read into the same LocalSet as ST 0601's (parse_eg0104).
EG0104_KEY = bytes.fromhex("060E2B34020101010E01010201010000")
KEY_VERSION_BYTE = 7  # the UL's version byte: any value is accepted when reading
ST0601, EG0104 = "ST 0601", "EG 0104"  # LocalSet.standard: which set a LocalSet was read from
# An EG 0104 item's key: a SMPTE data dictionary element (byte 7, its version, any), then what
# EG0104_ITEMS names by the key's last 8 bytes.
EG0104_ITEM_PREFIX = bytes.fromhex("060E2B34010101")
CHECKSUM_TAG = 1
TIMESTAMP_TAG = 2  # Precision Time Stamp: microseconds since 1970 (UTC), uint64
VERSION_TAG = 65
ST0601_VERSION = 17  # the UAS Datalink LS version this writes (tag 65)

FloatArray = npt.NDArray[np.float64]


class KlvError(ValueError):
    """A Local Set that cannot be read: what is wrong, and where (byte offset in the set)."""


@dataclass(frozen=True)
class Mapping:
    """One tag's integer mapping: [low, high] over `size` bytes unsigned, or +-span signed (low =
    -high) with the most negative integer reserved for "out of range"."""

    name: str
    low: float
    high: float
    size: int
    signed: bool = False


TAGS: dict[int, Mapping] = {
    5: Mapping("platform_heading_deg", 0.0, 360.0, 2),
    6: Mapping("platform_pitch_deg", -20.0, 20.0, 2, signed=True),
    7: Mapping("platform_roll_deg", -50.0, 50.0, 2, signed=True),
    13: Mapping("sensor_latitude_deg", -90.0, 90.0, 4, signed=True),
    14: Mapping("sensor_longitude_deg", -180.0, 180.0, 4, signed=True),
    15: Mapping("sensor_msl_m", -900.0, 19000.0, 2),  # Sensor True Altitude, above sea level
    16: Mapping("hfov_deg", 0.0, 180.0, 2),
    17: Mapping("vfov_deg", 0.0, 180.0, 2),
    18: Mapping("sensor_azimuth_deg", 0.0, 360.0, 4),  # relative to the platform
    19: Mapping("sensor_elevation_deg", -180.0, 180.0, 4, signed=True),
    20: Mapping("sensor_roll_deg", 0.0, 360.0, 4),
    21: Mapping("slant_range_m", 0.0, 5_000_000.0, 4),
    23: Mapping("centre_latitude_deg", -90.0, 90.0, 4, signed=True),
    24: Mapping("centre_longitude_deg", -180.0, 180.0, 4, signed=True),
    25: Mapping("centre_msl_m", -900.0, 19000.0, 2),
    75: Mapping("sensor_ellipsoid_m", -900.0, 19000.0, 2),
    78: Mapping("centre_ellipsoid_m", -900.0, 19000.0, 2),
    90: Mapping("platform_pitch_full_deg", -90.0, 90.0, 4, signed=True),
    91: Mapping("platform_roll_full_deg", -90.0, 90.0, 4, signed=True),
}


# EG 0104.5's items read, by their universal key's last 8 bytes: (name, how the value is written,
# EG 0104's name for it).
# "float": IEEE 754, 4 or 8 bytes big-endian; "uint": 8 bytes, big-endian; "text": bytes kept as
# the ST 0601 tag it answers (10 platform designation, 11 sensor, 3 mission id). Items not named
# here (corner points, target width, dates, security) are skipped.
EG0104_ITEMS: dict[bytes, tuple[str | int, str, str]] = {
    bytes.fromhex(key): item
    for key, item in {
        "0702010101050000": ("time_us", "uint", "User Defined Time Stamp"),
        "0701100106000000": ("platform_heading_deg", "float", "Platform Heading Angle"),
        # floats: no +-20 / +-50 deg bound as ST 0601's tags 6, 7 have
        "0701100105000000": ("platform_pitch_full_deg", "float", "Platform Pitch Angle"),
        "0701100104000000": ("platform_roll_full_deg", "float", "Platform Roll Angle"),
        "0701020102040200": ("sensor_latitude_deg", "float", "Device Latitude"),
        "0701020102040000": ("sensor_latitude_deg", "float", "Device Latitude"),  # older key
        "0701020102060200": ("sensor_longitude_deg", "float", "Device Longitude"),
        "0701020102060000": ("sensor_longitude_deg", "float", "Device Longitude"),
        "0701020102020000": ("sensor_msl_m", "float", "Device Altitude"),  # above sea level
        "0420020101080000": ("hfov_deg", "float", "Field of View (Horizontal)"),
        "04200201010A0100": ("vfov_deg", "float", "Field of View (Vertical)"),
        "0701100102000000": ("los_azimuth_deg", "float", "Angle to North"),
        "0701100103000000": ("los_obliquity_deg", "float", "Obliquity Angle"),
        "0701100101000000": ("los_roll_deg", "float", "Sensor Roll Angle"),
        "0701080101000000": ("slant_range_m", "float", "Slant Range"),
        "0701020103020000": ("centre_latitude_deg", "float", "Frame Center Latitude"),
        "0701020103040000": ("centre_longitude_deg", "float", "Frame Center Longitude"),
        "0701020103160000": ("centre_msl_m", "float", "Frame Center Elevation"),  # above sea
        "0101200100000000": (10, "text", "Device Designation"),
        "0420010201010000": (11, "text", "Image Source Device"),
        "0105050000000000": (3, "text", "Episode Number"),
    }.items()
}
# The line of sight as EG 0104 gives it (see the module's docstring): read by camera_orientation.
LOS_NAMES = ("los_azimuth_deg", "los_obliquity_deg", "los_roll_deg")


# --- writing -----------------------------------------------------------------------------------


def ber_length(n: int) -> bytes:
    """BER length: short form below 128, else long form (0x80 | byte count, big-endian)."""
    if n < 128:
        return bytes([n])
    body = n.to_bytes((n.bit_length() + 7) // 8, "big")
    return bytes([0x80 | len(body)]) + body


def ber_oid(tag: int) -> bytes:
    """A tag as BER-OID: 7 bits a byte, most significant first, the high bit set on all but the
    last (tags below 128 are one byte)."""
    out = [tag & 0x7F]
    tag >>= 7
    while tag:
        out.append(0x80 | (tag & 0x7F))
        tag >>= 7
    return bytes(reversed(out))


def unsigned(value: float, low: float, high: float, size: int) -> bytes:
    """value in [low, high] mapped onto an unsigned integer of `size` bytes (clamped)."""
    top = 2 ** (8 * size) - 1
    v = int(round((min(max(value, low), high) - low) * top / (high - low)))
    return v.to_bytes(size, "big")


def signed(value: float, span: float, size: int) -> bytes:
    """value in [-span, span] mapped onto a signed integer of `size` bytes; NaN or out of range:
    the most negative integer (ST 0601's error marker)."""
    top = 2 ** (8 * size - 1) - 1
    if not math.isfinite(value) or abs(value) > span:
        return (-(top + 1)).to_bytes(size, "big", signed=True)
    return int(round(value * top / span)).to_bytes(size, "big", signed=True)


def encode(tag: int, value: float) -> bytes:
    """A value of a mapped tag (TAGS) as its nominal-length integer."""
    m = TAGS[tag]
    if m.signed:
        return signed(value, m.high, m.size)
    return unsigned(value, m.low, m.high, m.size)


def checksum(data: bytes) -> int:
    """ST 0601's running 16-bit sum: even-offset bytes as the high byte, odd as the low byte."""
    total = 0
    for i, b in enumerate(data):
        total += b << (8 * ((i + 1) % 2))
    return total & 0xFFFF


def tlv(items: list[tuple[int, bytes]]) -> bytes:
    """Tag-length-value items in order (BER-OID tags, BER lengths): a Local Set's body, or the
    whole value of a set nested in an ST 0601 item (no key, no checksum of its own)."""
    return b"".join(ber_oid(tag) + ber_length(len(v)) + v for tag, v in items)


def local_set(items: list[tuple[int, bytes]]) -> bytes:
    """A whole Local Set: the key, the BER length, the items in order, the checksum last."""
    body = tlv(items) + bytes([CHECKSUM_TAG, 2])
    head = UAS_LOCAL_SET_KEY + ber_length(len(body) + 2)
    return head + body + checksum(head + body).to_bytes(2, "big")


# --- reading -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class LocalSet:
    """One Local Set read: its time stamp (microseconds since 1970, UTC; None when absent), the
    version it says (None: before tag 65 existed, or EG 0104), the mapped values by name (NaN:
    the standard's error code) and the raw bytes of every other tag (EG 0104's names under the
    ST 0601 tags they answer)."""

    time_us: int | None
    version: int | None
    values: dict[str, float] = field(default_factory=dict)
    other: dict[int, bytes] = field(default_factory=dict)
    standard: str = ST0601  # or EG0104: the set it was read from

    def get(self, name: str) -> float:
        """A mapped value by name (TAGS), NaN when the set does not carry it or says "error"."""
        return self.values.get(name, math.nan)


def read_ber(data: bytes, i: int) -> tuple[int, int]:
    """(length, index after it) of the BER length at data[i]; KlvError when it runs out."""
    if i >= len(data):
        raise KlvError(f"a length is cut off at byte {i}")
    first = data[i]
    if first < 128:
        return first, i + 1
    n = first & 0x7F
    if n == 0 or n > 8 or i + 1 + n > len(data):
        raise KlvError(f"bad BER length at byte {i}")
    return int.from_bytes(data[i + 1 : i + 1 + n], "big"), i + 1 + n


def read_oid(data: bytes, i: int) -> tuple[int, int]:
    """(tag, index after it) of the BER-OID tag at data[i]; KlvError when it runs out."""
    tag = 0
    for j in range(i, min(len(data), i + 4)):
        tag = (tag << 7) | (data[j] & 0x7F)
        if data[j] < 128:
            return tag, j + 1
    raise KlvError(f"bad tag at byte {i}")


def decode(tag: int, raw: bytes) -> float:
    """A mapped tag's value from its bytes (any length: the mapping scales with it); NaN for the
    reserved error code of a signed mapping."""
    m = TAGS[tag]
    if not raw:
        return math.nan
    size = len(raw)
    if m.signed:
        v = int.from_bytes(raw, "big", signed=True)
        top = 2 ** (8 * size - 1) - 1
        return math.nan if v == -(top + 1) else v * m.high / top
    v = int.from_bytes(raw, "big")
    return m.low + v * (m.high - m.low) / (2 ** (8 * size) - 1)


def is_key(data: bytes, i: int = 0, key: bytes = UAS_LOCAL_SET_KEY) -> bool:
    """Whether `key` (default: the UAS Datalink key) starts at data[i], its version byte any."""
    found = data[i : i + 16]
    return (
        len(found) == 16
        and found[:KEY_VERSION_BYTE] == key[:KEY_VERSION_BYTE]
        and found[KEY_VERSION_BYTE + 1 :] == key[KEY_VERSION_BYTE + 1 :]
    )


def find_key(data: bytes, start: int = 0, key: bytes = UAS_LOCAL_SET_KEY) -> int:
    """Where `key` (any version byte) first starts in data at or after `start`; -1 if nowhere."""
    i = data.find(key[:KEY_VERSION_BYTE], start)
    while i >= 0 and not is_key(data, i, key):
        i = data.find(key[:KEY_VERSION_BYTE], i + 1)
    return i


def is_eg0104(data: bytes) -> bool:
    """Whether a run of bytes holds an EG 0104 Universal Metadata Set (its key, any version)."""
    return find_key(data, key=EG0104_KEY) >= 0


def parse_any(packet: bytes) -> LocalSet:
    """A UAS Datalink Local Set (`parse`) or an EG 0104 set (`parse_eg0104`), by its key."""
    return parse_eg0104(packet) if is_key(packet, key=EG0104_KEY) else parse(packet)


def _eg0104_value(label: str, kind: str, raw: bytes, at: int) -> float | int | bytes:
    """One EG 0104 item's value (see EG0104_ITEMS); KlvError naming it and what was expected."""
    if kind == "text":
        return raw
    label = f"EG 0104 {label} (the item at byte {at})"
    if kind == "uint":
        if len(raw) != 8:
            raise KlvError(f"{label} has {len(raw)} bytes, expected 8 (microseconds since 1970)")
        return int.from_bytes(raw, "big")
    if len(raw) not in (4, 8):
        raise KlvError(f"{label} has {len(raw)} bytes, expected a 4- or 8-byte IEEE 754 float")
    value = struct.unpack(">f" if len(raw) == 4 else ">d", raw)[0]
    return value if math.isfinite(value) else math.nan


def parse_eg0104(packet: bytes) -> LocalSet:
    """One EG 0104 Universal Metadata Set (key first) read into a LocalSet (standard EG0104): the
    items EG0104_ITEMS names under ST 0601's names, the line of sight under LOS_NAMES (see the
    module's docstring). KlvError for a wrong key, a length past the end, an item whose key is
    not a universal key, or a value of a length its kind cannot have."""
    if not is_key(packet, key=EG0104_KEY):
        raise KlvError("not an EG 0104 Universal Metadata Set (wrong key)")
    length, i = read_ber(packet, 16)
    end = i + length
    if end > len(packet):
        raise KlvError(f"the EG 0104 set says {length} bytes, {len(packet) - i} follow")
    time_us: int | None = None
    values: dict[str, float] = {}
    other: dict[int, bytes] = {}
    while i < end:
        key = packet[i : i + 16]
        if len(key) < 16 or key[:4] != EG0104_ITEM_PREFIX[:4]:
            raise KlvError(
                f"EG 0104 item at byte {i}: not a 16-byte universal key (06 0E 2B 34 ...)"
            )
        n, j = read_ber(packet, i + 16)
        if j + n > end:
            raise KlvError(f"EG 0104 item {key.hex()} at byte {i} runs past the set's end")
        known = key[:7] == EG0104_ITEM_PREFIX and key[8:] in EG0104_ITEMS
        if known:
            name, kind, label = EG0104_ITEMS[key[8:]]
            value = _eg0104_value(label, kind, packet[j : j + n], i)
            if isinstance(name, int):
                other[name] = value
            elif name == "time_us":
                time_us = value or None
            else:
                values[name] = value
        i = j + n
    return LocalSet(time_us, None, values, other, EG0104)


def parse(packet: bytes) -> LocalSet:
    """One Local Set (key first) read and checked: KlvError for a wrong key, a length past the
    end, a missing checksum or one that does not match."""
    if not is_key(packet):
        raise KlvError("not a UAS Datalink Local Set (wrong key)")
    length, start = read_ber(packet, 16)
    end = start + length
    if end > len(packet):
        raise KlvError(f"the set says {length} bytes, {len(packet) - start} follow")
    items: list[tuple[int, bytes]] = []
    i = start
    while i < end:
        tag, i = read_oid(packet, i)
        n, i = read_ber(packet, i)
        if i + n > end:
            raise KlvError(f"tag {tag} runs past the set's end at byte {i}")
        items.append((tag, packet[i : i + n]))
        i += n
    if not items or items[-1][0] != CHECKSUM_TAG or len(items[-1][1]) != 2:
        raise KlvError("no checksum (tag 1) at the set's end")
    expected, found = int.from_bytes(items[-1][1], "big"), checksum(packet[: end - 2])
    if found != expected:
        raise KlvError(f"checksum {found:04x}, the set says {expected:04x}")
    time_us = version = None
    values: dict[str, float] = {}
    other: dict[int, bytes] = {}
    for tag, raw in items[:-1]:
        if tag == TIMESTAMP_TAG and len(raw) == 8:
            time_us = int.from_bytes(raw, "big")
        elif tag == VERSION_TAG and len(raw) == 1:
            version = raw[0]
        elif tag in TAGS:
            values[TAGS[tag].name] = decode(tag, raw)
        else:
            other[tag] = raw
    return LocalSet(time_us, version, values, other)


def split(data: bytes, dropped: list[tuple[int, str]] | None = None) -> Iterator[bytes]:
    """The Local Sets in a run of bytes (a KLV packet may hold several; bytes before a key are
    skipped), each cut at the length it says (see `sets_at`, which also gives where)."""
    return (raw for _, raw in sets_at(data, dropped))


class _SetFinder:
    """Where the next set (a UAS Datalink key or an EG 0104 key, any version) starts in data,
    asked with growing starts: each key's next place is searched again only once passed (a
    file of one kind is not scanned to its end for the other at every set)."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.found = {UAS_LOCAL_SET_KEY: -2, EG0104_KEY: -2}  # -2: not searched yet

    def next(self, start: int) -> int:
        for key, at in self.found.items():
            if at == -2 or 0 <= at < start:
                self.found[key] = find_key(self.data, start, key)
        places = [at for at in self.found.values() if at >= 0]
        return min(places) if places else -1


def sets_at(
    data: bytes, dropped: list[tuple[int, str]] | None = None
) -> Iterator[tuple[int, bytes]]:
    """(byte offset, bytes) of each Local Set in a run of bytes, cut at the length it says. A
    set cut off by the end or by the next set's key (a set cut short), or whose length cannot
    be read, is left out, noted in `dropped` as (byte offset of its key, what is wrong), and the
    search goes on after its key. Both UAS Datalink Local Sets and EG 0104 sets are found."""
    finder = _SetFinder(data)
    i = finder.next(0)
    while i >= 0:
        after = finder.next(i + 16)
        try:
            length, start = read_ber(data, i + 16)
        except KlvError as exc:
            reason = str(exc)
        else:
            end = start + length
            if end <= len(data) and not 0 <= after < end:
                yield i, data[i:end]
                i = after  # -1, or a key at or after the set's end
                continue
            reason = (
                f"the set says {length} bytes, the next set begins {after - start} bytes on"
                if 0 <= after < end
                else f"the set says {length} bytes, {len(data) - start} follow"
            )
        if dropped is not None:
            dropped.append((i, reason))
        i = after


# --- the camera it describes -------------------------------------------------------------------

_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# Our camera frame (OpenGL: x right, y up, looking down -z) in the sensor's (x the line of sight,
# y right, z down): the columns are the camera's axes.
_CAMERA_IN_SENSOR = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def ypr_matrix(yaw_deg: float, pitch_deg: float, roll_deg: float) -> FloatArray:
    """Rz(yaw) Ry(pitch) Rx(roll): an aerospace (x forward, y right, z down) body's rotation."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def camera_orientation(s: LocalSet) -> FloatArray | None:
    """Camera -> ENU quaternion [w, x, y, z] of a set: the platform's rotation (heading, pitch,
    roll: Rz Ry Rx of the aircraft in North-East-Down), then the sensor's relative rotation
    (azimuth, elevation, roll: Rz Ry Rx of the line of sight in the aircraft's frame), as ST 0601
    defines them. The full-range pitch and roll (90, 91) are used where present; a missing
    pitch, roll or relative angle counts as 0; no heading, or any angle in error: None. An EG
    0104 set: its own line of sight (`line_of_sight_orientation`)."""
    if s.standard == EG0104:
        return line_of_sight_orientation(s)
    heading = s.get("platform_heading_deg")
    pitch = s.values.get("platform_pitch_full_deg", s.values.get("platform_pitch_deg", 0.0))
    roll = s.values.get("platform_roll_full_deg", s.values.get("platform_roll_deg", 0.0))
    az = s.values.get("sensor_azimuth_deg", 0.0)
    el = s.values.get("sensor_elevation_deg", 0.0)
    sroll = s.values.get("sensor_roll_deg", 0.0)
    angles = (heading, pitch, roll, az, el, sroll)
    if not all(math.isfinite(a) for a in angles):
        return None
    return camera_from_sensor(ypr_matrix(heading, pitch, roll) @ ypr_matrix(az, el, sroll))


def eg0104_elevation_deg(obliquity_deg: float) -> float:
    """The line of sight's elevation above the horizon (deg, in [-180, 180)) from EG 0104's
    Obliquity Angle (deg: 180 level ahead, 270 straight down, 0 level behind): 180 - O."""
    return (180.0 - obliquity_deg + 180.0) % 360.0 - 180.0


def line_of_sight_orientation(s: LocalSet) -> FloatArray | None:
    """Camera -> ENU quaternion [w, x, y, z] of an EG 0104 set: Rz Ry Rx in North-East-Down of
    its line of sight's azimuth from true north (Angle to North), elevation (180 deg minus the
    Obliquity Angle) and roll about it (Sensor Roll Angle; missing: 0). None where the azimuth
    or the obliquity is missing or not a number."""
    az, obliquity = s.get("los_azimuth_deg"), s.get("los_obliquity_deg")
    roll = s.values.get("los_roll_deg", 0.0)
    if not all(math.isfinite(a) for a in (az, obliquity, roll)):
        return None
    return camera_from_sensor(ypr_matrix(az, eg0104_elevation_deg(obliquity), roll))


def camera_from_sensor(r_ned: FloatArray) -> FloatArray:
    """Camera -> ENU quaternion [w, x, y, z] of a sensor whose axes (x the line of sight, y right,
    z down) are the columns of r_ned in North-East-Down: the one convention ST 0601 and MAVLink
    share (app.io.mavlink uses it too)."""
    return rotations.from_matrix(_NED_TO_ENU @ r_ned @ _CAMERA_IN_SENSOR)


def camera_set(
    utc_s: float,
    geodetic: tuple[float, float, float],
    hpr_deg: tuple[float, float, float],
    hfov_deg: float,
    ground_h_m: float | None = None,
    placed: bool = True,
) -> bytes:
    """The Local Set of a camera at a position (lat, lon deg, ellipsoidal h m) with a heading,
    pitch and roll (deg): the platform level on that heading, the sensor's relative elevation
    and roll the camera's pitch and roll (as a gimbal on a level aircraft: ST 0601's platform
    pitch only spans +-20 deg); its field of view, UTC (utc_s: Unix seconds, tag 2), and the
    ground's ellipsoidal height as the frame centre's (tag 78). What the
    live recorder writes for a MAVLink flight, and the simulator's downlinks. placed False:
    without the sensor's latitude and longitude (tags 13, 14; a platform without a fix that
    still knows its height) nor a frame centre."""
    lat, lon, h = geodetic
    heading, pitch, roll = hpr_deg
    items = [
        (2, struct.pack(">Q", int(round(utc_s * 1e6)))),
        (65, bytes([ST0601_VERSION])),
        (5, encode(5, heading % 360.0)),
        (6, encode(6, 0.0)),
        (7, encode(7, 0.0)),
        (18, encode(18, 0.0)),
        (19, encode(19, pitch)),
        (20, encode(20, roll % 360.0)),
        *([(13, encode(13, lat)), (14, encode(14, lon))] if placed else []),
        (75, encode(75, h)),
        (16, encode(16, hfov_deg)),
    ]
    if ground_h_m is not None and placed:
        items.append((78, encode(78, ground_h_m)))
    return local_set(items)
