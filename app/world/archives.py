"""Local tile archives, read and written: MBTiles (sqlite, Web Mercator, TMS rows), PMTiles v3
(one file of Hilbert-ordered tiles, Web Mercator XYZ; the `pmtiles` package's reader and
writer) and GeoPackage tiles (sqlite; any CRS, its pyramid in gpkg_tile_matrix_set and
gpkg_tile_matrix, rows from the top).

Readers answer raw tile bytes (None: no such tile) and are safe to share between threads;
ArchiveError says why an archive cannot be used (no file name in it: the caller names the
source). Writers take (z, x, y, bytes) in the archive's own addressing: XYZ rows for MBTiles and
PMTiles, a grid's level, column and row (from the top) for GeoPackage.
"""

from __future__ import annotations

import gzip
import math
import mmap
import sqlite3
import threading
from collections.abc import Iterable
from pathlib import Path

from pmtiles.reader import Reader as PMTilesReader
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer as PMTilesWriter

from app.world import tiles as tm
from app.world.grids import Matrix, TileGrid, crs_of
from app.world.sources import split_options

RASTER_TILE_TYPES = (TileType.PNG, TileType.JPEG, TileType.WEBP, TileType.AVIF)
TILE_TYPE_OF = {"png": TileType.PNG, "jpg": TileType.JPEG, "jpeg": TileType.JPEG}


class ArchiveError(ValueError):
    """An archive that cannot be read as tiles (its text says what is wrong)."""


def _open_sqlite(path: Path) -> sqlite3.Connection:
    if not path.is_file():
        raise ArchiveError("no such file")
    uri = path.resolve().as_uri() + "?mode=ro"
    return sqlite3.connect(uri, uri=True, check_same_thread=False)


def mbtiles_max_zoom(path: Path) -> int | None:
    """The finest zoom an MBTiles file holds (its metadata's maxzoom, else its tiles'), None
    when it cannot be read."""
    try:
        db = _open_sqlite(Path(path))
    except (ArchiveError, sqlite3.Error):
        return None
    try:
        row = db.execute("SELECT value FROM metadata WHERE name='maxzoom'").fetchone()
        if row is not None and str(row[0]).strip().lstrip("-").isdigit():
            return int(row[0])
        row = db.execute("SELECT MAX(zoom_level) FROM tiles").fetchone()
        return None if row is None or row[0] is None else int(row[0])
    except sqlite3.Error:
        return None
    finally:
        db.close()


class PMTiles:
    """A PMTiles v3 archive of raster tiles (PNG, JPEG, WebP, AVIF), read through a memory map."""

    def __init__(self, path: Path) -> None:
        path = Path(path)
        if not path.is_file():
            raise ArchiveError("no such file")
        self._file = path.open("rb")
        try:
            self._map = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
            self._reader = PMTilesReader(lambda offset, length: self._map[offset : offset + length])
            self.header = self._reader.header()
        except Exception as exc:  # the package's MagicNumberNotFound, SpecVersionUnsupported...
            self._file.close()
            raise ArchiveError(f"not a PMTiles v3 archive ({type(exc).__name__})") from exc
        if self.header["tile_type"] not in RASTER_TILE_TYPES:
            self.close()
            raise ArchiveError(
                f"holds {self.header['tile_type'].name} tiles, not raster images (PNG, JPEG, WebP)"
            )
        self._lock = threading.Lock()

    @property
    def max_zoom(self) -> int:
        return int(self.header["max_zoom"])

    def get(self, z: int, x: int, y: int) -> bytes | None:
        """Tile (z, x, y) (XYZ rows), uncompressed; None where the archive has none."""
        with self._lock:
            data = self._reader.get(z, x, y)
        if data is None:
            return None
        if self.header["tile_compression"] == Compression.GZIP:
            data = gzip.decompress(data)
        return bytes(data)

    def close(self) -> None:
        self._map.close()
        self._file.close()


