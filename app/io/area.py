"""An area given as a GeoJSON file (`geofuse find --polygon`, `geofuse export ortho --area`): a
Polygon or MultiPolygon in WGS84 longitude/latitude degrees (GeoJSON's axis order), as a bare
geometry, a Feature or a FeatureCollection (its features' polygons taken together).

Refused with a DataFormatError naming the file, the GeoJSON member at fault and what was
expected: text that is not JSON, a feature without geometry, a geometry that is not a polygon (a
Point, a LineString), an empty polygon, coordinates that are not finite (NaN, infinite) or not
degrees, and a polygon that is not valid (a ring that crosses itself).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.errors import ShapelyError
from shapely.geometry import shape
from shapely.geometry.base import BaseGeometry
from shapely.validation import explain_validity

from app.core.errors import DataFormatError

__all__ = ["AREA_TYPES", "non_finite", "read_area"]

AREA_TYPES = ("Polygon", "MultiPolygon")
LATITUDE_DEG = (-90.0, 90.0)
LONGITUDE_DEG = (-180.0, 360.0)  # as the command line's longitudes (app.cli.options.GEODETIC)


def _refused(
    option: str, path: Path, message: str, *, line: int | None = None, field: str | None = None
) -> DataFormatError:
    """The DataFormatError of an area given for `option` (named at the end of the message)."""
    return DataFormatError(path, f"{message} ({option})", line=line, field=field)


def non_finite(geometries: Any) -> np.ndarray:
    """Indices of the geometries (an array-like of shapely geometries) with a coordinate that is
    NaN or infinite, in order, each once."""
    xy, index = shapely.get_coordinates(np.asarray(geometries, dtype=object), return_index=True)
    return np.unique(index[~np.isfinite(xy).all(axis=1)])


def _geometries(path: Path, doc: object, option: str) -> list[tuple[str, dict[str, Any]]]:
    """(member name, GeoJSON geometry object) of each geometry the document holds."""
    if not isinstance(doc, dict):
        raise _refused(option, path, "expected a GeoJSON object, got JSON text of another kind")
    kind = doc.get("type")
    if kind == "FeatureCollection":
        features = doc.get("features")
        if not isinstance(features, list) or not features:
            raise _refused(option, path, "expected a non-empty list of features", field="features")
        named = [(f"features[{i}]", f) for i, f in enumerate(features)]
    elif kind == "Feature":
        named = [("", doc)]
    else:
        return [("", doc)]
    out = []
    for name, feature in named:
        geometry = feature.get("geometry") if isinstance(feature, dict) else None
        where = f"{name}.geometry" if name else "geometry"
        if not isinstance(geometry, dict):
            raise _refused(option, path, "no geometry (expected a Polygon)", field=where)
        out.append((where, geometry))
    return out


def _polygon(path: Path, where: str, geometry: dict[str, Any], option: str) -> BaseGeometry:
    """One GeoJSON geometry object as a checked Polygon or MultiPolygon (degrees)."""
    field = where or "type"
    try:
        with warnings.catch_warnings():  # shapely warns of NaN before it is refused below
            warnings.simplefilter("ignore", RuntimeWarning)
            polygon = shape(geometry)
    except (ShapelyError, ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        raise _refused(
            option, path, f"not a GeoJSON geometry ({exc}); expected a Polygon", field=field
        ) from exc
    if polygon.geom_type not in AREA_TYPES:
        raise _refused(
            option,
            path,
            f"got a {polygon.geom_type}, expected a Polygon or MultiPolygon",
            field=field,
        )
    where = f"{where}.coordinates" if where else "coordinates"
    if polygon.is_empty:
        raise _refused(
            option, path, f"an empty {polygon.geom_type}, expected at least 3 corners", field=where
        )
    if len(non_finite([polygon])):
        raise _refused(
            option,
            path,
            "coordinates that are NaN or infinite, expected longitude, latitude in degrees",
            field=where,
        )
    lon0, lat0, lon1, lat1 = polygon.bounds
    in_range = (
        LATITUDE_DEG[0] <= lat0 <= lat1 <= LATITUDE_DEG[1]
        and LONGITUDE_DEG[0] <= lon0 <= lon1 <= LONGITUDE_DEG[1]
    )
    if not in_range:
        raise _refused(
            option,
            path,
            f"longitudes {lon0:g} to {lon1:g}, latitudes {lat0:g} to {lat1:g}, expected "
            f"longitude, latitude in degrees (GeoJSON's order; latitudes within +-90)",
            field=where,
        )
    if not polygon.is_valid:
        raise _refused(
            option,
            path,
            f"not a valid polygon ({explain_validity(polygon)}), expected rings that do not "
            "cross themselves or each other",
            field=where,
        )
    return polygon


def read_area(path: str | Path, option: str) -> BaseGeometry:
    """The Polygon or MultiPolygon (longitude, latitude degrees) a GeoJSON file gives for the
    command-line option `option` (named in the errors); several features: their union."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise _refused(option, path, f"cannot be read ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise _refused(option, path, f"not UTF-8 text ({exc.reason}), expected GeoJSON") from exc
    except json.JSONDecodeError as exc:
        raise _refused(
            option, path, f"not JSON ({exc.msg}), expected GeoJSON", line=exc.lineno
        ) from exc
    except RecursionError as exc:
        raise _refused(option, path, "JSON nested too deep, expected GeoJSON") from exc
    parts = [_polygon(path, w, g, option) for w, g in _geometries(path, doc, option)]
    return parts[0] if len(parts) == 1 else shapely.union_all(parts)
