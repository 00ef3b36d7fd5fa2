"""Frame records (app.export.records) as GIS layers: GeoJSON (RFC 7946), KML and KMZ (Google
Earth), and the metadata CSV of ArcGIS Pro's Video Multiplexer (Full Motion Video: the MISB
fields, then one column of geofuse's own after them, fmv_row). Pure text;
files are written through app.core.outputs (checked, atomic, never over an input).

Heights: GeoJSON keeps heights above the WGS84 ellipsoid (RFC 7946); KML's `absolute` and MISB's
Sensor True Altitude and Frame Center Elevation are above mean sea level (EGM2008, app.geodesy.geoid);
the ellipsoidal heights sit beside them (`*_ellipsoid_height_m`, Sensor Ellipsoid Height, Frame
Center Height Above Ellipsoid). Times: `utc` from the session's clock (Session.utc_of), null where
none is known.

GeoJSON: the footprints file holds polygons only (one Polygon or MultiPolygon per frame, in plan
view and valid by construction: app.export.footprint), so that it converts to a Shapefile or a
PostGIS table as one layer; beside it `NAME_borders.geojson` (the image border on the scene, a
closed 3D LineString per frame) and `NAME_track.geojson` (the camera track, a LineString). KML:
three folders in one document (footprints clamped to the ground, the 3D borders and the camera
track at `absolute` heights).
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
from shapely.geometry import mapping
from shapely.geometry.base import BaseGeometry

from app.export.footprint import plan_footprint
from app.export.records import FOOTPRINT_MAX_RANGE_M, FrameRecord

FMV_FIELDS = (  # MISB ST 0601 names, as the Video Multiplexer's field mapping template lists them
    "UNIX Time Stamp", "Sensor Latitude", "Sensor Longitude", "Sensor True Altitude", "Sensor Ellipsoid Height",
    "Platform Heading Angle", "Platform Pitch Angle", "Platform Roll Angle",
    "Sensor Relative Azimuth Angle", "Sensor Relative Elevation Angle", "Sensor Relative Roll Angle",
    "Sensor Horizontal Field of View", "Sensor Vertical Field of View", "Slant Range",
    "Frame Center Latitude", "Frame Center Longitude", "Frame Center Elevation", "Frame Center Height Above Ellipsoid",
    "Offset Corner Latitude Point 1", "Offset Corner Longitude Point 1", "Offset Corner Latitude Point 2", "Offset Corner Longitude Point 2",
    "Offset Corner Latitude Point 3", "Offset Corner Longitude Point 3", "Offset Corner Latitude Point 4", "Offset Corner Longitude Point 4",
)  # fmt: skip
FMV_EXTENSIONS = (  # geofuse's own columns, after every MISB one (fmv_row)
    "geofuse GNSS Status",
)
FMV_HEADER = FMV_FIELDS + FMV_EXTENSIONS
COMPANIONS = ("_borders", "_track")  # files written beside a GeoJSON footprints file


def _value(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def iso_utc(unix_s: float | None) -> str | None:
    """ISO 8601 UTC with microseconds, or None."""
    if unix_s is None:
        return None
    return (
        datetime.fromtimestamp(unix_s, UTC)
        .isoformat(timespec="microseconds")
        .replace("+00:00", "Z")
    )


def properties(r: FrameRecord) -> dict[str, object]:
    """The fields of one frame, named with their units and datums."""
    return {
        "clip": r.clip,
        "frame": r.index,
        "gnss": r.gnss,
        "time_s": round(r.session_s, 6),
        "media_time_s": round(r.media_s, 6),
        "utc": iso_utc(r.utc_s),
        "sensor_latitude": r.sensor[0],
        "sensor_longitude": r.sensor[1],
        "sensor_ellipsoid_height_m": r.sensor[2],
        "sensor_msl_height_m": r.sensor_msl_m,
        "heading_deg": r.hpr[0],
        "pitch_deg": r.hpr[1],
        "roll_deg": r.hpr[2],
        "hfov_deg": r.hfov_deg,
        "vfov_deg": r.vfov_deg,
        "centre_latitude": _value(r.centre[0]),
        "centre_longitude": _value(r.centre[1]),
        "centre_ellipsoid_height_m": _value(r.centre[2]),
        "centre_msl_height_m": _value(r.centre_msl_m),
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


def _geometry(geometry: BaseGeometry | None) -> dict | None:
    """A footprint (already on app.export.footprint's 1e-9 degree grid) as GeoJSON, or None."""
    return None if geometry is None else mapping(geometry)


def footprints_geojson(records: Iterable[FrameRecord]) -> dict:
    """A FeatureCollection of polygons only: each frame's plan-view footprint (valid by
    construction; null where the frame sees no ground), its fields as properties."""
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": _geometry(plan_footprint(r.ground)),
                "properties": properties(r),
            }
            for r in records
        ],
    }


