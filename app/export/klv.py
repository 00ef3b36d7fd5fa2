"""MISB ST 0601 (UAS Datalink Local Set) KLV for every exported frame, muxed beside the video in an
MPEG transport stream (the video copied, not re-encoded), so that a Full Motion Video player takes
a phone's, GoPro's or consumer drone's clip.

Each Local Set is written by app.io.misb (the key, BER lengths, ST 0601's integer mappings, the
checksum last), the module that reads them too. The camera is the platform: platform heading =
the optical axis's heading, platform pitch and roll 0; the sensor's relative elevation and roll
carry its pitch and roll, as a gimbal's would.
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
from app.io.misb import ST0601_VERSION, encode, local_set, signed
from app.io.video import VideoInfo, demux, open_video

CORNER_OFFSET_DEG = 0.075  # ST 0601 offset corners (tags 26-33) cover +-0.075 deg from the centre


def frame_set(r: FrameRecord) -> bytes:
    """One UAS Datalink Local Set for a frame (see the module docstring for the mapping)."""
    heading, pitch, roll = r.hpr
    t = r.utc_s if r.utc_s is not None else r.session_s
    items: list[tuple[int, bytes]] = [
        (2, struct.pack(">Q", int(round(t * 1e6)))),  # Precision Time Stamp, microseconds
        (65, bytes([ST0601_VERSION])),
        (5, encode(5, heading % 360.0)),  # Platform Heading Angle
        (6, encode(6, 0.0)),  # Platform Pitch Angle
        (7, encode(7, 0.0)),  # Platform Roll Angle
        (13, encode(13, r.sensor[0])),  # Sensor Latitude
        (14, encode(14, r.sensor[1])),  # Sensor Longitude
        (15, encode(15, r.sensor_msl_m)),  # Sensor True Altitude (MSL)
        (75, encode(75, r.sensor[2])),  # Sensor Ellipsoid Height
        (16, encode(16, r.hfov_deg)),  # Sensor Horizontal Field of View
        (17, encode(17, r.vfov_deg)),  # Sensor Vertical Field of View
        (18, encode(18, 0.0)),  # Sensor Relative Azimuth Angle
        (19, encode(19, pitch)),  # Sensor Relative Elevation Angle
        (20, encode(20, roll % 360.0)),  # Sensor Relative Roll Angle
    ]
    if math.isfinite(r.slant_m):
        items.append((21, encode(21, r.slant_m)))  # Slant Range
        items += [
            (23, encode(23, r.centre[0])),
            (24, encode(24, r.centre[1])),
            (25, encode(25, r.centre_msl_m)),  # Frame Center Elevation (MSL)
            (78, encode(78, r.centre[2])),  # Frame Center Height Above Ellipsoid
        ]
        for k in range(4):  # Offset Corner Latitude/Longitude Point k+1, relative to the centre
            items.append((26 + 2 * k, signed(r.corners[k, 0] - r.centre[0], CORNER_OFFSET_DEG, 2)))
            items.append((27 + 2 * k, signed(r.corners[k, 1] - r.centre[1], CORNER_OFFSET_DEG, 2)))
    return local_set(items)


def write_klv_ts(
    video: VideoInfo,
    records: Iterable[FrameRecord],
    out: Path,
    progress: Callable[[float], None] | None = None,
) -> int:
    """An MPEG-TS at `out`: the video's packets copied, and a KLV data stream with one Local Set
    per record at its frame's presentation time; returns the number of Local Sets written.

    The sets' times come from the frame table (video.pts_s, on the stream's clock by adding
    origin_s), never from a muxed packet: the muxer rebases a packet to the output's 1/90000 time
    base in place, and packets arrive in decode order (B-frames), while a data stream's times must
    rise. The sets are muxed in presentation order, each once the video's decode time reaches it."""

    frames = sorted((k, r) for r in records if (k := frame_of(video.pts_s, r.media_s)) is not None)
    tb = Fraction(1, 90000)
    ticks = [int(round((float(video.pts_s[k]) + video.origin_s) * 90000)) for k, _ in frames]
    written = 0
    with open_video(video.path) as src, av.open(str(out), "w", format="mpegts") as dst:
        vin = src.streams.video[0]
        vout = dst.add_stream_from_template(vin)
        data = dst.add_data_stream("klv")

        def mux_sets(until: float) -> None:
            nonlocal written
            while written < len(frames) and ticks[written] <= until:
                k = av.Packet(frame_set(frames[written][1]))
                k.stream = data
                k.time_base = tb
                k.pts = k.dts = ticks[written]
                dst.mux(k)
                written += 1
                if progress is not None:
                    progress(written / len(frames))

        for packet in demux(src, vin):
            if packet.dts is None:
                continue
            mux_sets(float(packet.dts * vin.time_base) * 90000)
            packet.stream = vout
            dst.mux(packet)
        mux_sets(float("inf"))
    return written
