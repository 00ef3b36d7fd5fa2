"""Building footprints from GeoParquet (`.parquet`, `.geoparquet`): Overture Maps' buildings
theme as published (a WKB `geometry` column in OGC:CRS84, `height`, `num_floors`,
`min_height`, `min_floor`, `roof_height`, `names`...) or any table of building polygons, as
footprints for LoD1 extrusion (app.scene.city.footprints, OVERTURE_KEYS).

The CRS comes from the file's GeoParquet metadata (geopandas); a Parquet file without it (as
DuckDB writes an Overture extract) is read with pyarrow, its WKB column (`geometry`, `geom` or
`wkb_geometry`) taken as longitude, latitude, and that is said. A row of Overture's
building_part type (it has `building_id`) is a part, drawn inside its building's outline.
Attributes: the row's plain values (text, numbers, flags) and `names.primary` as `name`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import geopandas
import numpy as np
import pyarrow
import pyarrow.parquet as pq
import shapely
from shapely.geometry import MultiPolygon, Polygon

from app.core.errors import SceneError
from app.scene.city.footprints import (
    OVERTURE_KEYS,
    Footprint,
    FootprintReader,
    Ground,
    Keep,
    valid_shape,
)

SUFFIXES = (".parquet", ".geoparquet")
WKB_COLUMNS = ("geometry", "geom", "wkb_geometry")


def is_parquet(location: str | Path) -> bool:
    """A (Geo)Parquet file, by its name."""
    return str(location).lower().endswith(SUFFIXES)


def _plain(value: object) -> bool:
    """A value worth keeping as an attribute: text, a finite number or a flag (Python's)."""
    if isinstance(value, float):
        return math.isfinite(value)
    return isinstance(value, str | int | bool) and value != ""


def _attributes(row: dict) -> dict:
    """A row's plain values (numpy scalars as Python's), with names.primary as `name`."""
    row = {k: v.item() if isinstance(v, np.generic) else v for k, v in row.items()}
    out = {k: v for k, v in row.items() if _plain(v)}
    names = row.get("names")
    if isinstance(names, dict) and _plain(names.get("primary")) and "name" not in out:
        out["name"] = names["primary"]
    return out


class ParquetReader(FootprintReader):
    """GeoParquet building footprints with the reader interface app.scene.city.read uses."""

    format = "GeoParquet"
    keys = OVERTURE_KEYS

    def __init__(self, path: str | Path, ground: Ground) -> None:
        super().__init__(path, ground)

    def _table(self) -> tuple[np.ndarray, list[dict]]:
        """(geometries lon, lat; the other columns, a dict a row). Raises SceneError where the
        file is not Parquet or has no geometry."""
        try:
            frame = geopandas.read_parquet(self.path)
        except (ValueError, KeyError):  # no GeoParquet metadata: a WKB column, lon, lat assumed
            frame = None
        except (OSError, pyarrow.ArrowException) as exc:
            raise SceneError(self.path, f"cannot read it as Parquet ({exc})") from None
        if frame is not None:
            if {"clip", "frame"} <= set(frame.columns):
                raise SceneError(
                    self.path, "an archive of clips (geofuse index), not building footprints"
                )
            self.version = "GeoParquet"
            if frame.crs is not None and not (
                frame.crs.is_geographic
                and frame.crs.equals("OGC:CRS84")
                or frame.crs.to_epsg() == 4326
            ):
                frame = frame.to_crs("OGC:CRS84")
            geoms = np.asarray(frame.geometry.values, dtype=object)
            rows = frame.drop(columns=frame.geometry.name).to_dict("records")
            return geoms, rows
        try:
            table = pq.read_table(self.path)
        except (OSError, pyarrow.ArrowException) as exc:
            raise SceneError(self.path, f"cannot read it as Parquet ({exc})") from None
        column = next((c for c in WKB_COLUMNS if c in table.column_names), None)
        if column is None:
            raise SceneError(
                self.path,
                f"no geometry column (expected GeoParquet metadata or a WKB column named {', '.join(WKB_COLUMNS)})",
            )
        try:
            geoms = shapely.from_wkb(table.column(column).to_numpy(zero_copy_only=False))
        except shapely.errors.GEOSException as exc:
            raise SceneError(self.path, f"column {column!r} is not WKB ({exc})") from None
        self.notes.append(
            f"{self.path.name}: no GeoParquet metadata: its {column!r} column taken as longitude, latitude (OGC:CRS84)"
        )
        self.version = "Parquet"
        return geoms, table.drop_columns([column]).to_pylist()

    def _footprints(self, keep: Keep) -> Iterator[Footprint]:
        geoms, rows = self._table()
        self.count = len(rows)
        bounds = shapely.bounds(geoms)
        for i, (geom, row) in enumerate(zip(geoms, rows, strict=True)):
            fid = str(row.get("id") or f"row {i}")
            if geom is None or not np.isfinite(bounds[i]).all():
                self.faults.add("no area", fid)
                continue
            centre = np.array([bounds[i, 0] + bounds[i, 2], bounds[i, 1] + bounds[i, 3]]) / 2
            if not keep(centre):
                continue
            if not isinstance(geom, Polygon | MultiPolygon):
                self.faults.add("not a polygon", f"{fid} ({geom.geom_type})")
                continue
            geom = shapely.force_2d(geom)
            if (shape := valid_shape(geom, fid, self.faults)) is not None:
                yield Footprint(fid, _attributes(row), shape, "building_id" in row)