def borders_geojson(records: Iterable[FrameRecord]) -> dict:
    """The image border on the scene per frame: a closed LineString of [lon, lat, ellipsoidal h]."""
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "geometry": {
                    "type": "LineString",
                    "coordinates": np.round(counter_clockwise_ring(r.footprint), 9).tolist(),
                },
                "properties": {
                    "frame": r.index,
                    "time_s": round(r.session_s, 6),
                    "utc": iso_utc(r.utc_s),
                },
            }
            for r in records
        ],
    }


def _tracks(records: Iterable[FrameRecord]) -> list[tuple[str, list[FrameRecord]]]:
    """The records by clip, in the order the clips come."""
    out: dict[str, list[FrameRecord]] = {}
    for r in records:
        out.setdefault(r.clip, []).append(r)
    return list(out.items())


def track_geojson(records: Iterable[FrameRecord]) -> dict:
    """The camera tracks: a LineString of [lon, lat, ellipsoidal h] per clip (of two frames or
    more)."""
    features = []
    for clip, rs in _tracks(records):
        if len(rs) >= 2:
            points = [[r.sensor[1], r.sensor[0], r.sensor[2]] for r in rs]
            features.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "LineString", "coordinates": np.round(points, 9).tolist()},
                    "properties": {"name": "camera track", "clip": clip, "frames": len(rs)},
                }
            )
    return {"type": "FeatureCollection", "features": features}


def companion(out: Path, which: str) -> Path:
    """The file written beside a GeoJSON footprints file: NAME_borders.geojson, NAME_track.geojson."""
    return out.with_name(f"{out.stem}{which}{out.suffix}")


def _coords(points: np.ndarray) -> str:
    return " ".join(f"{lon:.9f},{lat:.9f},{h:.3f}" for lon, lat, h in points)


def _kml_polygon(polygon) -> str:
    def ring(r) -> str:
        return (
            "<LinearRing><coordinates>"
            + " ".join(f"{x:.9f},{y:.9f}" for x, y in np.asarray(r.coords)[:, :2])
            + "</coordinates></LinearRing>"
        )

    inner = "".join(f"<innerBoundaryIs>{ring(r)}</innerBoundaryIs>" for r in polygon.interiors)
    return f"<Polygon><tessellate>1</tessellate><altitudeMode>clampToGround</altitudeMode><outerBoundaryIs>{ring(polygon.exterior)}</outerBoundaryIs>{inner}</Polygon>"


