"""Measurements and marks on the scene: what a person picks on the draped video or the model.

A measurement is a list of picked points (ENU metres in the session's local frame): the straight
distance along them (3D), the distance along the ground (the same path seen from above), the
height difference from the first to the last, and for three or more points the area of the
polygon they enclose seen from above (shoelace, square metres; the local frame is a tangent
plane, exact enough for a site).

A mark is a measurement kept: a point, a line or a polygon with a label, the clip and the video
frame (index and media seconds) it was taken from. Marks are kept beside the input (never in
it): `NAME.marks.geojson` next to `NAME.toml` or `NAME.MP4`, and exported as GeoJSON (RFC 7946,
heights above the ellipsoid) or KML (heights above sea level, EGM2008). A polygon is written
valid as a simple feature: counter-clockwise, closed, and repaired by GEOS where its outline
crosses itself (as clicked), which can make it a MultiPolygon; one drawn on a wall (no area seen
from above) is written as drawn, its 3D ring.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO
from xml.sax.saxutils import escape

import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry import mapping

from app.core.errors import DataFormatError
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation

__all__ = [
    "KINDS",
    "Mark",
    "Measure",
    "marks_geojson",
    "marks_kml",
    "marks_path",
    "measure",
    "read_marks",
]

KINDS = ("point", "line", "polygon")
MIN_POINTS = {"point": 1, "line": 2, "polygon": 3}


@dataclass(frozen=True)
class Measure:
    """straight_m: along the points in 3D; ground_m: the same path seen from above; height_m:
    the last point's height minus the first's; area_m2: of the polygon seen from above (None
    below three points)."""

    straight_m: float
    ground_m: float
    height_m: float
    area_m2: float | None

    def line(self) -> str:
        area = "" if self.area_m2 is None else f", area {self.area_m2:.1f} m2"
        return (
            f"{self.straight_m:.2f} m straight, {self.ground_m:.2f} m along the ground, "
            f"height difference {self.height_m:+.2f} m{area}"
        )


def measure(points_enu: npt.ArrayLike) -> Measure:
    """What the points (N, 3) ENU m measure (see the module docstring)."""
    p = np.asarray(points_enu, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return Measure(0.0, 0.0, 0.0, None)
    steps = np.diff(p, axis=0)
    straight = float(np.linalg.norm(steps, axis=1).sum())
    ground = float(np.linalg.norm(steps[:, :2], axis=1).sum())
    area = None
    if len(p) >= 3:
        x, y = p[:, 0] - p[0, 0], p[:, 1] - p[0, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))
    return Measure(straight, ground, float(p[-1, 2] - p[0, 2]), area)


@dataclass(frozen=True)
class Mark:
    """A kept point, line or polygon: kind (KINDS), label, clip (the file it was taken from),
    frame (video frame index) and media_s (its time, s from the first frame), points (N, 3)
    ENU m in the session's frame; city_object: the city object every point lies on
    (app.scene.city.model.Feature.as_dict: layer, id, type, surface, parent, attributes), None
    off city models."""

    kind: str
    label: str
    clip: str
    frame: int
    media_s: float
    points: np.ndarray = field(repr=False)
    city_object: dict | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"a mark is a point, a line or a polygon, not {self.kind!r}")
        if len(self.points) < MIN_POINTS[self.kind]:
            raise ValueError(
                f"a {self.kind} needs {MIN_POINTS[self.kind]} points or more, got {len(self.points)}"
            )

    def geometry(self, frame: LocalFrame) -> dict:
        """GeoJSON geometry (lon, lat, ellipsoidal h), a polygon valid by GEOS."""
        geo = frame.enu_to_geodetic(np.asarray(self.points, np.float64))
        lon_lat_h = np.column_stack([geo[:, 1], geo[:, 0], geo[:, 2]])
        if self.kind == "point":
            return {"type": "Point", "coordinates": lon_lat_h[0].tolist()}
        if self.kind == "line":
            return {"type": "LineString", "coordinates": lon_lat_h.tolist()}
        polygon = shapely.Polygon(lon_lat_h)
        if not polygon.is_valid:
            repaired = shapely.make_valid(polygon)
            parts = [g for g in shapely.get_parts(repaired) if g.geom_type == "Polygon"]
            if not parts:  # no area seen from above (drawn on a wall): the ring as drawn
                return {
                    "type": "Polygon",
                    "coordinates": [lon_lat_h.tolist() + [lon_lat_h[0].tolist()]],
                }
            polygon = parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
        return mapping(shapely.orient_polygons(polygon, exterior_cw=False))

    def properties(self) -> dict[str, object]:
        m = measure(self.points)
        return {
            "label": self.label,
            "kind": self.kind,
            "clip": self.clip,
            "frame": self.frame,
            "media_time_s": round(self.media_s, 6),
            "length_m": round(m.straight_m, 3) if self.kind != "point" else None,
            "ground_length_m": round(m.ground_m, 3) if self.kind != "point" else None,
            "area_m2": round(m.area_m2, 3) if self.kind == "polygon" else None,
            **_object_properties(self.city_object),
        }


OBJECT_KEYS = ("layer", "id", "type", "surface", "parent")


def _object_properties(city_object: dict | None) -> dict[str, object]:
    """A city object as flat properties (object_id, object_surface...; GIS tables are flat) and
    its attributes as one JSON text (object_attributes)."""
    if city_object is None:
        return {}
    out: dict[str, object] = {f"object_{k}": city_object.get(k) for k in OBJECT_KEYS}
    out["object_attributes"] = json.dumps(city_object.get("attributes") or {}, default=str)
    return out


def _object_of(props: dict) -> dict | None:
    """The city object back from a mark's properties (None when it has none)."""
    if props.get("object_id") is None:
        return None
    out = {k: props.get(f"object_{k}") for k in OBJECT_KEYS}
    out["attributes"] = json.loads(props.get("object_attributes") or "{}")
    return out


