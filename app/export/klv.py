"""MISB ST 0601 (UAS Datalink Local Set) KLV for every exported frame, muxed beside the video in an
MPEG transport stream (the video copied, not re-encoded), so that a Full Motion Video player takes
a phone's, GoPro's or consumer drone's clip.

Each Local Set: the 16-byte UAS Datalink key, a BER length, then tag-length-value items with
ST 0601's integer mappings (a value of range R over an N-byte integer is v * (2^(8N) - 1) / R,
signed ones over 2^(8N-1) - 1, with the most negative integer as the "out of range" marker), and
the checksum (tag 1) last: the 16-bit sum of the packet from the key's first byte through the
checksum's own tag and length. The camera is the platform: platform heading = the optical axis's
heading, platform pitch and roll 0; the sensor's relative elevation and roll carry its pitch and
roll, as a gimbal's would.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable
from fractions import Fraction
from pathlib import Path

import av

from app.camera.frame_time import frame_of
from app.export.records import FrameRecord
from app.io.video import VideoInfo, media_seconds

UAS_LOCAL_SET_KEY = bytes.fromhex("060E2B34020B01010E01030101000000")
ST0601_VERSION = 17
CORNER_OFFSET_DEG = 0.075  # ST 0601 offset corners (tags 26-33) cover +-0.075 deg from the centre


def ber_length(n: int) -> bytes:
    """BER length: short form below 128, else long form (0x80 | byte count, big-endian)."""
    if n < 128:
        return bytes([n])
    body = n.to_bytes((n.bit_length() + 7) // 8, "big")
    return bytes([0x80 | len(body)]) + body


def unsigned(value: float, low: float, high: float, size: int) -> bytes:
    """value in [low, high] mapped onto an unsigned integer of `size` bytes."""
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


def checksum(data: bytes) -> int:
    """ST 0601's running 16-bit sum: even-offset bytes as the high byte, odd as the low byte."""
    total = 0
    for i, b in enumerate(data):
        total += b << (8 * ((i + 1) % 2))
    return total & 0xFFFF


def local_set(r: FrameRecord) -> bytes:
    """One UAS Datalink Local Set for a frame (see the module docstring for the mapping)."""
    heading, pitch, roll = r.hpr
    t = r.utc_s if r.utc_s is not None else r.session_s
    items: list[tuple[int, bytes]] = [
        (2, struct.pack(">Q", int(round(t * 1e6)))),  # Precision Time Stamp, microseconds
        (65, bytes([ST0601_VERSION])),
        (5, unsigned(heading % 360.0, 0.0, 360.0, 2)),  # Platform Heading Angle
        (6, signed(0.0, 20.0, 2)),  # Platform Pitch Angle
        (7, signed(0.0, 50.0, 2)),  # Platform Roll Angle
        (13, signed(r.sensor[0], 90.0, 4)),  # Sensor Latitude
        (14, signed(r.sensor[1], 180.0, 4)),  # Sensor Longitude
        (15, unsigned(r.sensor_msl_m, -900.0, 19000.0, 2)),  # Sensor True Altitude (MSL)
        (75, unsigned(r.sensor[2], -900.0, 19000.0, 2)),  # Sensor Ellipsoid Height
        (16, unsigned(r.hfov_deg, 0.0, 180.0, 2)),  # Sensor Horizontal Field of View
        (17, unsigned(r.vfov_deg, 0.0, 180.0, 2)),  # Sensor Vertical Field of View
        (18, unsigned(0.0, 0.0, 360.0, 4)),  # Sensor Relative Azimuth Angle
        (19, signed(pitch, 180.0, 4)),  # Sensor Relative Elevation Angle
        (20, unsigned(roll % 360.0, 0.0, 360.0, 4)),  # Sensor Relative Roll Angle
    ]
    if math.isfinite(r.slant_m):
        items.append((21, unsigned(r.slant_m, 0.0, 5_000_000.0, 4)))  # Slant Range
        items += [
            (23, signed(r.centre[0], 90.0, 4)),
            (24, signed(r.centre[1], 180.0, 4)),
            (25, unsigned(r.centre_msl_m, -900.0, 19000.0, 2)),  # Frame Center Elevation (MSL)
            (78, unsigned(r.centre[2], -900.0, 19000.0, 2)),  # Frame Center Height Above Ellipsoid
        ]
        for k in range(
            4
        ):  # Offset Corner Latitude/Longitude Point k+1, relative to the frame centre
            items.append((26 + 2 * k, signed(r.corners[k, 0] - r.centre[0], CORNER_OFFSET_DEG, 2)))
            items.append((27 + 2 * k, signed(r.corners[k, 1] - r.centre[1], CORNER_OFFSET_DEG, 2)))
    body = b"".join(bytes([tag]) + ber_length(len(v)) + v for tag, v in items) + b"\x01\x02"
    head = UAS_LOCAL_SET_KEY + ber_length(len(body) + 2)
    return head + body + checksum(head + body).to_bytes(2, "big")


def write_klv_ts(
    video: VideoInfo,
    records: Iterable[FrameRecord],
    out: Path,
    progress: Callable[[float], None] | None = None,
) -> int:
    """An MPEG-TS at `out`: the video's packets copied, and a KLV data stream with one Local Set
    per record at its frame's presentation time; returns the number of Local Sets written."""

    by_frame = {k: r for r in records if (k := frame_of(video.pts_s, r.media_s)) is not None}
    written = 0
    with av.open(str(video.path)) as src, av.open(str(out), "w", format="mpegts") as dst:
        vin = src.streams.video[0]
        vout = dst.add_stream_from_template(vin)
        data = dst.add_data_stream("klv")
        origin = video.origin_s
        tb = Fraction(1, 90000)
        for packet in src.demux(vin):
            if packet.dts is None:
                continue
            packet.stream = vout
            dst.mux(packet)
            if packet.pts is None:
                continue
            media = media_seconds(packet.pts, vin.time_base, origin)
            r = by_frame.get(frame_of(video.pts_s, media))
            if r is not None:
                k = av.Packet(local_set(r))
                k.stream = data
                k.time_base = tb
                k.pts = k.dts = int(round(float(packet.pts * vin.time_base) * 90000))
                dst.mux(k)
                written += 1
                if progress is not None:
                    progress(written / max(len(by_frame), 1))
    return written
