"""Where a tileset's files come from: a folder or an http(s) URL, read the same way.

Locations are strings: an absolute file path or a URL. URIs inside a tileset are resolved
against the file that names them (RFC 3986 for URLs; percent-decoded, query dropped for files).
Gzip-compressed files (as some servers and tools store b3dm and JSON) are inflated by magic.
"""

from __future__ import annotations

import gzip
import os
import urllib.error
import urllib.parse
import urllib.request

HTTP_TIMEOUT_S = 30.0


class FetchError(OSError):
    """A file of a tileset that cannot be read; `location` names it."""

    def __init__(self, location: str, reason: str) -> None:
        self.location = location
        super().__init__(f"{location}: {reason}")


def is_url(location: str) -> bool:
    return location.lower().startswith(("http://", "https://"))


def display_name(location: str) -> str:
    """A location as messages name it: a URL whole; a file by its name, a tileset.json with its
    folder (most tilesets are called that)."""
    if is_url(location):
        return location
    parts = location.replace("\\", "/").rstrip("/").split("/")
    return (
        "/".join(parts[-2:])
        if parts[-1].lower() == "tileset.json" and len(parts) > 1
        else parts[-1]
    )


def resolve(base: str, uri: str) -> str:
    """`uri` as written inside the file at `base`, made absolute."""
    if is_url(uri):
        return uri
    if is_url(base):
        return urllib.parse.urljoin(base, uri)
    path = (
        urllib.parse.unquote(urllib.parse.urlsplit(uri).path) if "%" in uri or "?" in uri else uri
    )
    return os.path.normpath(os.path.join(os.path.dirname(base), path))


def read(location: str) -> bytes:
    """The bytes at `location` (inflated when gzip). Raises FetchError naming it."""
    try:
        if is_url(location):
            req = urllib.request.Request(
                location, headers={"Accept-Encoding": "gzip", "User-Agent": "geofuse"}
            )
            with urllib.request.urlopen(req, timeout=HTTP_TIMEOUT_S) as resp:
                data = resp.read()
        else:
            with open(location, "rb") as fh:
                data = fh.read()
    except urllib.error.HTTPError as exc:
        raise FetchError(location, f"HTTP {exc.code} {exc.reason}") from exc
    except urllib.error.URLError as exc:
        raise FetchError(location, f"cannot reach: {exc.reason}") from exc
    except FileNotFoundError as exc:
        raise FetchError(location, "file does not exist") from exc
    except OSError as exc:
        raise FetchError(location, str(exc)) from exc
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError) as exc:
            raise FetchError(location, f"damaged gzip data: {exc}") from exc
    return data
