"""MISB ST 0601 (UAS Datalink Local Set) KLV for every exported frame, muxed beside the video in an
MPEG transport stream (the video copied, not re-encoded), so that a Full Motion Video player takes
a phone's, GoPro's or consumer drone's clip.

Each Local Set is written by app.io.misb (the key, BER lengths, ST 0601's integer mappings, the
checksum last), the module that reads them too. The camera is the platform: platform heading =
the optical axis's heading, platform pitch and roll 0; the sensor's relative elevation and roll
carry its pitch and roll, as a gimbal's would.

Which pose a set carries is said in the set itself: a pose corrected by registration against the
scene (the `registered` source, or a live feed's correction: app.live.register) carries ST 0601
item 98, a Geo-Registration Local Set (MISB ST 1601.2, nested: no key, no checksum) naming the
algorithm (its items 1 document version, 2 algorithm name, 3 algorithm version); a set without
item 98 carries the platform's (or the phone's) own pose. Item 98 is the one ST 0601 gives for
"these values come out of geo-registration"; the naming items (10 Platform Designation, 11 Image
Source Sensor) name the aircraft and the sensor, which downstream tools key on, and neither
Generic Flag Data (47) nor Positioning Method Source (124: INS and satellite systems) has a bit
for it. `pose_items` builds the items both the file export (`frame_set`) and the live restream
(app.live.restream) send.

What positioned each frame (issue 52: the solve CSV's `gnss`, app.camera.fixes) is said in item
124, Positioning Method Source, the one ST 0601 item whose bits name navigation sources: a frame
whose position stands on a GNSS fix used says the satellite bit (GPS: the receivers geofuse reads
do not name their constellations, and GPS is ST 0601's first); a frame whose fix was rejected or
is missing, where the IMU carried the track between the keyframes and the fixes kept
(app.register.inertial), says the INS bit alone; one with neither (no accelerometer) has no item
124, as ST 0601 has no bit for the scene (item 98 says the registration). Rejected and missing are
told apart only in the FMV CSV (`geofuse GNSS Status`) and the solve CSV: ST 0601 has no item
for a fix's integrity, and geofuse adds no tag of its own.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable
from fractions import Fraction
from pathlib import Path

import av

from app import __version__
from app.camera.fixes import USED
from app.camera.frame_time import frame_of
from app.core.constants import REGISTERED
from app.export.records import FrameRecord
from app.io.misb import ST0601_VERSION, encode, local_set, signed, tlv
from app.io.video import VideoInfo, demux, open_video
from app.session.camera_track import CameraTrack

CORNER_OFFSET_DEG = 0.075  # ST 0601 offset corners (tags 26-33) cover +-0.075 deg from the centre
GEOREGISTRATION_TAG = 98  # ST 0601 item 98: a Geo-Registration Local Set (MISB ST 1601)
POSITIONING_TAG = 124  # ST 0601 item 124: Positioning Method Source, one byte of flags
INS_BIT, GPS_BIT = 0x01, 0x02  # its bits 0 (on-board INS) and 1 (NAVSAT: GPS)
ST1601_VERSION = 2  # the ST 1601 document version written (item 1 of the nested set)
REGISTRATION_ALGORITHM = "geofuse render-and-compare"  # ST 1601 item 2: what corrected the pose


def georegistration_item() -> tuple[int, bytes]:
    """ST 0601 item 98: a Geo-Registration Local Set (ST 1601.2) naming geofuse's registration."""
    return (
        GEOREGISTRATION_TAG,
        tlv(
            [
                (1, bytes([ST1601_VERSION])),  # Document Version
                (2, REGISTRATION_ALGORITHM.encode()),  # Algorithm Name
                (3, __version__.encode()),  # Algorithm Version
            ]
        ),
    )


