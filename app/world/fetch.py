"""Tiles of one source, from its MBTiles file or over HTTP through the disk cache, with every
fault said once per source and counted, never raised.

Faults: a missing tile (404: the caller draws a coarser level there, or none), a time-out, a
server that closes mid-tile, a server that asks to slow down (429: its Retry-After honoured up
to RETRY_WAIT_MAX_S, twice at most), a corrupt tile (not an image), a refused key (401/403: the
source is given up for the rest of the fetch, named without the key), a fetch that ran out of
time. Requests carry the source's headers and key; no message holds the URL's query or the key.
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
from app.world.cache import TileCache
from app.world.sources import TileSource

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
    "forbidden": "refused (401/403: check the key or the token; the source was given up)",
    "error": "failed (other HTTP or network errors)",
    "late": "not fetched within the time allowed",
}


class SourceFetcher:
    """Decoded tiles of `source` (get), counting requests, cache hits and faults."""

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
        parts = [
            f"{n} {FAULTS[k]} (first {self.source.redact(self.first[k])})"
            for k, n in self.faults.items()
        ]
        messages.add_once(
            f"world-faults {what}", f"{what} ({self.source.label}): tiles " + "; ".join(parts)
        )

    # -- reading --------------------------------------------------------------------------------

    def get(self, z: int, x: int, y: int) -> np.ndarray | None:
        """Tile (z, x, y) (XYZ rows) as an (H, W, 3) uint8 array, None where it cannot be had
        (the fault counted)."""
        if self.given_up:
            return None
        data = self._mbtiles(z, x, y) if self.source.is_mbtiles else self._http(z, x, y)
        if data is None:
            return None
        try:
            with Image.open(io.BytesIO(data)) as im:
                return np.asarray(im.convert("RGB"), np.uint8)
        except (UnidentifiedImageError, OSError, ValueError) as exc:
            self.cache.drop(self.source.identity, z, x, y)
            self._fault("corrupt", z, x, y, type(exc).__name__)
            return None

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

    def _http(self, z: int, x: int, y: int) -> bytes | None:
        identity = self.source.identity
        cached = self.cache.get(identity, z, x, y)
        if cached is not None and cached.fresh:
            with self._lock:
                self.from_cache += 1
            if cached.data is None:
                self._fault("missing", z, x, y)
            return cached.data
        headers = {"User-Agent": USER_AGENT, **self.source.request_headers()}
        if cached is not None and cached.etag:
            headers["If-None-Match"] = cached.etag
        for attempt in range(RETRIES_429 + 1):
            left = self.deadline - self.clock()
            if left <= 0 or self.given_up:
                self._fault("late", z, x, y)
                return None
            request = urllib.request.Request(self.source.url(z, x, y), headers=headers)
            with self._lock:
                self.requests += 1
            try:
                with urllib.request.urlopen(request, timeout=min(REQUEST_TIMEOUT_S, left)) as resp:
                    data = resp.read()
                    got = {k.lower(): v for k, v in resp.headers.items()}
                self.cache.put(identity, z, x, y, data, got)
                return data
            except urllib.error.HTTPError as exc:
                got = {k.lower(): v for k, v in (exc.headers or {}).items()}
                if exc.code == 304 and cached is not None:
                    self.cache.refresh(identity, z, x, y, got)
                    return cached.data
                if exc.code == 404:
                    self.cache.put(identity, z, x, y, None, got)
                    self._fault("missing", z, x, y)
                    return None
                if exc.code in (401, 403):
                    self._fault("forbidden", z, x, y, f"HTTP {exc.code}")
                    return None
                if exc.code == 429 and attempt < RETRIES_429:
                    self.sleep(min(retry_after_s(got.get("retry-after")), RETRY_WAIT_MAX_S, left))
                    continue
                kind = "throttled" if exc.code == 429 else "error"
                self._fault(kind, z, x, y, f"HTTP {exc.code}")
                return None
            except TimeoutError:
                self._fault("timeout", z, x, y)
                return None
            except urllib.error.URLError as exc:
                timed_out = isinstance(exc.reason, TimeoutError) or "timed out" in str(exc.reason)
                if timed_out:
                    self._fault("timeout", z, x, y)
                else:
                    self._fault("error", z, x, y, self.source.redact(str(exc.reason)))
                return None
            except (HTTPException, ConnectionError) as exc:  # IncompleteRead, reset mid-tile
                self._fault("closed", z, x, y, type(exc).__name__)
                return None
        return None

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None


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