def marks_path(input_path: str | Path) -> Path:
    """Where a session's or clip's marks are kept: NAME.marks.geojson beside it."""
    p = Path(input_path)
    return p.with_name(f"{p.stem}.marks.geojson")


def marks_geojson(marks: list[Mark], frame: LocalFrame) -> dict:
    """A FeatureCollection of the marks (RFC 7946), with the local frame's origin kept in a
    foreign member so that the file reads back into the same ENU points."""
    return {
        "type": "FeatureCollection",
        "geofuse_origin": [frame.lat_deg, frame.lon_deg, frame.h_m],
        "features": [
            {"type": "Feature", "geometry": m.geometry(frame), "properties": m.properties()}
            for m in marks
        ],
    }


def marks_kml(marks: list[Mark], frame: LocalFrame, name: str) -> str:
    """A KML document, one Placemark per mark at `absolute` heights (above sea level)."""
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>',
        f"<name>{escape(name)}</name>",
    ]
    for m in marks:
        geo = frame.enu_to_geodetic(np.asarray(m.points, np.float64))
        msl = geo[:, 2] - undulation(geo[:, 0], geo[:, 1])
        pts = np.column_stack([geo[:, 1], geo[:, 0], msl])
        if m.kind == "polygon":
            pts = np.vstack([pts, pts[:1]])
        coords = " ".join(f"{lon:.9f},{lat:.9f},{h:.3f}" for lon, lat, h in pts)
        body = {
            "point": f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{coords}</coordinates></Point>",
            "line": f"<LineString><altitudeMode>absolute</altitudeMode><coordinates>{coords}</coordinates></LineString>",
            "polygon": f"<Polygon><altitudeMode>absolute</altitudeMode><outerBoundaryIs><LinearRing><coordinates>{coords}</coordinates></LinearRing></outerBoundaryIs></Polygon>",
        }[m.kind]
        data = "".join(
            f'<Data name="{k}"><value>{"" if v is None else escape(str(v))}</value></Data>'
            for k, v in m.properties().items()
        )
        out.append(
            f"<Placemark><name>{escape(m.label)}</name><ExtendedData>{data}</ExtendedData>{body}</Placemark>"
        )
    out.append("</Document></kml>")
    return "\n".join(out)


def write_marks(marks: list[Mark], frame: LocalFrame, f: IO[str], suffix: str, name: str) -> None:
    """The marks as GeoJSON (.geojson, .json) or KML (.kml)."""
    if suffix == ".kml":
        f.write(marks_kml(marks, frame, name))
    else:
        json.dump(marks_geojson(marks, frame), f, allow_nan=False)


MAX_FRAME = 2**31 - 1  # a frame index above this is no video's (it overflows int32 indices)


