"""Cursor on Target events (pure: no I/O) for what geofuse shares with TAK (ATAK, WinTAK, iTAK,
TAK Server): the aircraft, its sensor's field of view and point of interest, the footprint, and
the marks. Each event is one CoT 2.0 XML document (MITRE's base event schema: version, uid,
type, how, time/start/stale, a point, a detail) as ATAK writes them.

What each thing becomes (the type codes are CoT's, MIL-STD-2525 in upper case):
- the aircraft: `a-f-A-M-F-Q` (friendly air, a UAV; CotIdentity.platform_type), at the sensor's
  position, with `<track>` (course, speed and slope of its motion in 3D, from the frame before;
  left out until two frames give it), `<sensor>` (ATAK's field-of-view cone: azimuth and
  elevation of the optical axis, roll, horizontal and vertical field of view, and the slant
  range to the point of interest, as MITRE's sensor sub-schema defines them), a callsign and
  remarks;
- the sensor point of interest: `b-m-p-s-p-i` at the frame centre on the scene, linked to the
  aircraft (`<link relation="p-p">`, ATAK's parent link, which draws the line of sight);
- the footprint: a drawn shape `u-d-f` whose `<link point="lat,lon"/>` vertices are the
  footprint's outline, closed (its first vertex repeated, ATAK's closed shape), one event per
  polygon of a MultiPolygon;
- the marks: points as spot map markers `b-m-p-s-m`, lines as open `u-d-f` drawings, areas as
  closed ones, named by their label (ATAK's `<contact callsign>`), with remarks saying what they
  measure and where they were taken; a mark no longer there is deleted on the receivers
  (`t-x-d-d` with `<__forcedelete/>`, ATAK's delete).

The photo crop of a mark is not attached: CoT over UDP or a TCP stream carries no files. ATAK's
attachments (`<attachment_list hashes=...>`) name files by hash that a TAK Server's Marti API
holds (an HTTPS upload with the same client certificate) or a data package carries, and MITRE's
`<image>` detail (base64 inside the event) is shown by no TAK client and would swell an event
past a datagram; the marks handed over (app.locate.marks.marks_geojson) hold no crop either.

Times: `time` and `start` are when the event is made (the sender's UTC clock), `stale` a few
seconds later for what moves (MOVING_STALE_S: a feed that stops fades out on the receivers
within it) and minutes later for the marks (MARK_STALE_S; the sender sends them again every
MARK_RESEND_S); the frame's own UTC, clip, index and pose source ride in a `<__geofuse>` detail
(ATAK keeps a detail it does not know, and ignores it). Positions: WGS84 degrees, heights above
the ellipsoid (CoT's hae), in metres; ce and le 9999999 (CoT's "unknown").

`how`: the aircraft `m-f` (fused) when its pose is geofuse's registered one, else `m-g` (from
the platform's GNSS); the point of interest, footprint and marks `m-i` (mensurated from the
imagery on the scene: a person picked a mark's pixel, the scene gave its place).
"""

from __future__ import annotations

import hashlib
import math
import re
import socket
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

from app.share.frames import SharedFrame

__all__ = [
    "CotEvent",
    "CotIdentity",
    "Motion",
    "aircraft_event",
    "delete_event",
    "footprint_events",
    "mark_events",
    "motion",
    "poi_event",
]

AIRCRAFT_TYPE = "a-f-A-M-F-Q"  # friendly, air, military, fixed wing, UAV: ATAK's UAS symbol
POI_TYPE = "b-m-p-s-p-i"  # bits, mapping, point, sensor, point of interest
DRAWING_TYPE = "u-d-f"  # a free-form drawing (ATAK's polyline / polygon)
SPOT_TYPE = "b-m-p-s-m"  # a spot map marker
DELETE_TYPE = "t-x-d-d"  # ATAK's delete of another uid

MOVING_STALE_S = 5.0  # the aircraft, its point of interest and footprint
MARK_STALE_S = 600.0
MARK_RESEND_S = 60.0
DELETE_STALE_S = 20.0
MOTION_MAX_DT_S = 5.0  # frames further apart give no motion
UNKNOWN = "9999999.0"  # ce, le (and hae) CoT's receivers read as unknown
XML_DECLARATION = "<?xml version='1.0' encoding='UTF-8' standalone='yes'?>"