def pose_items(
    utc_s: float,
    sensor: tuple[float, float, float],
    sensor_msl_m: float,
    hpr: tuple[float, float, float],
    fov_deg: tuple[float, float],
    registered: bool,
) -> list[tuple[int, bytes]]:
    """The items of a camera's pose: its time (utc_s: Unix s), place (sensor: lat, lon deg,
    ellipsoidal h m; sensor_msl_m: its height above mean sea level), optical axis (hpr:
    heading, pitch, roll deg; see the module docstring for the mapping) and field of view
    (fov_deg: horizontal, vertical deg); registered: the pose comes out of registration
    (item 98, `georegistration_item`)."""
    heading, pitch, roll = hpr
    items: list[tuple[int, bytes]] = [
        (2, struct.pack(">Q", int(round(utc_s * 1e6)))),  # Precision Time Stamp, microseconds
        (65, bytes([ST0601_VERSION])),
        (5, encode(5, heading % 360.0)),  # Platform Heading Angle
        (6, encode(6, 0.0)),  # Platform Pitch Angle
        (7, encode(7, 0.0)),  # Platform Roll Angle
        (13, encode(13, sensor[0])),  # Sensor Latitude
        (14, encode(14, sensor[1])),  # Sensor Longitude
        (15, encode(15, sensor_msl_m)),  # Sensor True Altitude (MSL)
        (75, encode(75, sensor[2])),  # Sensor Ellipsoid Height
        (16, encode(16, fov_deg[0])),  # Sensor Horizontal Field of View
        (17, encode(17, fov_deg[1])),  # Sensor Vertical Field of View
        (18, encode(18, 0.0)),  # Sensor Relative Azimuth Angle
        (19, encode(19, pitch)),  # Sensor Relative Elevation Angle
        (20, encode(20, roll % 360.0)),  # Sensor Relative Roll Angle
    ]
    return items + [georegistration_item()] if registered else items


def positioning(gnss: str | None, inertial: bool) -> int | None:
    """ST 0601 item 124's flags for a frame whose position stands on `gnss` (app.camera.fixes:
    used, rejected, missing; None: not known), inertial: the IMU carried the track where the
    fixes were not used; None where no bit fits (module docstring)."""
    if gnss is None:
        return None
    if gnss == USED:
        return GPS_BIT
    return INS_BIT if inertial else None


def frame_set(r: FrameRecord, registered: bool = False, inertial: bool = False) -> bytes:
    """One UAS Datalink Local Set for a frame (see the module docstring for the mapping);
    registered: its pose comes out of registration (said in item 98); inertial: the IMU carried
    its track where the fixes were rejected or missing (item 124, `positioning`)."""
    t = r.utc_s if r.utc_s is not None else r.session_s
    fov = (r.hfov_deg, r.vfov_deg)
    items = pose_items(t, r.sensor, r.sensor_msl_m, r.hpr, fov, registered)
    flags = positioning(r.gnss, inertial)
    if flags is not None:
        items.append((POSITIONING_TAG, bytes([flags])))
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


def is_registered(track: CameraTrack) -> bool:
    """Whether a track's poses come out of registration: the `registered` source with at least
    one keyframe used (else it is its prior's, uncorrected)."""
    reg = track.registration
    return (
        track.source == REGISTERED
        and reg is not None
        and any(getattr(k, "used", False) for k in reg.keyframes)
    )


def carried_by_imu(track: CameraTrack) -> bool:
    """Whether a registered track was carried by the IMU where its fixes were not used
    (app.register.inertial: an accelerometer drove it)."""
    carried = getattr(track.registration, "carried", None) if is_registered(track) else None
    return carried is not None and carried.felt


def write_klv_ts(
    video: VideoInfo,
    records: Iterable[FrameRecord],
    out: Path,
    progress: Callable[[float], None] | None = None,
    registered: bool = False,
    inertial: bool = False,
) -> int:
    """An MPEG-TS at `out`: the video's packets copied, and a KLV data stream with one Local Set
    per record at its frame's presentation time; returns the number of Local Sets written.
    registered: the records' poses come out of registration (item 98 in every set); inertial:
    the IMU carried the track where the fixes were not used (item 124, `positioning`).

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
                k = av.Packet(frame_set(frames[written][1], registered, inertial))
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
