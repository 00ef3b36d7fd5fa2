"""Which clips saw a place, and when: the footprints of an archive that hold a point (within a
radius) or meet a polygon, as time spans per clip, the most head-on view first.

A span is a run of a clip's footprints that hold the place, no more than SPAN_GAP footprint
spacings apart. Head-on: the angle between the camera's optical axis and the direction from the
camera to the place (0: at the image's centre); a span is ranked by its smallest, then by the
distance. The query reads only the row groups whose bounding boxes meet the place (the GeoParquet
covering bbox), then tests the footprints themselves (a spatial index).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import shapely
from shapely.geometry.base import BaseGeometry

from app.archive.store import read_footprints
from app.core.errors import GeofuseError
from app.geodesy.enu import METRES_PER_DEGREE, ecef_to_enu_rotation, geodetic_to_ecef

__all__ = ["Hit", "find", "place_of"]

NEEDED = (
    "clip",
    "frame",
    "clip_s",
    "utc",
    "sensor_lat",
    "sensor_lon",
    "sensor_h",
    "axis_e",
    "axis_n",
    "axis_u",
    "centre_h",
)
SPAN_GAP = 2.5  # footprint spacings between two rows of one span, at most


@dataclass(frozen=True)
class Hit:
    """A clip's time span over the place: clip (its path), start_s, end_s (clip seconds),
    start_utc, end_utc (None without a clock), frame (the most head-on frame) and its angle off
    the optical axis (deg) and distance (m), footprints (rows in the span)."""

    clip: str
    start_s: float
    end_s: float
    start_utc: datetime | None
    end_utc: datetime | None
    frame: int
    frame_s: float
    off_axis_deg: float
    distance_m: float
    footprints: int

    def as_dict(self) -> dict[str, object]:
        def iso(t: datetime | None) -> str | None:
            return None if t is None else t.isoformat().replace("+00:00", "Z")

        return {
            "clip": self.clip,
            "start_utc": iso(self.start_utc),
            "end_utc": iso(self.end_utc),
            "start_s": round(self.start_s, 3),
            "end_s": round(self.end_s, 3),
            "frame": self.frame,
            "frame_s": round(self.frame_s, 3),
            "off_axis_deg": round(self.off_axis_deg, 2),
            "distance_m": round(self.distance_m, 1),
        }

    def line(self) -> str:
        when = (
            f"{self.start_utc:%Y-%m-%d %H:%M:%S}-{self.end_utc:%H:%M:%S} UTC, "
            if self.start_utc is not None and self.end_utc is not None
            else ""
        )
        return (
            f"{self.clip}: {when}{self.start_s:.1f}-{self.end_s:.1f} s of the clip; best at "
            f"{self.frame_s:.1f} s ({self.off_axis_deg:.0f} deg off the axis, {self.distance_m:.0f} m)"
        )


def place_of(
    point: tuple[float, float] | None = None,
    radius_m: float = 0.0,
    polygon: BaseGeometry | None = None,
) -> BaseGeometry:
    """The place asked about, in longitude/latitude degrees: a point (lat, lon) grown by
    radius_m (a circle in metres), or a polygon."""
    if polygon is not None:
        return polygon
    lat, lon = point
    p = shapely.Point(lon, lat)
    if radius_m <= 0:
        return p
    circle = shapely.Point(0.0, 0.0).buffer(radius_m, 32)
    k = np.array([METRES_PER_DEGREE * math.cos(math.radians(lat)), METRES_PER_DEGREE])
    return shapely.transform(circle, lambda xy: xy / k + [lon, lat])


def _off_axis(
    rows: pd.DataFrame, lat: float, lon: float, h: float
) -> tuple[np.ndarray, np.ndarray]:
    """(angle off each row's optical axis (deg), distance (m)) of the place from each camera."""
    cam = geodetic_to_ecef(
        rows["sensor_lat"].to_numpy(), rows["sensor_lon"].to_numpy(), rows["sensor_h"].to_numpy()
    )
    target = np.asarray(geodetic_to_ecef(lat, lon, h))
    d_ecef = target - np.atleast_2d(cam)
    distance = np.linalg.norm(d_ecef, axis=1)
    # the axis in ENU at each camera -> ECEF (the transposed rotation)
    to_enu = ecef_to_enu_rotation(rows["sensor_lat"].to_numpy(), rows["sensor_lon"].to_numpy())
    axis_enu = rows[["axis_e", "axis_n", "axis_u"]].to_numpy()
    axis = np.einsum("nji,nj->ni", to_enu, axis_enu)
    cos = np.einsum("ij,ij->i", axis, d_ecef) / np.maximum(distance, 1e-9)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), distance


def find(
    archive: Path,
    place: BaseGeometry,
    start: datetime | None = None,
    end: datetime | None = None,
    height_m: float | None = None,
) -> list[Hit]:
    """The spans in which the place lies inside (or meets) a footprint, between start and end
    (UTC; rows without a clock are left out when either is given), most head-on first.
    height_m: the place's ellipsoidal height for the ranking (default: the median height at
    which these footprints' optical axes meet the scene, else the cameras' less 2 m)."""
    minx, miny, maxx, maxy = place.bounds
    try:
        rows = read_footprints(archive, (minx, miny, maxx, maxy))
        rows[list(NEEDED)]  # noqa: B018 - the columns the query reads
    except (OSError, ValueError, KeyError) as exc:
        raise GeofuseError(f"{archive}: not an archive written by `geofuse index` ({exc})") from exc
    if len(rows):
        rows = rows.iloc[rows.sindex.query(place, predicate="intersects")]
    if start is not None:
        rows = rows[rows["utc"].notna() & (rows["utc"] >= pd.Timestamp(start))]
    if end is not None:
        rows = rows[rows["utc"].notna() & (rows["utc"] <= pd.Timestamp(end))]
    if not len(rows):
        return []
    c = place.centroid
    if height_m is None:
        centre = rows["centre_h"].to_numpy(dtype=float)
        finite = centre[np.isfinite(centre)]
        height_m = (
            float(np.median(finite)) if len(finite) else float(rows["sensor_h"].median()) - 2.0
        )
    h = height_m
    angle, distance = _off_axis(rows, c.y, c.x, h)
    rows = rows.assign(off_axis=angle, distance=distance).sort_values(["clip", "clip_s"])
    hits = []
    for clip, group in rows.groupby("clip", sort=False):
        t = group["clip_s"].to_numpy()
        spacing = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
        breaks = np.flatnonzero(np.diff(t) > SPAN_GAP * spacing) + 1
        for part in np.split(np.arange(len(group)), breaks):
            g = group.iloc[part]
            best = g.iloc[int(np.lexsort((g["distance"].to_numpy(), g["off_axis"].to_numpy()))[0])]
            utc = g["utc"]
            hits.append(
                Hit(
                    str(clip),
                    float(g["clip_s"].iloc[0]),
                    float(g["clip_s"].iloc[-1]),
                    None if utc.isna().all() else utc.min().to_pydatetime(),
                    None if utc.isna().all() else utc.max().to_pydatetime(),
                    int(best["frame"]),
                    float(best["clip_s"]),
                    float(best["off_axis"]),
                    float(best["distance"]),
                    len(g),
                )
            )
    return sorted(hits, key=lambda hit: (hit.off_axis_deg, hit.distance_m))