class GeoPackageTiles:
    """The tiles of a GeoPackage: its first tiles table, or `#table=NAME` after the path."""

    def __init__(self, location: str) -> None:
        path, options = split_options(location)
        try:
            self._db = _open_sqlite(Path(path))
            self.table, self.grid, self._levels = self._read(options.get("table"))
        except sqlite3.Error as exc:
            raise ArchiveError(f"not a GeoPackage ({exc})") from exc
        self._lock = threading.Lock()

    def _read(self, table: str | None) -> tuple[str, TileGrid, tuple[int, ...]]:
        db = self._db
        tables = [
            r[0]
            for r in db.execute(
                "SELECT table_name FROM gpkg_contents WHERE data_type='tiles' ORDER BY rowid"
            )
        ]
        if not tables:
            raise ArchiveError("holds no tiles table (gpkg_contents names none)")
        if table is None:
            table = tables[0]
        elif table not in tables:
            raise ArchiveError(f"no tiles table {table!r} (it holds {', '.join(tables)})")
        found = db.execute(
            "SELECT s.srs_id, s.organization, s.organization_coordsys_id, s.definition, "
            "m.min_x, m.max_y FROM gpkg_tile_matrix_set m JOIN gpkg_spatial_ref_sys s "
            "ON s.srs_id = m.srs_id WHERE m.table_name=?",
            (table,),
        ).fetchone()
        if found is None:
            raise ArchiveError(f"table {table}: no gpkg_tile_matrix_set row")
        _, org, code, definition, left, top = found
        crs = f"{org.upper()}:{code}" if org and org.upper() == "EPSG" else str(definition)
        try:
            crs_of(crs)
        except Exception as exc:  # pyproj's CRSError
            raise ArchiveError(f"table {table}: unknown CRS {crs[:60]!r}") from exc
        rows = db.execute(
            "SELECT zoom_level, matrix_width, matrix_height, tile_width, tile_height, "
            "pixel_x_size, pixel_y_size FROM gpkg_tile_matrix WHERE table_name=? "
            "ORDER BY zoom_level",
            (table,),
        ).fetchall()
        if not rows:
            raise ArchiveError(f"table {table}: no gpkg_tile_matrix rows")
        matrices = tuple(
            Matrix(str(z), float(px), float(left), float(top), int(tw), int(th), int(mw), int(mh))
            for z, mw, mh, tw, th, px, _ in rows
        )
        return table, TileGrid(crs, matrices, table), tuple(int(r[0]) for r in rows)

    def get(self, z: int, x: int, y: int) -> bytes | None:
        """Column x, row y (from the top) of level z (the grid's index); None where none."""
        with self._lock:
            found = self._db.execute(
                f'SELECT tile_data FROM "{self.table}" '  # a name gpkg_contents gave
                "WHERE zoom_level=? AND tile_column=? AND tile_row=?",
                (self._levels[z], x, y),
            ).fetchone()
        return None if found is None else bytes(found[0])

    def close(self) -> None:
        self._db.close()


# -- writing ----------------------------------------------------------------------------------


def write_mbtiles(
    path: Path, tiles: Iterable[tuple[int, int, int, bytes]], metadata: dict[str, str]
) -> int:
    """An MBTiles file of tiles (z, x, y XYZ rows, bytes) with its metadata (name, format,
    bounds, minzoom, maxzoom, attribution...); tiles written."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    db = sqlite3.connect(tmp)
    n = 0
    try:
        db.execute("CREATE TABLE metadata (name text, value text)")
        db.execute(
            "CREATE TABLE tiles (zoom_level integer, tile_column integer, tile_row integer, "
            "tile_data blob)"
        )
        db.execute("CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)")
        for z, x, y, data in tiles:
            db.execute(
                "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?)",
                (z, x, (1 << z) - 1 - y, sqlite3.Binary(data)),
            )
            n += 1
        db.executemany("INSERT INTO metadata VALUES (?, ?)", list(metadata.items()))
        db.commit()
    finally:
        db.close()
    tmp.replace(path)
    return n


def write_pmtiles(
    path: Path,
    tiles: Iterable[tuple[int, int, int, bytes]],
    image_format: str = "png",
    metadata: dict | None = None,
) -> int:
    """A PMTiles v3 archive of raster tiles (z, x, y XYZ rows, bytes), uncompressed as images
    are; bounds and centre from the tiles' extent; tiles written."""
    entries = sorted((zxy_to_tileid(z, x, y), z, x, y, data) for z, x, y, data in tiles)
    if not entries:
        raise ArchiveError("no tile to write")
    zs = [e[1] for e in entries]
    top = [e for e in entries if e[1] == min(zs)]
    west, south, east, north = tm.TileRange(
        min(zs), min(e[2] for e in top), min(e[3] for e in top),
        max(e[2] for e in top), max(e[3] for e in top),
    ).bounds_m()  # fmt: skip
    lon = [v / tm.HALF_WORLD_M * 180.0 for v in (west, east)]
    lat = [float(_lat_of(v)) for v in (south, north)]
    with open(path, "wb") as f:
        writer = PMTilesWriter(f)
        for tile_id, *_, data in entries:
            writer.write_tile(tile_id, data)
        writer.finalize(
            {
                "tile_type": TILE_TYPE_OF.get(image_format, TileType.PNG),
                "tile_compression": Compression.NONE,
                "min_lon_e7": int(lon[0] * 1e7),
                "min_lat_e7": int(lat[0] * 1e7),
                "max_lon_e7": int(lon[1] * 1e7),
                "max_lat_e7": int(lat[1] * 1e7),
                "center_zoom": min(zs),
                "center_lon_e7": int((lon[0] + lon[1]) / 2 * 1e7),
                "center_lat_e7": int((lat[0] + lat[1]) / 2 * 1e7),
            },
            metadata or {},
        )
    return len(entries)


