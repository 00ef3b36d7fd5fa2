"""Frame records (app.export.records) as GIS layers: GeoJSON (RFC 7946), KML and KMZ (Google
Earth), and the metadata CSV of ArcGIS Pro's Video Multiplexer (Full Motion Video). Pure text;
files are written through app.outputs (checked, atomic, never over an input).

GeoJSON: one Polygon feature per frame (the footprint, exterior ring counter-clockwise and closed,
positions [longitude, latitude, ellipsoidal height]) with the frame's fields as properties, then
one LineString feature for the camera track. Fields without a value (the frame centre above the
horizon) are null. KML carries the same fields as ExtendedData, heights `absolute`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
from collections.abc import Iterable
from datetime import datetime, timezone
from xml.sax.saxutils import escape

import numpy as np

from app.export.records import FOOTPRINT_MAX_RANGE_M, FrameRecord

FMV_FIELDS = (  # MISB ST 0601 names, as the Video Multiplexer's field mapping template lists them
    "UNIX Time Stamp", "Sensor Latitude", "Sensor Longitude", "Sensor Ellipsoid Height",
    "Platform Heading Angle", "Platform Pitch Angle", "Platform Roll Angle",
    "Sensor Relative Azimuth Angle", "Sensor Relative Elevation Angle", "Sensor Relative Roll Angle",
    "Sensor Horizontal Field of View", "Sensor Vertical Field of View", "Slant Range",
    "Frame Center Latitude", "Frame Center Longitude", "Frame Center Elevation",
    "Corner Latitude Point 1", "Corner Longitude Point 1", "Corner Latitude Point 2", "Corner Longitude Point 2",
    "Corner Latitude Point 3", "Corner Longitude Point 3", "Corner Latitude Point 4", "Corner Longitude Point 4",
)  # fmt: skip


def _value(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def iso_utc(unix_s: float | None) -> str | None:
    """ISO 8601 UTC with microseconds, or None."""
    if unix_s is None:
        return None
    return (
        datetime.fromtimestamp(unix_s, timezone.utc)
        .isoformat(timespec="microseconds")
        .replace("+00:00", "Z")
    )


def properties(r: FrameRecord) -> dict[str, object]:
    """The fields of one frame, named with their units."""
    return {
        "frame": r.index,
        "time_s": round(r.session_s, 6),
        "media_time_s": round(r.media_s, 6),
        "utc": iso_utc(r.utc_s),
        "sensor_latitude": r.sensor[0],
        "sensor_longitude": r.sensor[1],
        "sensor_height_m": r.sensor[2],
        "heading_deg": r.hpr[0],
        "pitch_deg": r.hpr[1],
        "roll_deg": r.hpr[2],
        "hfov_deg": r.hfov_deg,
        "vfov_deg": r.vfov_deg,
        "centre_latitude": _value(r.centre[0]),
        "centre_longitude": _value(r.centre[1]),
        "centre_height_m": _value(r.centre[2]),
        "slant_range_m": _value(r.slant_m),
        "clipped": r.clipped,
        "clip_range_m": FOOTPRINT_MAX_RANGE_M if r.clipped else None,
    }


def counter_clockwise_ring(lat_lon_h: np.ndarray) -> np.ndarray:
    """A closed ring (N + 1, 3) as [lon, lat, h], counter-clockwise seen from above (RFC 7946's
    right-hand rule for exterior rings), from N points (lat, lon, h) in any winding."""
    ring = np.column_stack([lat_lon_h[:, 1], lat_lon_h[:, 0], lat_lon_h[:, 2]])
    x = ring[:, 0] * math.cos(math.radians(float(np.mean(ring[:, 1]))))
    y = ring[:, 1]
    area2 = float(
        np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    )  # shoelace: > 0 counter-clockwise
    if area2 < 0:
        ring = ring[::-1]
    return np.vstack([ring, ring[:1]])


def geojson(records: Iterable[FrameRecord]) -> dict:
    """A FeatureCollection: footprints, then the camera track."""
    features, track = [], []
    for r in records:
        ring = counter_clockwise_ring(r.footprint)
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "Polygon", "coordinates": [np.round(ring, 9).tolist()]},
                "properties": properties(r),
            }
        )
        track.append([r.sensor[1], r.sensor[0], r.sensor[2]])
    if len(track) >= 2:
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": np.round(track, 9).tolist()},
                "properties": {"name": "camera track"},
            }
        )
    return {"type": "FeatureCollection", "features": features}


def write_geojson(records: Iterable[FrameRecord], f) -> None:
    json.dump(geojson(records), f, allow_nan=False)


def kml(records: Iterable[FrameRecord], name: str) -> str:
    """A KML document: one Placemark per footprint (with ExtendedData), then the camera track."""
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>',
        f"<name>{escape(name)}</name>",
        '<Style id="footprint"><LineStyle><color>ff00a5ff</color><width>2</width></LineStyle><PolyStyle><color>4000a5ff</color></PolyStyle></Style>',
    ]
    track = []
    for r in records:
        ring = counter_clockwise_ring(r.footprint)
        coords = " ".join(f"{lon:.9f},{lat:.9f},{h:.3f}" for lon, lat, h in ring)
        data = "".join(
            f'<Data name="{k}"><value>{"" if v is None else escape(str(v))}</value></Data>'
            for k, v in properties(r).items()
        )
        out.append(
            f"<Placemark><name>frame {r.index}</name><styleUrl>#footprint</styleUrl><ExtendedData>{data}</ExtendedData>"
            f"<Polygon><altitudeMode>absolute</altitudeMode><outerBoundaryIs><LinearRing><coordinates>{coords}</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark>"
        )
        track.append(f"{r.sensor[1]:.9f},{r.sensor[0]:.9f},{r.sensor[2]:.3f}")
    if len(track) >= 2:
        out.append(
            f"<Placemark><name>camera track</name><LineString><altitudeMode>absolute</altitudeMode><coordinates>{' '.join(track)}</coordinates></LineString></Placemark>"
        )
    out.append("</Document></kml>")
    return "\n".join(out)


def write_kmz(records: Iterable[FrameRecord], f, name: str) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", kml(records, name))
    f.write(buf.getvalue())


def fmv_row(r: FrameRecord) -> list[str]:
    """One row of the Video Multiplexer CSV: time in integer microseconds since the Unix epoch;
    the camera is the platform (heading only: the sensor's elevation and roll carry the pitch and
    roll, as a gimbal's would); corners as absolute latitude and longitude."""
    t = r.utc_s if r.utc_s is not None else r.session_s
    h, p, roll = r.hpr
    c = r.corners
    cells = [
        int(round(t * 1e6)),
        r.sensor[0],
        r.sensor[1],
        r.sensor[2],
        h % 360.0,
        0.0,
        0.0,
        0.0,
        p,
        roll % 360.0,
        r.hfov_deg,
        r.vfov_deg,
        r.slant_m,
        *r.centre,
    ]
    cells += [v for k in range(4) for v in (c[k, 0], c[k, 1])]
    return [str(cells[0])] + [
        "" if not math.isfinite(v) else f"{v:.9f}" if abs(v) <= 360 else f"{v:.3f}"
        for v in cells[1:]
    ]


def write_fmv_csv(records: Iterable[FrameRecord], f) -> None:
    w = csv.writer(f)
    w.writerow(FMV_FIELDS)
    for r in records:
        w.writerow(fmv_row(r))


def write_records(records: Iterable[FrameRecord], f, suffix: str, name: str) -> None:
    """Write records in the format the output's suffix names: .geojson/.json, .kml, .kmz, .csv."""
    if suffix in (".geojson", ".json"):
        write_geojson(records, f)
    elif suffix == ".kml":
        f.write(kml(records, name))
    elif suffix == ".kmz":
        write_kmz(records, f, name)
    elif suffix == ".csv":
        write_fmv_csv(records, f)
    else:
        raise ValueError(f"unknown export suffix {suffix!r}")
