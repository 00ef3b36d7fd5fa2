"""A bounded disk cache of fetched tiles, honouring HTTP caching headers.

Each tile is a file under ROOT/<source>/<z>/<x>/<y> (the source named by a hash of its
identity: its template with {key} unfilled, never the key; ROOT/<source>/source.json names it,
for `geofuse cache`) with a JSON beside it holding when it
goes stale (Cache-Control max-age, else Expires, else DEFAULT_FRESH_S) and its ETag, so a stale
tile is revalidated (If-None-Match) rather than fetched whole. A tile the server said is missing
(404) is kept as such for as long. `no-store` is honoured. The cache's size is kept under a
bound (GEOFUSE_TILE_CACHE_MB, default 2048 MB) by dropping the least recently used files.

ROOT: $GEOFUSE_TILE_CACHE, else the platform's cache folder (app.core.paths.cache_dir)/tiles.
"""

from __future__ import annotations

import email.utils
import hashlib
import json
import os
import re
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from app.core.paths import cache_dir

ENV_ROOT = "GEOFUSE_TILE_CACHE"
ENV_LIMIT_MB = "GEOFUSE_TILE_CACHE_MB"
DEFAULT_LIMIT_MB = 2048.0
DEFAULT_FRESH_S = 7 * 86400.0  # a tile whose server says nothing stays fresh this long, s
MISSING_FRESH_S = 86400.0  # a 404 is believed this long when the server says nothing, s
SOURCE_RECORD = "source.json"
_MAX_AGE = re.compile(r"(?:^|,)\s*(?:s-)?max-age\s*=\s*(\d+)", re.I)


def cache_root() -> Path:
    """Where tiles are kept: $GEOFUSE_TILE_CACHE, else cache_dir()/tiles."""
    env = os.environ.get(ENV_ROOT)
    return Path(env) if env else cache_dir() / "tiles"


def freshness_s(headers: dict[str, str], default_s: float, now: float) -> float | None:
    """How long (s) a response stays fresh by its headers (keys lower case): max-age, else
    Expires less Date, else default_s; None for no-store (not to be kept)."""
    cc = headers.get("cache-control", "")
    if "no-store" in cc.lower():
        return None
    if "no-cache" in cc.lower():
        return 0.0
    m = _MAX_AGE.search(cc)
    if m:
        return float(m.group(1))
    if "expires" in headers:
        try:
            expires = email.utils.parsedate_to_datetime(headers["expires"]).timestamp()
            date = headers.get("date")
            base = email.utils.parsedate_to_datetime(date).timestamp() if date else now
            return max(0.0, expires - base)
        except (TypeError, ValueError):
            return 0.0
    return default_s


@dataclass(frozen=True)
class KeptSource:
    """One source's part of the cache: its folder, identity (kind|encoding|scheme|location as
    TileSource.identity gives it, no key; '' for built worlds and unnamed folders), bytes and
    tiles kept (a 404 kept counts, and a GeoTIFF's window)."""

    folder: Path
    identity: str
    bytes: int
    tiles: int


@dataclass(frozen=True)
class Cached:
    """A tile from the cache: data (None: the server said it is missing), its ETag, and whether
    it is still fresh (usable without asking the server)."""

    data: bytes | None
    etag: str | None
    fresh: bool