def _positions(kind: str, geometry: object) -> npt.NDArray[np.float64]:
    """(N, 3) longitude, latitude (deg), ellipsoidal height (m) of a mark's geometry as
    marks_geojson writes it (a polygon's ring without its closing point); ValueError saying what
    is wrong: not numbers, not [lon, lat, h] positions, not finite, or off the globe."""
    if not isinstance(geometry, dict):
        raise ValueError("the geometry is not an object (expected a GeoJSON geometry)")
    coords = geometry.get("coordinates")
    if kind == "point":
        coords = [coords]
    elif kind == "polygon":
        try:
            ring = coords[0] if geometry.get("type") == "Polygon" else coords[0][0]
            coords = ring[:-1]
        except (IndexError, KeyError, TypeError):
            raise ValueError(
                "the polygon has no outer ring (expected [[[lon, lat, h], ...]])"
            ) from None
    try:
        lon_lat_h = np.asarray(coords)  # numbers only make a numeric array: "14.5" does not
    except ValueError:  # ragged
        lon_lat_h = np.zeros(0)
    if lon_lat_h.dtype.kind not in "iuf":
        raise ValueError("coordinates that are not numbers (expected [lon, lat, h] positions)")
    lon_lat_h = lon_lat_h.astype(np.float64)
    if lon_lat_h.ndim != 2 or lon_lat_h.shape[1] != 3:
        raise ValueError(f"the {kind}'s coordinates are not [lon, lat, h] positions")
    if not np.isfinite(lon_lat_h).all():
        raise ValueError("coordinates that are not finite numbers (NaN or infinite)")
    if (np.abs(lon_lat_h[:, 0]) > 180).any() or (np.abs(lon_lat_h[:, 1]) > 90).any():
        raise ValueError("longitude beyond [-180, 180] or latitude beyond [-90, 90] degrees")
    return lon_lat_h


def _mark(feature: object, frame: LocalFrame) -> Mark:
    """One feature of a marks file as a Mark in `frame`'s ENU; ValueError saying what is wrong."""
    if not isinstance(feature, dict) or not isinstance(feature.get("properties"), dict):
        raise ValueError("not a GeoJSON Feature with properties")
    props = feature["properties"]
    kind = props.get("kind")
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} (expected one of {', '.join(KINDS)})")
    lon_lat_h = _positions(kind, feature.get("geometry"))
    index = props.get("frame")
    if (
        not isinstance(index, int | float)
        or isinstance(index, bool)
        or not 0 <= index <= MAX_FRAME
        or index != int(index)
    ):
        raise ValueError(f"frame {index!r} (expected a video frame index, 0 to {MAX_FRAME})")
    media_s = props.get("media_time_s")
    if not isinstance(media_s, int | float) or isinstance(media_s, bool) or not media_s >= 0:
        raise ValueError(f"media_time_s {media_s!r} (expected seconds from the first frame, >= 0)")
    if not np.isfinite(media_s):
        raise ValueError(f"media_time_s {media_s!r} is not finite")
    enu = frame.geodetic_to_enu(lon_lat_h[:, 1], lon_lat_h[:, 0], lon_lat_h[:, 2])
    try:
        city_object = _object_of(props)
    except (TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"object_attributes: {exc} (expected a JSON object text)") from None
    return Mark(
        kind,
        str(props.get("label", "")),
        str(props.get("clip", "")),
        int(index),
        float(media_s),
        enu,
        city_object,
    )


def read_marks(
    path: str | Path,
    frame: LocalFrame,
    skip: Callable[[DataFormatError], None] | None = None,
) -> list[Mark]:
    """Marks kept beside an input, back in `frame`'s ENU. A file that is not a marks GeoJSON
    (not JSON, not UTF-8, no `features` list) raises DataFormatError naming the file; a feature
    that is no mark (NaN or off-globe coordinates, a frame that is no index, a kind unknown)
    raises one naming the file and `features[i]`, or, given `skip`, is handed to it and left
    out (the others read)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(path, f"not a marks file ({exc})") from exc
    if not isinstance(doc, dict):
        raise DataFormatError(
            path, f"a JSON {type(doc).__name__} (expected a GeoJSON FeatureCollection object)"
        )
    features = doc.get("features", [])
    if not isinstance(features, list):
        raise DataFormatError(
            path,
            f"a {type(features).__name__} (expected a list of GeoJSON Features)",
            field="features",
        )
    out = []
    for i, feature in enumerate(features):
        try:
            out.append(_mark(feature, frame))
        except ValueError as exc:
            label = (
                feature.get("properties", {}).get("label") if isinstance(feature, dict) else None
            )
            named = f" ({label!r})" if isinstance(label, str) and label else ""
            error = DataFormatError(path, f"not a mark{named}: {exc}", field=f"features[{i}]")
            if skip is None:
                raise error from exc
            skip(error)
    return out