def kml(records: Iterable[FrameRecord], name: str) -> str:
    """A KML document in three folders: the plan-view footprints (clamped to the ground, the
    frame's fields as ExtendedData), the image borders on the scene and the camera track (both
    `absolute`: heights above mean sea level, EGM2008)."""
    records = list(records)
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>',
        f"<name>{escape(name)}</name>",
        '<Style id="footprint"><LineStyle><color>ff00a5ff</color><width>2</width></LineStyle><PolyStyle><color>4000a5ff</color></PolyStyle></Style>',
        "<Folder><name>footprints</name>",
    ]
    for r in records:
        shape = plan_footprint(r.ground)
        if shape is None:
            continue
        parts = [shape] if shape.geom_type == "Polygon" else list(shape.geoms)
        geometry = "".join(_kml_polygon(p) for p in parts)
        if len(parts) > 1:
            geometry = f"<MultiGeometry>{geometry}</MultiGeometry>"
        data = "".join(
            f'<Data name="{k}"><value>{"" if v is None else escape(str(v))}</value></Data>'
            for k, v in properties(r).items()
        )
        out.append(
            f"<Placemark><name>frame {r.index}</name><styleUrl>#footprint</styleUrl><ExtendedData>{data}</ExtendedData>{geometry}</Placemark>"
        )
    out.append("</Folder><Folder><name>footprint borders (3D)</name>")
    for r in records:
        ring = counter_clockwise_ring(r.footprint_msl)
        out.append(
            f"<Placemark><name>frame {r.index}</name><styleUrl>#footprint</styleUrl><LineString><altitudeMode>absolute</altitudeMode><coordinates>{_coords(ring)}</coordinates></LineString></Placemark>"
        )
    out.append("</Folder><Folder><name>camera track</name>")
    for clip, rs in _tracks(records):
        if len(rs) >= 2:
            track = np.array([[r.sensor[1], r.sensor[0], r.sensor_msl_m] for r in rs])
            out.append(
                f"<Placemark><name>{escape(clip or 'camera track')}</name><LineString><altitudeMode>absolute</altitudeMode><coordinates>{_coords(track)}</coordinates></LineString></Placemark>"
            )
    out.append("</Folder></Document></kml>")
    return "\n".join(out)


def write_kmz(records: Iterable[FrameRecord], f, name: str) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", kml(records, name))
    f.write(buf.getvalue())


def fmv_row(r: FrameRecord) -> list[str]:
    """One row of the Video Multiplexer CSV: time in integer microseconds since the Unix epoch
    (UTC; the session clock where none is known); the camera is the platform (heading only: the
    sensor's elevation and roll carry the pitch and roll, as a gimbal's would); altitudes above
    mean sea level with the ellipsoid heights beside them; corners as offsets from the frame
    centre in degrees (empty where the centre or the corner meets nothing). Then geofuse's own
    columns (FMV_EXTENSIONS): `geofuse GNSS Status`, what posed the frame (used, rejected,
    missing: app.camera.fixes; empty where the track stands on no GNSS). It comes last and under
    a heading no MISB template lists, so that the fixed schema does not move: the Video
    Multiplexer maps columns by their headings (in any order) to its field mapping template's
    names and maps this one to nothing, readers by heading (csv.DictReader, pandas) find every
    MISB field as before, and readers by position find the 26 MISB fields in the first 26
    columns, in the same order."""
    t = r.utc_s if r.utc_s is not None else r.session_s
    h, p, roll = r.hpr
    c = r.corners
    cells = [
        int(round(t * 1e6)),
        r.sensor[0],
        r.sensor[1],
        r.sensor_msl_m,
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
        r.centre[0],
        r.centre[1],
        r.centre_msl_m,
        r.centre[2],
    ]
    cells += [v for k in range(4) for v in (c[k, 0] - r.centre[0], c[k, 1] - r.centre[1])]
    misb = [str(cells[0])] + [
        "" if not math.isfinite(v) else f"{v:.9f}" if abs(v) <= 360 else f"{v:.3f}"
        for v in cells[1:]
    ]
    return misb + ["" if r.gnss is None else r.gnss]


def write_fmv_csv(records: Iterable[FrameRecord], f) -> None:
    """The Video Multiplexer CSV: FMV_HEADER, then one fmv_row per record."""
    w = csv.writer(f)
    w.writerow(FMV_HEADER)
    for r in records:
        w.writerow(fmv_row(r))


def write_records(records: Iterable[FrameRecord], f, suffix: str, name: str) -> None:
    """Write records in the format the output's suffix names: .geojson/.json (the footprints;
    the borders and track go to their own files: footprints_geojson's companions), .kml, .kmz,
    .csv."""
    if suffix in (".geojson", ".json"):
        json.dump(footprints_geojson(records), f, allow_nan=False)
    elif suffix == ".kml":
        f.write(kml(records, name))
    elif suffix == ".kmz":
        write_kmz(records, f, name)
    elif suffix == ".csv":
        write_fmv_csv(records, f)