# ARGB as the signed 32-bit integers ATAK writes
FOOTPRINT_STROKE = -256  # 0xFFFFFF00 yellow
FOOTPRINT_FILL = 0x40FFFF00  # yellow, a quarter opaque
MARK_COLOUR = -65536  # 0xFFFF0000 red
MARK_FILL = 0x40FF0000

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3

KIND_AIRCRAFT, KIND_POI, KIND_FOOTPRINT, KIND_MARK, KIND_DELETE = (
    "aircraft",
    "sensor point",
    "footprint",
    "mark",
    "delete",
)


@dataclass(frozen=True)
class CotIdentity:
    """Who sends: uid (the aircraft's; every other uid derives from it), callsign (the name
    receivers show) and the aircraft's CoT type."""

    uid: str
    callsign: str = "geofuse"
    platform_type: str = AIRCRAFT_TYPE

    @staticmethod
    def of(callsign: str = "geofuse", host: str | None = None) -> CotIdentity:
        """The identity of this machine's geofuse under a callsign: uid geofuse-HOST-CALLSIGN
        (letters, digits, dots and dashes only)."""
        host = host if host is not None else socket.gethostname()
        slug = re.sub(r"[^A-Za-z0-9.-]+", "-", f"{host}-{callsign}").strip("-") or "geofuse"
        return CotIdentity(f"geofuse-{slug}", callsign)


@dataclass(frozen=True)
class CotEvent:
    """One event: kind (aircraft, sensor point, footprint, mark, delete), its uid, its stale
    time (Unix s: a sender drops it unsent past this) and its XML (UTF-8 bytes)."""

    kind: str
    uid: str
    stale_s: float
    xml: bytes


@dataclass(frozen=True)
class Motion:
    """The aircraft's motion between two frames: course (deg clockwise from true north, of the
    horizontal part), speed (m/s, in 3D, as MITRE's track defines it) and slope (deg, up > 0)."""

    course_deg: float
    speed_m_s: float
    slope_deg: float


def motion(
    before: SharedFrame, now: SharedFrame, max_dt_s: float = MOTION_MAX_DT_S
) -> Motion | None:
    """The motion from `before` to `now` (their sensor positions over their media times), None
    where they are not 0 < dt <= max_dt_s apart. Local radii of curvature at their mean
    latitude: exact to far below a millimetre over the metres between two frames."""
    dt = now.media_s - before.media_s
    if not 0.0 < dt <= max_dt_s:
        return None
    lat0 = math.radians(0.5 * (before.sensor[0] + now.sensor[0]))
    w = 1.0 - WGS84_E2 * math.sin(lat0) ** 2
    h = 0.5 * (before.sensor[2] + now.sensor[2])
    meridian = WGS84_A * (1.0 - WGS84_E2) / w**1.5 + h
    normal = (WGS84_A / math.sqrt(w) + h) * math.cos(lat0)
    north = math.radians(now.sensor[0] - before.sensor[0]) * meridian
    dlon = (now.sensor[1] - before.sensor[1] + 540.0) % 360.0 - 180.0
    east = math.radians(dlon) * normal
    up = now.sensor[2] - before.sensor[2]
    ground = math.hypot(east, north)
    return Motion(
        _angle(math.degrees(math.atan2(east, north))),
        math.hypot(ground, up) / dt,
        math.degrees(math.atan2(up, ground)),
    )


def _angle(deg: float, places: int = 3) -> float:
    """An angle in [0, 360), after rounding to `places` (359.99999 must not print as 360)."""
    v = round(deg % 360.0, places)
    return 0.0 if v >= 360.0 else v


def _roll(deg: float, places: int = 3) -> float:
    """A roll in (-180, 180] after rounding."""
    v = round((deg + 180.0) % 360.0 - 180.0, places)
    return 180.0 if v <= -180.0 else v


