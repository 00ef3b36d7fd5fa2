"""Tiles of one source, from its local archive (MBTiles, PMTiles, GeoPackage) or over HTTP
through the disk cache (XYZ/TMS templates; a WMTS layer, its capabilities read once and kept in
the cache too; quantized-mesh terrain, its layer.json likewise, only the tiles it says the server
has asked for), with every fault said once per source and counted, never raised.

Faults: a missing tile (404: the caller draws a coarser level there, or none), a time-out, a
server that closes mid-tile, a server that asks to slow down (429: its Retry-After honoured up
to RETRY_WAIT_MAX_S, twice at most), a corrupt tile (not an image, not a mesh), a refused key
(401/403: the source is given up for the rest of the fetch, named without the key), a fetch that
ran out of time. Requests carry the source's headers and key; no message holds the URL's query or the key.
"""

from __future__ import annotations

import email.utils
import io
import sqlite3
import threading
import time
import urllib.error
import urllib.request
from collections import Counter
from http.client import HTTPException
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from app.core.messages import Messages
from app.world.archives import ArchiveError, GeoPackageTiles, PMTiles, mbtiles_max_zoom
from app.world.cache import TileCache
from app.world.grids import TileGrid
from app.world.quantized import (
    QuantizedLayer,
    QuantizedMesh,
    QuantizedMeshError,
    decode_mesh,
    tile_heights,
)
from app.world.quantized import read_layer as read_quantized_layer
from app.world.sources import QUANTIZED_MESH, TileSource
from app.world.wmts import WmtsError, WmtsLayer, read_layer

REQUEST_TIMEOUT_S = 10.0
RETRY_WAIT_MAX_S = 5.0
RETRIES_429 = 2
USER_AGENT = "geofuse (https://github.com/geofuse)"

FAULTS = {
    "missing": "missing (404: drawn from a coarser level, or left out)",
    "timeout": "timed out",
    "closed": "cut off by the server mid-tile",
    "throttled": "refused for too many requests (429) after waiting as asked",
    "corrupt": "not a readable image (corrupt)",
    "corrupt-mesh": "not a readable quantized-mesh tile (corrupt)",
    "forbidden": "refused (401/403: check the key or the token; the source was given up)",
    "error": "failed (other HTTP or network errors)",
    "late": "not fetched within the time allowed",
}
SOURCE_FAULTS = {  # faults of the whole source, said before its tiles'
    "capabilities": "its WMTS capabilities could not be used",
    "layer": "its layer.json could not be used",
    "archive": "the archive could not be read",
}
CAPABILITIES_AT = (0, 0, 0)  # where a WMTS's capabilities or a layer.json is kept in the cache


