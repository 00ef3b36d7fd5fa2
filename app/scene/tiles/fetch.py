"""Where a tileset's files come from: a folder or an http(s) URL, read the same way.

Locations are strings: an absolute file path or a URL. URIs inside a tileset are resolved
against the file that names them (RFC 3986 for URLs; percent-decoded, query dropped for files).
Gzip-compressed files (as some servers and tools store b3dm and JSON) are inflated by magic.

Keyed services (Google Photorealistic 3D Tiles, Cesium ion): the root is asked for with a key or
token in its query (`?key=...`), and its children name a session (`?session=...`) that every
further request must carry with the key. As CesiumJS does, a child on the same host inherits its
parent's query parameters that it does not set itself; a child on another host inherits none (a
key is never sent where it was not given). Secret values (SECRET_PARAMS) are never shown: every
location a message names goes through `redact`.
"""

from __future__ import annotations

import os
import re
import urllib.error
import urllib.parse
import urllib.request

from app.core.compression import DamagedGzip, gunzipped

HTTP_TIMEOUT_S = 30.0
# query parameters whose values are secrets: never in a message, a log or a file written
SECRET_PARAMS = ("key", "token", "access_token", "apikey", "api_key", "sessiontoken", "session")


class FetchError(OSError):
    """A file of a tileset that cannot be read; `location` names it."""

    def __init__(self, location: str, reason: str) -> None:
        self.location = redact(location)
        super().__init__(f"{self.location}: {redact(reason)}")


def is_url(location: str) -> bool:
    return location.lower().startswith(("http://", "https://"))


def display_name(location: str) -> str:
    """A location as messages name it: a URL whole; a file by its name, a tileset.json with its
    folder (most tilesets are called that)."""
    if is_url(location):
        return redact(location)
    parts = location.replace("\\", "/").rstrip("/").split("/")
    return (
        "/".join(parts[-2:])
        if parts[-1].lower() == "tileset.json" and len(parts) > 1
        else parts[-1]
    )


def redact(text: str) -> str:
    """`text` (a location, or a message naming one) with the values of secret query parameters
    replaced by '***'."""
    if "=" not in text:
        return text
    names = "|".join(SECRET_PARAMS)
    return re.sub(rf"(?i)([?&](?:{names})=)[^&#\s'\"]*", r"\1***", text)


def _inherit(base: str, url: str) -> str:
    """`url` with the query parameters of `base` that it does not set, where both are on one
    scheme, host and port; else `url` as it is."""
    b, u = urllib.parse.urlsplit(base), urllib.parse.urlsplit(url)
    if not b.query or (b.scheme.lower(), b.netloc.lower()) != (u.scheme.lower(), u.netloc.lower()):
        return url
    own = urllib.parse.parse_qsl(u.query, keep_blank_values=True)
    names = {k for k, _ in own}
    extra = [
        (k, v) for k, v in urllib.parse.parse_qsl(b.query, keep_blank_values=True) if k not in names
    ]
    if not extra:
        return url
    return u._replace(query=urllib.parse.urlencode(own + extra, safe="{}")).geturl()


def resolve(base: str, uri: str) -> str:
    """`uri` as written inside the file at `base`, made absolute (a URL's child on the same host
    carrying the parent's query parameters: the module docstring)."""
    if is_url(uri):
        return _inherit(base, uri) if is_url(base) else uri
    if is_url(base):
        return _inherit(base, urllib.parse.urljoin(base, uri))
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
    try:
        return gunzipped(data)
    except DamagedGzip as exc:
        raise FetchError(location, f"damaged gzip data: {exc}") from exc