def _iso(unix_s: float) -> str:
    """xs:dateTime in UTC with milliseconds, as ATAK writes it."""
    t = datetime.fromtimestamp(unix_s, UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _deg(v: float) -> str:
    return f"{v:.9f}"  # 0.1 mm; xs:decimal has no exponent


def _m(v: float) -> str:
    return f"{v:.3f}"


def _num(v: float, places: int = 3) -> str:
    return f"{v:.{places}f}"


def _event(
    kind: str,
    cot_type: str,
    uid: str,
    how: str,
    now_s: float,
    stale_after_s: float,
    point: tuple[float, float, float] | None,
) -> tuple[ET.Element, ET.Element, float]:
    """(event, its detail, stale Unix s); point (lat, lon, hae) or None (all unknown: 0, 0)."""
    stale = now_s + stale_after_s
    t = _iso(now_s)
    event = ET.Element(
        "event",
        {
            "version": "2.0",
            "uid": uid,
            "type": cot_type,
            "how": how,
            "time": t,
            "start": t,
            "stale": _iso(stale),
        },
    )
    lat, lon, hae = point if point is not None else (0.0, 0.0, None)
    ET.SubElement(
        event,
        "point",
        {
            "lat": _deg(lat),
            "lon": _deg(lon),
            "hae": UNKNOWN if hae is None or not math.isfinite(hae) else _m(hae),
            "ce": UNKNOWN,
            "le": UNKNOWN,
        },
    )
    return event, ET.SubElement(event, "detail"), stale


def _done(kind: str, uid: str, stale: float, event: ET.Element) -> CotEvent:
    xml = XML_DECLARATION + ET.tostring(event, encoding="unicode")
    return CotEvent(kind, uid, stale, xml.encode("utf-8"))


def _frame_detail(detail: ET.Element, frame: SharedFrame) -> None:
    """The frame the event comes from, for receivers that read it (and tests)."""
    attrs = {
        "clip": frame.clip,
        "frame": str(frame.index),
        "media_s": f"{frame.media_s:.6f}",
        "source": frame.source,
    }
    if frame.utc_s is not None:
        attrs["utc"] = _iso(frame.utc_s)
    if frame.gnss is not None:
        attrs["gnss"] = frame.gnss
    ET.SubElement(detail, "__geofuse", attrs)


def _remarks(detail: ET.Element, text: str) -> None:
    ET.SubElement(detail, "remarks", {"source": "geofuse"}).text = text


def _where(frame: SharedFrame) -> str:
    gnss = f", GNSS {frame.gnss}" if frame.gnss is not None else ""
    return f"{frame.clip or 'video'} frame {frame.index} ({frame.source or 'unknown'} pose{gnss})"


def aircraft_event(
    frame: SharedFrame, who: CotIdentity, now_s: float, moving: Motion | None = None
) -> CotEvent:
    """The aircraft at the frame's sensor position, its track (`moving`, when known) and its
    sensor's field of view (see the module docstring); now_s: UTC Unix s."""
    how = "m-f" if frame.source == "registered" else "m-g"
    event, detail, stale = _event(
        KIND_AIRCRAFT, who.platform_type, who.uid, how, now_s, MOVING_STALE_S, frame.sensor
    )
    ET.SubElement(detail, "contact", {"callsign": who.callsign})
    if moving is not None:
        ET.SubElement(
            detail,
            "track",
            {
                "course": _num(_angle(moving.course_deg)),
                "speed": _num(max(moving.speed_m_s, 0.0)),
                "slope": _num(max(-90.0, min(90.0, moving.slope_deg))),
            },
        )
    heading, pitch, roll = frame.hpr
    sensor = {
        "azimuth": _num(_angle(heading)),
        "elevation": _num(max(-90.0, min(90.0, pitch))),
        "roll": _num(_roll(roll)),
        "fov": _num(_angle(frame.hfov_deg)),
        "vfov": _num(_angle(frame.vfov_deg)),
        "type": "r-e",  # raster, electro-optical (MITRE's sensor types)
    }
    if frame.slant_m is not None and math.isfinite(frame.slant_m):
        sensor["range"] = _num(max(frame.slant_m, 0.0), 1)
    ET.SubElement(detail, "sensor", sensor)
    _remarks(
        detail,
        f"{who.callsign}: {_where(frame)}; {frame.sensor_msl_m:.1f} m above sea level",
    )
    _frame_detail(detail, frame)
    return _done(KIND_AIRCRAFT, who.uid, stale, event)


def poi_uid(who: CotIdentity) -> str:
    return f"{who.uid}.SPI"


def poi_event(frame: SharedFrame, who: CotIdentity, now_s: float) -> CotEvent | None:
    """The sensor's point of interest (the frame centre on the scene), None where the optical
    axis meets nothing; linked to the aircraft as its parent."""
    if frame.centre is None:
        return None
    uid = poi_uid(who)
    event, detail, stale = _event(
        KIND_POI, POI_TYPE, uid, "m-i", now_s, MOVING_STALE_S, frame.centre
    )
    ET.SubElement(detail, "contact", {"callsign": f"{who.callsign} SPI"})
    ET.SubElement(
        detail,
        "link",
        {
            "uid": who.uid,
            "type": who.platform_type,
            "relation": "p-p",
            "parent_callsign": who.callsign,
            "production_time": _iso(now_s),
        },
    )
    msl = "" if frame.centre_msl_m is None else f", {frame.centre_msl_m:.1f} m above sea level"
    slant = "" if frame.slant_m is None else f"slant range {frame.slant_m:.1f} m"
    _remarks(detail, f"point of interest of {who.callsign}: {slant}{msl}; {_where(frame)}")
    _frame_detail(detail, frame)
    return _done(KIND_POI, uid, stale, event)


def _rings(geometry: dict | None) -> list[list[Sequence[float]]]:
    """The outer rings of a GeoJSON Polygon or MultiPolygon (positions [lon, lat, (h)])."""
    if geometry is None:
        return []
    if geometry.get("type") == "Polygon":
        return [geometry["coordinates"][0]]
    if geometry.get("type") == "MultiPolygon":
        return [polygon[0] for polygon in geometry["coordinates"]]
    return []


def _link_point(position: Sequence[float]) -> str:
    """ATAK's "lat,lon" or "lat,lon,hae" of a GeoJSON position [lon, lat, (h)]."""
    text = f"{_deg(position[1])},{_deg(position[0])}"
    return text + (f",{_m(position[2])}" if len(position) > 2 else "")


def _drawing(
    kind: str,
    uid: str,
    positions: Sequence[Sequence[float]],
    closed: bool,
    name: str,
    stroke: int,
    fill: int | None,
    how: str,
    now_s: float,
    stale_after_s: float,
    hae: float | None,
) -> tuple[ET.Element, ET.Element, float]:
    """A u-d-f drawing through the positions ([lon, lat, (h)]; a closed one ends on its first),
    its point the mean of its vertices."""
    verts = list(positions)
    if closed and list(verts[0]) != list(verts[-1]):
        verts.append(verts[0])
    body = verts[:-1] if closed else verts
    lat = sum(p[1] for p in body) / len(body)
    lon = sum(p[0] for p in body) / len(body)
    event, detail, stale = _event(
        kind, DRAWING_TYPE, uid, how, now_s, stale_after_s, (lat, lon, hae)
    )
    for p in verts:
        ET.SubElement(detail, "link", {"point": _link_point(p)})
    ET.SubElement(detail, "strokeColor", {"value": str(stroke)})
    ET.SubElement(detail, "strokeWeight", {"value": "3.0"})
    if fill is not None:
        ET.SubElement(detail, "fillColor", {"value": str(fill)})
    ET.SubElement(detail, "contact", {"callsign": name})
    ET.SubElement(detail, "labels_on", {"value": "true"})
    return event, detail, stale


def footprint_uid(who: CotIdentity, part: int = 0) -> str:
    return f"{who.uid}.footprint" + (f".{part}" if part else "")


def footprint_events(frame: SharedFrame, who: CotIdentity, now_s: float) -> list[CotEvent]:
    """The footprint as closed drawings, one per polygon (none where the frame sees no
    ground); the vertices are the SharedFrame's, in its order."""
    out = []
    hae = frame.centre[2] if frame.centre is not None else None
    for k, ring in enumerate(_rings(frame.footprint)):
        if len(ring) < 3:
            continue
        uid = footprint_uid(who, k)
        event, detail, stale = _drawing(
            KIND_FOOTPRINT,
            uid,
            ring,
            True,
            f"{who.callsign} footprint",
            FOOTPRINT_STROKE,
            FOOTPRINT_FILL,
            "m-i",
            now_s,
            MOVING_STALE_S,
            hae,
        )
        _remarks(detail, f"footprint of {who.callsign}: {_where(frame)}")
        _frame_detail(detail, frame)
        out.append(_done(KIND_FOOTPRINT, uid, stale, event))
    return out


def mark_uid(who: CotIdentity, feature: dict) -> str:
    """A mark's uid: the same for the same mark (kind, label, clip, frame, place), in every
    run and every sender of this identity."""
    props = feature.get("properties", {})
    key = repr(
        (
            props.get("kind"),
            props.get("label"),
            props.get("clip"),
            props.get("frame"),
            feature.get("geometry"),
        )
    )
    return f"{who.uid}.mark.{hashlib.sha1(key.encode('utf-8')).hexdigest()[:12]}"


def _mark_remarks(props: dict) -> str:
    kind = props.get("kind", "mark")
    parts = [str(kind)]
    if props.get("length_m") is not None:
        parts.append(
            f"{props['length_m']:.2f} m ({props.get('ground_length_m') or 0.0:.2f} m along the ground)"
        )
    if props.get("area_m2") is not None:
        parts.append(f"area {props['area_m2']:.1f} m2")
    taken = f"from {props.get('clip') or 'video'} frame {props.get('frame')}"
    if props.get("media_time_s") is not None:
        taken += f" ({props['media_time_s']:.2f} s)"
    parts.append(taken)
    if props.get("object_id") is not None:
        parts.append(f"on {props.get('object_type') or 'object'} {props['object_id']}")
    return "; ".join(parts)


def mark_events(marks: dict, who: CotIdentity, now_s: float) -> list[CotEvent]:
    """Every mark of a GeoJSON FeatureCollection (app.locate.marks.marks_geojson: lon, lat,
    ellipsoidal h): points as spot markers, lines as open drawings, polygons as closed ones
    (one per polygon of a MultiPolygon), named by their label (else "KIND N")."""
    out = []
    for i, feature in enumerate(marks.get("features", [])):
        props = feature.get("properties") or {}
        geometry = feature.get("geometry") or {}
        name = str(props.get("label") or f"{props.get('kind', 'mark')} {i + 1}")
        uid = mark_uid(who, feature)
        remarks = _mark_remarks(props)
        kind = geometry.get("type")
        if kind == "Point":
            lon, lat, *h = geometry["coordinates"]
            event, detail, stale = _event(
                KIND_MARK,
                SPOT_TYPE,
                uid,
                "m-i",
                now_s,
                MARK_STALE_S,
                (lat, lon, h[0] if h else None),
            )
            ET.SubElement(detail, "contact", {"callsign": name})
            ET.SubElement(detail, "color", {"argb": str(MARK_COLOUR)})
            ET.SubElement(
                detail,
                "usericon",
                {"iconsetpath": f"COT_MAPPING_SPOTMAP/{SPOT_TYPE}/{MARK_COLOUR}"},
            )
            _remarks(detail, remarks)
            out.append(_done(KIND_MARK, uid, stale, event))
            continue
        if kind == "LineString":
            pieces = [(geometry["coordinates"], False)]
        else:
            pieces = [(ring, True) for ring in _rings(geometry)]
        for k, (positions, closed) in enumerate(pieces):
            if len(positions) < 2:
                continue
            part_uid = uid + (f".{k}" if k else "")
            heights = [p[2] for p in positions if len(p) > 2]
            event, detail, stale = _drawing(
                KIND_MARK,
                part_uid,
                positions,
                closed,
                name if len(pieces) == 1 else f"{name} ({k + 1})",
                MARK_COLOUR,
                MARK_FILL if closed else None,
                "m-i",
                now_s,
                MARK_STALE_S,
                sum(heights) / len(heights) if heights else None,
            )
            _remarks(detail, remarks)
            out.append(_done(KIND_MARK, part_uid, stale, event))
    return out


def delete_event(uid: str, now_s: float) -> CotEvent:
    """ATAK's delete of the item `uid` (a mark removed)."""
    event, detail, stale = _event(
        KIND_DELETE, DELETE_TYPE, f"{uid}.delete", "m-g", now_s, DELETE_STALE_S, None
    )
    ET.SubElement(detail, "link", {"uid": uid, "relation": "none", "type": "none"})
    ET.SubElement(detail, "__forcedelete")
    return _done(KIND_DELETE, uid, stale, event)
