"""Bodies that may come gzipped (tiles served gzipped, HTTP answers, tileset files): one way to
tell and to gunzip them, whose failure each caller names in its own error."""

from __future__ import annotations

import gzip
import zlib

GZIP_MAGIC = b"\x1f\x8b"


class DamagedGzip(ValueError):
    """Bytes that say they are gzip and do not gunzip (the reason in the message)."""


def gunzipped(data: bytes, gzipped: bool = False) -> bytes:
    """`data` gunzipped where it starts as gzip does, or where `gzipped` says it is (an HTTP
    Content-Encoding); as it was otherwise. DamagedGzip where it does not gunzip (a corrupt or
    truncated stream)."""
    if not gzipped and data[:2] != GZIP_MAGIC:
        return data
    try:
        return gzip.decompress(data)
    except (OSError, EOFError, zlib.error) as exc:
        raise DamagedGzip(str(exc)) from None