def _lat_of(y_m: float) -> float:
    """Latitude (deg) of an EPSG:3857 northing (m)."""
    return math.degrees(2.0 * math.atan(math.exp(y_m / 6378137.0)) - math.pi / 2.0)


def write_gpkg(
    path: Path,
    grid: TileGrid,
    tiles: Iterable[tuple[int, int, int, bytes]],
    table: str = "tiles",
    epsg: int | None = None,
) -> int:
    """A GeoPackage holding one tiles table in `grid` (its levels numbered 0..n-1 as its
    zoom_level), tiles (level, column, row from the top, bytes); epsg: the grid CRS's code
    (else its WKT is written as an organisation 'NONE' system); tiles written."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    crs = crs_of(grid.crs)
    code = epsg if epsg is not None else crs.to_epsg()
    srs_id = code if code is not None else 100000
    m0 = grid.matrices[0]
    xmin, ymax = m0.left, m0.top
    xmax, ymin = xmin + m0.cols * m0.span[0], ymax - m0.rows * m0.span[1]
    db = sqlite3.connect(tmp)
    n = 0
    try:
        db.execute("PRAGMA application_id = 1196444487")  # 'GPKG'
        db.execute("PRAGMA user_version = 10300")
        db.execute(
            "CREATE TABLE gpkg_spatial_ref_sys (srs_name TEXT NOT NULL, srs_id INTEGER PRIMARY "
            "KEY, organization TEXT NOT NULL, organization_coordsys_id INTEGER NOT NULL, "
            "definition TEXT NOT NULL, description TEXT)"
        )
        db.execute(
            "CREATE TABLE gpkg_contents (table_name TEXT NOT NULL PRIMARY KEY, data_type TEXT "
            "NOT NULL, identifier TEXT UNIQUE, description TEXT DEFAULT '', last_change "
            "DATETIME, min_x DOUBLE, min_y DOUBLE, max_x DOUBLE, max_y DOUBLE, srs_id INTEGER)"
        )
        db.execute(
            "CREATE TABLE gpkg_tile_matrix_set (table_name TEXT NOT NULL PRIMARY KEY, srs_id "
            "INTEGER NOT NULL, min_x DOUBLE NOT NULL, min_y DOUBLE NOT NULL, max_x DOUBLE NOT "
            "NULL, max_y DOUBLE NOT NULL)"
        )
        db.execute(
            "CREATE TABLE gpkg_tile_matrix (table_name TEXT NOT NULL, zoom_level INTEGER NOT "
            "NULL, matrix_width INTEGER NOT NULL, matrix_height INTEGER NOT NULL, tile_width "
            "INTEGER NOT NULL, tile_height INTEGER NOT NULL, pixel_x_size DOUBLE NOT NULL, "
            "pixel_y_size DOUBLE NOT NULL, CONSTRAINT pk_ttm PRIMARY KEY (table_name, zoom_level))"
        )
        db.execute(
            f'CREATE TABLE "{table}" (id INTEGER PRIMARY KEY AUTOINCREMENT, zoom_level INTEGER '
            "NOT NULL, tile_column INTEGER NOT NULL, tile_row INTEGER NOT NULL, tile_data BLOB "
            "NOT NULL, UNIQUE (zoom_level, tile_column, tile_row))"
        )
        db.execute(
            "INSERT INTO gpkg_spatial_ref_sys VALUES (?, ?, ?, ?, ?, ?)",
            (crs.name, srs_id, "EPSG" if code is not None else "NONE", srs_id, crs.to_wkt(), ""),
        )
        db.execute(
            "INSERT INTO gpkg_contents VALUES (?, 'tiles', ?, '', datetime('now'), ?, ?, ?, ?, ?)",
            (table, table, xmin, ymin, xmax, ymax, srs_id),
        )
        db.execute(
            "INSERT INTO gpkg_tile_matrix_set VALUES (?, ?, ?, ?, ?, ?)",
            (table, srs_id, xmin, ymin, xmax, ymax),
        )
        for z, m in enumerate(grid.matrices):
            db.execute(
                "INSERT INTO gpkg_tile_matrix VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (table, z, m.cols, m.rows, m.tile_w, m.tile_h, m.res, m.res),
            )
        for z, x, y, data in tiles:
            db.execute(
                f'INSERT OR REPLACE INTO "{table}" (zoom_level, tile_column, tile_row, tile_data) '
                "VALUES (?, ?, ?, ?)",
                (z, x, y, sqlite3.Binary(data)),
            )
            n += 1
        db.commit()
    finally:
        db.close()
    tmp.replace(path)
    return n