class SourceFetcher:
    """Decoded tiles of `source` (get), counting requests, cache hits and faults. Tiles are
    addressed as XYZ Web Mercator (z, x, y) where source.web_mercator (templates, MBTiles,
    PMTiles), else as (level, column, row from the top) of the source's grid() (a quantized-mesh
    tile is cached and named in messages by the row its server counts, TMS or not)."""

    def __init__(
        self,
        source: TileSource,
        cache: TileCache,
        deadline: float,
        clock=time.monotonic,
        sleep=time.sleep,
    ) -> None:
        self.source = source
        self.cache = cache
        self.deadline = deadline
        self.clock, self.sleep = clock, sleep
        self.requests = 0
        self.from_cache = 0
        self.faults: Counter[str] = Counter()
        self.first: dict[str, str] = {}  # kind -> the first tile and detail, for the message
        self.given_up = False
        self._lock = threading.Lock()
        self._db: sqlite3.Connection | None = None
        self._archive: PMTiles | GeoPackageTiles | None = None
        self._wmts: WmtsLayer | None = None
        self._qm: QuantizedLayer | None = None
        self._availability_lock = threading.Lock()
        self._opened = False
        self._open_lock = threading.Lock()

    # -- faults ---------------------------------------------------------------------------------

    def _fault(self, kind: str, z: int, x: int, y: int, detail: str = "") -> None:
        with self._lock:
            self.faults[kind] += 1
            self.first.setdefault(kind, f"{z}/{x}/{y}" + (f": {detail}" if detail else ""))
            if kind == "forbidden":
                self.given_up = True

    def report(self, messages: Messages, what: str) -> None:
        """One message for this source's faults (none when there were none); `what` names the
        source to the person (e.g. "world maptiler imagery")."""
        if not self.faults:
            return
        whole = [f"{SOURCE_FAULTS[k]}: {self.first[k]}" for k in self.faults if k in SOURCE_FAULTS]
        parts = [
            f"{n} {FAULTS[k]} (first {self.first[k]})"
            for k, n in self.faults.items()
            if k in FAULTS
        ]
        text = "; ".join(whole + (["tiles " + "; ".join(parts)] if parts else []))
        messages.add_once(
            f"world-faults {what}", self.source.redact(f"{what} ({self.source.label}): {text}")
        )

    def _whole(self, kind: str, detail: str) -> None:
        """A fault of the whole source (SOURCE_FAULTS): said with its detail; nothing more is
        asked of it."""
        with self._lock:
            self.faults[kind] += 1
            self.first.setdefault(kind, self.source.redact(detail))
            self.given_up = True

    # -- reading --------------------------------------------------------------------------------

    def open(self) -> bool:
        """Open the source once: its archive, or a WMTS's capabilities (fetched through the
        cache); False where it cannot be used (the fault counted)."""
        with self._open_lock:
            if not self._opened:
                self._opened = True
                self._open_now()
            return not self.given_up

    def _open_now(self) -> None:
        form = self.source.form
        if form == "mbtiles" and not Path(self.source.location).is_file():
            self._whole("archive", "no such file")
            return
        try:
            if form == "pmtiles":
                self._archive = PMTiles(self.source.location)
            elif form == "gpkg":
                self._archive = GeoPackageTiles(self.source.location)
        except ArchiveError as exc:
            self._whole("archive", str(exc))
            return
        if form in ("wmts", QUANTIZED_MESH):
            document = self._document()
            if document is None:
                return
            try:
                if form == "wmts":
                    self._wmts = read_layer(document, self.source.location)
                else:
                    self._qm = read_quantized_layer(
                        document, self.source.location, self.source.max_zoom
                    )
            except (WmtsError, QuantizedMeshError) as exc:
                self.cache.drop(self._doc_identity, *CAPABILITIES_AT)
                self._whole(self._doc_kind, str(exc))

    def grid(self) -> TileGrid | None:
        """The source's own tile grid (a WMTS layer's TileMatrixSet, a GeoPackage's pyramid);
        None for the XYZ Web Mercator forms (app.world.tiles) and for a source that cannot be
        opened (the fault counted: see given_up)."""
        if not self.open():
            return None
        if self._wmts is not None:
            return self._wmts.grid
        if self._qm is not None:
            return self._qm.grid
        if isinstance(self._archive, GeoPackageTiles):
            return self._archive.grid
        return None

    def max_zoom(self) -> int:
        """The finest XYZ zoom to ask for: the source's max_zoom, no finer than a local
        archive's finest level."""
        finest = None
        if self.source.form == "mbtiles":
            finest = mbtiles_max_zoom(Path(self.source.location))
        elif self.source.form == "pmtiles" and self.open() and self._archive is not None:
            finest = self._archive.max_zoom
        return self.source.max_zoom if finest is None else min(self.source.max_zoom, finest)

    def get(self, z: int, x: int, y: int) -> np.ndarray | None:
        """Tile (z, x, y) as an (H, W, 3) uint8 array (a quantized-mesh tile: its (H, W) float64
        heights, m above the ellipsoid, sampled at its pixel centres, north row first), None
        where it cannot be had (the fault counted). (z, x, y): XYZ Web Mercator for templates,
        MBTiles and PMTiles; level (the grid's index), column and row from the top of the
        source's grid() otherwise."""
        if self.source.form == QUANTIZED_MESH:
            mesh = self.mesh(z, x, y)
            return None if mesh is None else tile_heights(self._qm, mesh, z, x, y)
        data = self.get_bytes(z, x, y)
        if data is None:
            return None
        try:
            with Image.open(io.BytesIO(data)) as im:
                return np.asarray(im.convert("RGB"), np.uint8)
        except (UnidentifiedImageError, OSError, ValueError) as exc:
            self.cache.drop(self.source.identity, z, x, y)
            self._fault("corrupt", z, x, y, type(exc).__name__)
            return None

    def get_bytes(self, z: int, x: int, y: int, check: bool = False) -> bytes | None:
        """Tile (z, x, y) (as get addresses it) as the source gave it (an image file's bytes),
        None where it cannot be had (the fault counted); check: only an image that reads (a
        corrupt one counted and dropped from the cache)."""
        data = self._bytes(z, x, y)
        if data is None or not check:
            return data
        if self._qm is not None:
            return data if self._decoded(data, z, x, y) is not None else None
        try:
            with Image.open(io.BytesIO(data)) as im:
                im.verify()
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
            self.cache.drop(self.source.identity, z, x, y)
            self._fault("corrupt", z, x, y, type(exc).__name__)
            return None
        return data

    def _bytes(self, z: int, x: int, y: int) -> bytes | None:
        if self.given_up or not self.open():
            return None
        form = self.source.form
        if form == "mbtiles" or self._archive is not None:
            try:
                data = self._mbtiles(z, x, y) if form == "mbtiles" else self._archive.get(z, x, y)
            except (
                Exception
            ) as exc:  # a damaged archive: whatever its reader (sqlite, pmtiles) raises
                self._whole("archive", f"{type(exc).__name__}: {str(exc)[:80]}")
                return None
            if data is None and form != "mbtiles":
                self._fault("missing", z, x, y)
            return data
        if self._wmts is not None:
            return self._http(z, x, y, self.source.fill(self._wmts.url(z, x, y)))
        if self._qm is not None:
            if not self.has(z, x, y):
                return None  # the layer says the server lacks it: never asked for
            return self._mesh_bytes(z, x, y)
        return self._http(z, x, y)

    # -- quantized-mesh -------------------------------------------------------------------------

    def _mesh_bytes(self, z: int, x: int, y: int) -> bytes | None:
        """A quantized-mesh tile's bytes (grid row y from the top), the extensions used asked
        for, cached and named by the server's row."""
        extra = {"Accept": self._qm.accept, "Accept-Encoding": "gzip"}
        url = self.source.fill(self._qm.url(z, x, y))
        return self._http(z, x, self._qm.server_row(z, y), url, extra=extra)

    def _decoded(self, data: bytes, z: int, x: int, y: int) -> QuantizedMesh | None:
        """A quantized-mesh tile's mesh, None for one that does not read (counted as corrupt,
        named by the server's row, and dropped from the cache)."""
        try:
            return decode_mesh(data, self._qm.little_endian_extensions)
        except QuantizedMeshError as exc:
            row = self._qm.server_row(z, y)
            self.cache.drop(self.source.identity, z, x, row)
            self._fault("corrupt-mesh", z, x, row, str(exc))
            return None

    def mesh(self, z: int, x: int, y: int) -> QuantizedMesh | None:
        """A quantized-mesh source's tile (level z, column x, grid row y from the top) decoded,
        None where it cannot be had (the fault counted) or the layer says it is not there."""
        data = self._bytes(z, x, y)
        return None if data is None else self._decoded(data, z, x, y)

    def has(self, z: int, x: int, y: int) -> bool:
        """Whether a quantized-mesh source has tile (z, x, y) (grid rows from the top), by its
        layer.json's `available` and, where it gives availability in tile metadata, by the
        metadata of the tiles above (fetched here, through the cache, once each). True for the
        other forms."""
        if self._qm is None:
            return True
        with self._availability_lock:
            while True:
                known = self._qm.available(z, x, y)
                if known is not None:
                    return known
                t = self._qm.to_load(z, x, y)
                data = self._mesh_bytes(*t)
                mesh = None if data is None else self._decoded(data, *t)
                try:
                    self._qm.add_metadata(*t, None if mesh is None else mesh.metadata)
                except QuantizedMeshError as exc:
                    self._fault(
                        "corrupt-mesh", t[0], t[1], self._qm.server_row(t[0], t[2]), str(exc)
                    )

    def finest_level(self, bounds: tuple[float, float, float, float], z: int) -> int:
        """z, or for a quantized-mesh source the finest level no finer than z at which it has
        any tile over bounds (xmin, ymin, xmax, ymax in its grid's CRS); its tiles missing
        there are drawn from coarser ones. A layer with no tile there at all is given up (said
        as the layer's fault)."""
        if self._qm is None:
            return z
        while not any(self.has(*t) for t in self._qm.grid.covering(bounds, z).tiles()):
            if z == 0:
                self._whole("layer", "it lists no tile over the clip's area")
                break
            z -= 1
        return z

    def _mbtiles(self, z: int, x: int, y: int) -> bytes | None:
        with self._lock:
            if self._db is None:
                uri = Path(self.source.location).resolve().as_uri() + "?mode=ro"
                self._db = sqlite3.connect(uri, uri=True, check_same_thread=False)
            row = (1 << z) - 1 - y  # MBTiles rows are TMS
            found = self._db.execute(
                "SELECT tile_data FROM tiles WHERE zoom_level=? AND tile_column=? AND tile_row=?",
                (z, x, row),
            ).fetchone()
        if found is None:
            self._fault("missing", z, x, y)
            return None
        return bytes(found[0])

    @property
    def _doc_identity(self) -> str:
        return self.source.identity + "|capabilities"

    @property
    def _doc_kind(self) -> str:
        """The SOURCE_FAULTS kind of the source's own document."""
        return "layer" if self.source.form == QUANTIZED_MESH else "capabilities"

    def _document(self) -> bytes | None:
        """The source's own document, a WMTS's capabilities or a quantized-mesh layer.json
        (through the cache, its secrets kept out of it)."""
        faults = sum(self.faults.values())
        data = self._http(
            *CAPABILITIES_AT, self.source.fill(self.source.location.partition("#")[0]), doc=True
        )
        if data is None:
            if sum(self.faults.values()) == faults:  # not said yet
                self._whole(self._doc_kind, "no answer")
            return None
        return self._unseal(data)

    def _seal(self, data: bytes) -> bytes:
        """`data` with every secret of the source replaced by a placeholder (to be kept)."""
        for i, secret in enumerate(self.source.secrets):
            for form in {secret, urllib.parse.quote(secret, safe="")}:
                data = data.replace(form.encode(), f"{{secret{i}}}".encode())
        return data

    def _unseal(self, data: bytes) -> bytes:
        for i, secret in enumerate(self.source.secrets):
            data = data.replace(f"{{secret{i}}}".encode(), secret.encode())
        return data

    def _http(
        self,
        z: int,
        x: int,
        y: int,
        url: str | None = None,
        doc: bool = False,
        extra: dict[str, str] | None = None,
    ) -> bytes | None:
        """Tile (z, x, y) from the cache or from `url` (default: the source's template's);
        doc: the source's own document (its faults said as the source's, its secrets sealed in
        the cache); extra: headers sent besides the source's."""
        identity = self._doc_identity if doc else self.source.identity
        fault = self._doc_fault if doc else self._fault
        url = url or self.source.url(z, x, y)
        cached = self.cache.get(identity, z, x, y)
        if cached is not None and cached.fresh:
            with self._lock:
                self.from_cache += 1
            if cached.data is None:
                fault("missing", z, x, y)
            return cached.data
        headers = {"User-Agent": USER_AGENT, **(extra or {}), **self.source.request_headers()}
        if cached is not None and cached.etag:
            headers["If-None-Match"] = cached.etag
        for attempt in range(RETRIES_429 + 1):
            left = self.deadline - self.clock()
            if left <= 0 or self.given_up:
                fault("late", z, x, y)
                return None
            request = urllib.request.Request(url, headers=headers)
            with self._lock:
                self.requests += 1
            try:
                with urllib.request.urlopen(request, timeout=min(REQUEST_TIMEOUT_S, left)) as resp:
                    data = resp.read()
                    got = {k.lower(): v for k, v in resp.headers.items()}
                self.cache.put(identity, z, x, y, self._seal(data) if doc else data, got)
                return data
            except urllib.error.HTTPError as exc:
                got = {k.lower(): v for k, v in (exc.headers or {}).items()}
                if exc.code == 304 and cached is not None:
                    self.cache.refresh(identity, z, x, y, got)
                    return cached.data
                if exc.code == 404:
                    self.cache.put(identity, z, x, y, None, got)
                    fault("missing", z, x, y)
                    return None
                if exc.code in (401, 403):
                    fault("forbidden", z, x, y, f"HTTP {exc.code}")
                    return None
                if exc.code == 429 and attempt < RETRIES_429:
                    self.sleep(min(retry_after_s(got.get("retry-after")), RETRY_WAIT_MAX_S, left))
                    continue
                kind = "throttled" if exc.code == 429 else "error"
                fault(kind, z, x, y, f"HTTP {exc.code}")
                return None
            except TimeoutError:
                fault("timeout", z, x, y)
                return None
            except urllib.error.URLError as exc:
                timed_out = isinstance(exc.reason, TimeoutError) or "timed out" in str(exc.reason)
                if timed_out:
                    fault("timeout", z, x, y)
                else:
                    fault("error", z, x, y, self.source.redact(str(exc.reason)))
                return None
            except (HTTPException, ConnectionError) as exc:  # IncompleteRead, reset mid-tile
                fault("closed", z, x, y, type(exc).__name__)
                return None
        return None

    def _doc_fault(self, kind: str, z: int, x: int, y: int, detail: str = "") -> None:
        """A fault fetching the source's own document: the whole source's."""
        text = "missing (HTTP 404)" if kind == "missing" else FAULTS[kind]
        self._whole(self._doc_kind, text + (f" ({detail})" if detail else ""))

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None
        if self._archive is not None:
            self._archive.close()
            self._archive = None


def retry_after_s(value: str | None, now: float | None = None) -> float:
    """A Retry-After header (seconds, or an HTTP date) as seconds to wait (1 when absent)."""
    if not value:
        return 1.0
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value).timestamp()
    except (TypeError, ValueError):
        return 1.0
    return max(0.0, when - (time.time() if now is None else now))