class TileCache:
    """The cache under `root` (default cache_root()), kept under limit_mb megabytes."""

    def __init__(
        self, root: Path | None = None, limit_mb: float | None = None, clock=time.time
    ) -> None:
        self.root = Path(root) if root is not None else cache_root()
        env_limit = os.environ.get(ENV_LIMIT_MB)
        self.limit_bytes = int(
            1e6 * (limit_mb if limit_mb is not None else float(env_limit or DEFAULT_LIMIT_MB))
        )
        self.clock = clock
        self._lock = threading.Lock()

    def source_dir(self, identity: str) -> Path:
        """The folder of a source's tiles (and of what else is kept of it), named for
        `geofuse cache` by its source.json the first time."""
        folder = self.folder_of(identity)
        record = folder / SOURCE_RECORD
        if not record.is_file():
            folder.mkdir(parents=True, exist_ok=True)
            tmp = record.with_name(f"{SOURCE_RECORD}.{threading.get_ident()}.tmp")
            tmp.write_text(json.dumps({"identity": identity}))
            os.replace(tmp, record)
        return folder

    def folder_of(self, identity: str) -> Path:
        """Where a source's tiles are kept (perhaps not yet made)."""
        return self.root / hashlib.sha256(identity.encode()).hexdigest()[:16]

    def _path(self, identity: str, z: int, x: int, y: int) -> Path:
        source = hashlib.sha256(identity.encode()).hexdigest()[:16]
        return self.root / source / str(z) / str(x) / str(y)

    def sources(self) -> list[KeptSource]:
        """What the cache holds, per source (largest first); built worlds and anything not
        named by a source.json under identity ''."""
        out = []
        if not self.root.is_dir():
            return out
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            try:
                identity = json.loads((folder / SOURCE_RECORD).read_text())["identity"]
            except (OSError, ValueError, KeyError, TypeError):
                identity = ""
            files = [p for p in folder.rglob("*") if p.is_file() and p.name != SOURCE_RECORD]
            tiles = sum(1 for p in files if p.suffix == ".json" or p.parent.name == "windows")
            out.append(KeptSource(folder, identity, sum(p.stat().st_size for p in files), tiles))
        return sorted(out, key=lambda s: -s.bytes)

    def clear(self, folders: list[Path] | None = None) -> int:
        """Remove the given sources' folders (KeptSource.folder), or everything; bytes freed."""
        freed = 0
        for folder in folders if folders is not None else [p for p in self.root.glob("*")]:
            if not folder.exists():
                continue
            if folder.is_dir():
                freed += sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
                shutil.rmtree(folder, ignore_errors=True)
            else:
                freed += folder.stat().st_size
                folder.unlink(missing_ok=True)
        return freed

    def get(self, identity: str, z: int, x: int, y: int) -> Cached | None:
        """The tile as kept, or None when not kept (or its record is damaged)."""
        path = self._path(identity, z, x, y)
        meta_path = path.with_suffix(".json")
        try:
            meta = json.loads(meta_path.read_text())
            data = None if meta.get("missing") else path.read_bytes()
        except (OSError, ValueError):
            return None
        for p in (meta_path, path) if data is not None else (meta_path,):
            os.utime(p)  # recently used: kept longest
        return Cached(data, meta.get("etag"), self.clock() < float(meta.get("expires", 0.0)))

    def put(
        self,
        identity: str,
        z: int,
        x: int,
        y: int,
        data: bytes | None,
        headers: dict[str, str],
    ) -> None:
        """Keep a tile (data None: the server said it is missing) for as long as its headers
        (keys lower case) allow; nothing for no-store."""
        now = self.clock()
        fresh = freshness_s(headers, MISSING_FRESH_S if data is None else DEFAULT_FRESH_S, now)
        if fresh is None:
            return
        self.source_dir(identity)
        path = self._path(identity, z, x, y)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {"expires": now + fresh, "etag": headers.get("etag"), "missing": data is None}
        if data is not None:
            tmp = path.with_name(path.name + f".{threading.get_ident()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, path)
        tmp = path.with_name(path.name + f".{threading.get_ident()}.json.tmp")
        tmp.write_text(json.dumps(meta))
        os.replace(tmp, path.with_suffix(".json"))

    def refresh(self, identity: str, z: int, x: int, y: int, headers: dict[str, str]) -> None:
        """A stale tile the server said is unchanged (304): fresh again for its new headers."""
        cached = self.get(identity, z, x, y)
        if cached is not None and cached.data is not None:
            self.put(identity, z, x, y, cached.data, {"etag": cached.etag or "", **headers})

    def drop(self, identity: str, z: int, x: int, y: int) -> None:
        """Forget a tile (a damaged one)."""
        path = self._path(identity, z, x, y)
        for p in (path, path.with_suffix(".json")):
            p.unlink(missing_ok=True)

    def size_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file())

    def trim(self) -> int:
        """Drop the least recently used files until the cache is under its bound (a source's
        source.json kept: it is tiny and names the folder); bytes freed."""
        with self._lock:
            files = [p for p in self.root.rglob("*") if p.is_file() and p.name != SOURCE_RECORD]
            stats = [(p, p.stat()) for p in files]
            total = sum(s.st_size for _, s in stats)
            freed = 0
            for p, s in sorted(stats, key=lambda ps: ps[1].st_mtime):
                if total - freed <= self.limit_bytes:
                    break
                p.unlink(missing_ok=True)
                freed += s.st_size
            return freed
