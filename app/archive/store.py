"""The archive on disk: GeoParquet written by geopandas (pyarrow).

`ARCHIVE.parquet`: one row per footprint, geometry the plan-view footprint (a valid Polygon or
MultiPolygon, WGS84 longitude/latitude, EPSG:4326, GeoParquet metadata: geopandas, GDAL and
DuckDB spatial read it), with the clip's path, the frame, its clip time (s) and UTC time (null
where the clip has no clock), the sensor's position (lat, lon deg, ellipsoidal h m), heading,
pitch, roll (deg), its optical axis (ENU unit vector, for ranking views), horizontal field of
view, and the ellipsoidal height where the optical axis meets the scene (NaN above the horizon). `ARCHIVE.clips.parquet` beside it: one row per clip with its status (indexed, failed,
duplicate), error, size, modification time, fingerprint and facts.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import geopandas as gpd
import pandas as pd
from shapely import wkb
from shapely.errors import ShapelyError

from app.archive.clips import ClipResult
from app.core.errors import DataFormatError
from app.io.area import non_finite

__all__ = ["clips_path", "read_clips", "read_footprints", "write_archive"]

CRS = "EPSG:4326"
ROW_GROUP_ROWS = 50_000  # a query reads only the row groups whose bounding boxes meet its place
FOOTPRINT_COLUMNS = (
    "clip", "frame", "clip_s", "utc", "sensor_lat", "sensor_lon", "sensor_h", "heading_deg",
    "pitch_deg", "roll_deg", "axis_e", "axis_n", "axis_u", "hfov_deg", "centre_h",
)  # fmt: skip
CLIP_COLUMNS = (
    "path", "status", "error", "size", "mtime_ns", "fingerprint", "camera", "lens", "source",
    "duration_s", "utc_start", "track_length_m", "footprints", "messages", "seconds",
    "worker_peak_mb",
)  # fmt: skip
KEY_COLUMNS = CLIP_COLUMNS[:6]  # what an incremental run compares: an older table holds these


def clips_path(archive: Path) -> Path:
    """The clips table beside the footprints: ARCHIVE.clips.parquet."""
    return archive.with_name(f"{archive.stem}.clips.parquet")


def read_footprints(
    archive: Path, bbox: tuple[float, float, float, float] | None = None
) -> gpd.GeoDataFrame:
    """The footprints of an archive, only those whose boxes meet bbox (longitude, latitude
    degrees: west, south, east, north) where given. DataFormatError naming the archive and its
    geometry column where a geometry is not WKB or has a coordinate that is NaN or infinite;
    OSError, ValueError (pyarrow) or KeyError where the file is no GeoParquet."""
    try:
        with warnings.catch_warnings():  # shapely warns before it raises on bytes not WKB
            warnings.simplefilter("ignore", RuntimeWarning)
            rows = gpd.read_parquet(archive, bbox=bbox)
    except ShapelyError as exc:
        raise DataFormatError(
            archive, f"bytes that are not WKB ({exc}), expected WKB polygons", field="geometry"
        ) from exc
    bad = non_finite(rows.geometry.values)
    if len(bad):
        first = rows.iloc[int(bad[0])]
        raise DataFormatError(
            archive,
            f"{len(bad)} footprint(s) with NaN or infinite coordinates (the first: "
            f"{first.get('clip', '?')} frame {first.get('frame', '?')}), expected longitude, "
            "latitude in degrees",
            field="geometry",
        )
    return rows


def read_clips(archive: Path) -> pd.DataFrame:
    """The clips table beside the archive (empty where there is none). DataFormatError naming
    it where it is not one `geofuse index` wrote (not Parquet, or a column missing)."""
    path = clips_path(archive)
    if not path.is_file():
        return pd.DataFrame(columns=list(CLIP_COLUMNS))
    try:
        clips = pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise DataFormatError(
            path, f"not Parquet ({exc}), expected the clips table of an archive"
        ) from exc
    missing = [c for c in KEY_COLUMNS if c not in clips.columns]
    if missing:
        raise DataFormatError(
            path,
            f"no column {missing[0]!r}, expected the clips table `geofuse index` writes",
            field=missing[0],
        )
    return clips


def _footprints(results: list[ClipResult]) -> gpd.GeoDataFrame:
    rows = [r for res in results for r in res.rows if r["geometry"] is not None]
    frame = pd.DataFrame(rows, columns=[*FOOTPRINT_COLUMNS, "geometry"])
    frame["utc"] = pd.to_datetime(frame["utc"], utc=True)
    geometry = gpd.GeoSeries([wkb.loads(g) for g in frame.pop("geometry")], crs=CRS)
    return gpd.GeoDataFrame(frame, geometry=geometry, crs=CRS)


def _clips(results: list[ClipResult]) -> pd.DataFrame:
    rows = []
    for r in results:
        facts = {k: r.facts.get(k) for k in CLIP_COLUMNS}
        facts.update(
            path=r.path,
            status=r.status,
            error=r.error,
            size=r.size,
            mtime_ns=r.mtime_ns,
            fingerprint=r.fingerprint,
            seconds=r.seconds,
            worker_peak_mb=r.worker_peak_mb,
        )
        rows.append(facts)
    out = pd.DataFrame(rows, columns=list(CLIP_COLUMNS))
    out["utc_start"] = pd.to_datetime(out["utc_start"], utc=True)
    return out


def write_archive(
    archive: Path, results: list[ClipResult], kept: list[str] | None = None
) -> tuple[int, int]:
    """Write the archive: the new results, and the rows of the clips in `kept` (paths indexed
    before and unchanged) from the archive already there. Written to temporary files beside and
    renamed. Returns (footprints, clips) written."""
    footprints = _footprints(results)
    clips = _clips(results)
    if kept and archive.is_file():
        try:
            old = read_footprints(archive)
        except (OSError, ValueError, KeyError) as exc:
            raise DataFormatError(
                archive, f"not GeoParquet ({exc}), expected an archive `geofuse index` wrote"
            ) from exc
        old_clips = read_clips(archive)
        footprints = pd.concat([old[old["clip"].isin(kept)], footprints], ignore_index=True)
        clips = pd.concat([old_clips[old_clips["path"].isin(kept)], clips], ignore_index=True)
    footprints = gpd.GeoDataFrame(footprints, geometry="geometry", crs=CRS)
    tmp = archive.with_name(f".{archive.name}.tmp")
    tmp_clips = archive.with_name(f".{clips_path(archive).name}.tmp")
    footprints.to_parquet(
        tmp,
        index=False,
        schema_version="1.1.0",
        write_covering_bbox=True,
        row_group_size=ROW_GROUP_ROWS,
    )
    clips.to_parquet(tmp_clips, index=False)
    tmp.replace(archive)
    tmp_clips.replace(clips_path(archive))
    return len(footprints), len(clips)
