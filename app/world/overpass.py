"""OpenStreetMap buildings for a clip's area from an Overpass API: one query per scene, its
answer kept in the tile cache (app.world.cache) so that the scene opens offline afterwards.

Spelling (`--buildings`, a `[[world]]` table's `buildings`): `overpass:` (the public Overpass
API, DEFAULT_ENDPOINT) or `overpass:https://host/api/interpreter` (any instance).

The query: every way and multipolygon relation tagged `building` or `building:part` in the
area (west, south, east, north deg: the world's, app.world.build.world_box), snapped outward
to SNAP_DEG so that a pre-fetch (`geofuse cache CLIP`) and the scene ask the same; `out body;
>; out skel qt;` as OSM XML, which app.scene.city.osm reads. It is POSTed with geofuse's
User-Agent, gzip accepted, within the world's time (timeout_s). Overpass's usage policy asks for
fair use: one query per scene, kept in the cache (as long as its headers say, else the cache's
default) and used stale when the server cannot be reached; an area larger than MAX_AREA_KM2
is refused (said with its size).

Faults, each said once and survived (the scene opens without the buildings): a server too busy
(429, 503, 504: a Retry-After honoured up to RETRY_WAIT_MAX_S, RETRIES times), an error remark
in the answer (Overpass's runtime errors: time-out, out of memory), a refused query (400, its
error said), an answer that is not OSM XML, time-outs and network errors; an answer without a
building is said ("no buildings in the area") and kept.
"""

from __future__ import annotations

import hashlib
import html
import math
import os
import re
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from http.client import HTTPException
from pathlib import Path

from app.core.compression import DamagedGzip, gunzipped
from app.core.messages import Messages
from app.scene.layers import Layer
from app.world.cache import TileCache
from app.world.fetch import USER_AGENT, retry_after_s
from app.world.grids import WGS84_GEOD
from app.world.sources import SourceError

PREFIX = "overpass:"
DEFAULT_ENDPOINT = "https://overpass-api.de/api/interpreter"
ATTRIBUTION = "(c) OpenStreetMap contributors (ODbL)"
MAX_AREA_KM2 = 25.0  # one query asks for at most this much ground
SNAP_DEG = 1e-4  # the area's edges are snapped outward to this grid (about 11 m)
RETRIES = 2  # a too-busy answer with Retry-After is asked again at most this many times
RETRY_WAIT_MAX_S = 30.0  # a Retry-After longer than this is not waited for
BUSY = (429, 503, 504)  # Overpass's "too many requests" and "too busy" (gateway time-out)
QUERY_TIMEOUT_S = (10, 180)  # the [timeout:] the query gives the server: the world's, within
KEPT_AT = (0, 0, 0)  # where the answer lies in its cache folder (one answer a folder)
FOLDER = "buildings"  # under the cache's worlds/: the answers as .osm files the reader opens
_REMARK = re.compile(rb"<remark>(.*?)</remark>", re.S)
_ELEMENT = re.compile(rb"<(?:way|relation)[\s>/]")
_TAG = re.compile(r"<[^>]+>")
_SPACE_BEFORE = re.compile(r"\s+([:;,.!?])")


@dataclass(frozen=True)
class OverpassSource:
    """An Overpass API's interpreter URL (endpoint), and what its data must be credited with."""

    endpoint: str = DEFAULT_ENDPOINT
    attribution: str = ATTRIBUTION

    @property
    def label(self) -> str:
        """The endpoint as messages name it: host and path, no query."""
        parts = urllib.parse.urlsplit(self.endpoint)
        return f"{parts.netloc}{parts.path}"

    def kept(self, identity: str) -> bool:
        """Whether a cache identity (app.world.cache.KeptSource) is an answer of this source."""
        kind, form, _, rest = (identity.split("|", 3) + ["", "", ""])[:4]
        return (kind, form) == ("buildings", "overpass") and rest.startswith(self.endpoint + " ")


@dataclass(frozen=True)
class Answer:
    """A query's answer: the OSM XML file the city reader opens (None: no building in it),
    whether it came from the cache (stale: kept past its freshness, the server unreachable),
    its size (B) and the area asked for (km2)."""

    path: Path | None
    from_cache: bool
    stale: bool
    size: int
    area_km2: float


def is_overpass(text: str) -> bool:
    """Whether a --buildings value names an Overpass API (`overpass:` before it)."""
    return text.strip().lower().startswith(PREFIX)


def parse_overpass(text: str) -> OverpassSource:
    """The source `overpass:` or `overpass:URL` names. Raises SourceError saying what is
    expected."""
    if not is_overpass(text):
        raise SourceError(
            f"buildings source {text.strip()!r}: expected overpass: or overpass:URL (a local "
            "buildings file is --buildings FILE, or a [[layers]] path of a manifest)"
        )
    rest = text.strip()[len(PREFIX) :].strip()
    if not rest:
        return OverpassSource()
    parts = urllib.parse.urlsplit(rest)
    if parts.scheme.lower() not in ("http", "https") or not parts.netloc:
        raise SourceError(
            f"buildings source {text.strip()!r}: expected overpass: alone (the public Overpass "
            "API) or overpass:https://HOST/api/interpreter"
        )
    return OverpassSource(rest)


def snapped(box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """(west, south, east, north) deg snapped outward to SNAP_DEG (an edge within a millionth of
    a step of the grid stays on it)."""
    west, south, east, north = box
    down = [math.floor(v / SNAP_DEG + 1e-6) * SNAP_DEG for v in (west, south)]
    up = [math.ceil(v / SNAP_DEG - 1e-6) * SNAP_DEG for v in (east, north)]
    return down[0], down[1], up[0], up[1]


def area_km2(box: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(area km2, width km along its middle latitude, height km) of a (west, south, east, north)
    deg box on the WGS84 ellipsoid."""
    west, south, east, north = box
    area, _ = WGS84_GEOD.polygon_area_perimeter(
        [west, east, east, west], [south, south, north, north]
    )
    mid = (south + north) / 2.0
    width = WGS84_GEOD.inv(west, mid, east, mid)[2]
    height = WGS84_GEOD.inv(west, south, west, north)[2]
    return abs(area) / 1e6, width / 1e3, height / 1e3


def overpass_query(box: tuple[float, float, float, float], timeout_s: float) -> tuple[str, str]:
    """(settings, body) of the Overpass QL query for the buildings in a (west, south, east,
    north) deg box (snapped already); the body names the answer in the cache."""
    west, south, east, north = box
    lo, hi = QUERY_TIMEOUT_S
    settings = f"[out:xml][timeout:{int(min(max(timeout_s, lo), hi))}]"
    body = (
        f"[bbox:{south:.4f},{west:.4f},{north:.4f},{east:.4f}];\n"
        "(\n"
        '  way["building"];\n'
        '  way["building:part"];\n'
        '  relation["building"]["type"="multipolygon"];\n'
        '  relation["building:part"]["type"="multipolygon"];\n'
        ");\n"
        "out body;\n>;\nout skel qt;\n"
    )
    return settings, body


class _Fault(Exception):
    """Why an answer could not be had (its words, for the message)."""


def _text(data: bytes, most: int = 200) -> str:
    """An error page's or remark's words: tags dropped, entities read, spaces folded."""
    words = " ".join(html.unescape(_TAG.sub(" ", data.decode("utf-8", "replace"))).split())
    words = _SPACE_BEFORE.sub(r"\1", words)
    return words[:most] + ("..." if len(words) > most else "")


def _gunzipped(raw: bytes, headers: dict[str, str]) -> bytes:
    """A body as sent, gunzipped where it is gzip (headers: keys lower case); raises _Fault for
    a damaged one."""
    try:
        return gunzipped(raw, headers.get("content-encoding", "").lower() == "gzip")
    except DamagedGzip as exc:
        raise _Fault(f"sent a damaged gzip answer ({exc})") from None


def _http_error_text(exc: urllib.error.HTTPError) -> str:
    """What Overpass said with an HTTP error: its page's 'Error:' line, else its first words."""
    try:
        headers = {k.lower(): v for k, v in (exc.headers or {}).items()}
        body = _gunzipped(exc.read(), headers)
    except (OSError, HTTPException, _Fault):
        body = b""
    text = _text(body, 400)
    at = text.find("Error:")
    return text[at:][:200] if at >= 0 else text[:200]


class OverpassFetch:
    """One query for the buildings of a box, through the cache; clock and sleep injected (s)."""

    def __init__(
        self,
        source: OverpassSource,
        cache: TileCache,
        timeout_s: float,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.source, self.cache, self.timeout_s = source, cache, timeout_s
        self.clock, self.sleep = clock, sleep
        self.requests = 0

    def identity(self, body: str) -> str:
        """The answer's name in the cache: the endpoint and the query's body (its bbox)."""
        digest = hashlib.sha256(f"{self.source.endpoint}\n{body}".encode()).hexdigest()[:16]
        bbox = body.split("]", 1)[0].removeprefix("[bbox:")
        return f"buildings|overpass|{digest}|{self.source.endpoint} bbox {bbox}"

    def answer(
        self, box: tuple[float, float, float, float], messages: Messages, what: str
    ) -> Answer | None:
        """The buildings of the (west, south, east, north) deg box (snapped outward), or None
        where they cannot be had (said once in `messages` under `what`, e.g. "world x
        buildings"); an answer without a building is said and returned with path None."""
        box = snapped(box)
        km2, w_km, h_km = area_km2(box)
        where = f"Overpass ({self.source.label})"
        if km2 > MAX_AREA_KM2:
            messages.add_once(
                f"world-buildings {what}",
                f"{what}: the area is {km2:.1f} km² ({w_km:.1f} x {h_km:.1f} km), more than the "
                f"{MAX_AREA_KM2:.0f} km² one query to {where} may ask for (fair use): the scene "
                "opens without its buildings; give an extract instead (--buildings FILE.osm.pbf)",
            )
            return None
        settings, body = overpass_query(box, self.timeout_s)
        identity = self.identity(body)
        cached = self.cache.get(identity, *KEPT_AT)
        kept = None if cached is None else cached.data
        key = f"world-buildings {what}"
        stale = False
        if kept is not None and cached.fresh:
            data, from_cache = kept, True
        else:
            try:
                data = self._fetch(settings + body, identity, cached.etag if cached else None)
            except _Fault as exc:
                if kept is None:
                    messages.add_once(
                        key, f"{what}: {where} {exc}: the scene opens without its buildings"
                    )
                    return None
                messages.add_once(
                    key, f"{what}: {where} {exc}: its answer kept in the cache (stale) is used"
                )
                data, stale = kept, True
            from_cache = data is None or stale
            data = kept if data is None else data  # None: unchanged (304)
        size = len(data)
        if not _ELEMENT.search(data):
            messages.add_once(
                key, f"{what}: no buildings in the area ({km2:.2f} km² around the track) on {where}"
            )
            return Answer(None, from_cache, stale, size, km2)
        path = self._kept_file(identity, box, data, fresh_copy=not from_cache)
        messages.info(
            f"{what}: OpenStreetMap buildings over {km2:.2f} km² ({w_km:.1f} x {h_km:.1f} km) "
            f"from {where}, {size / 1e3:.0f} kB "
            + ("from the cache" if from_cache else "fetched (kept in the cache)")
        )
        return Answer(path, from_cache, stale, size, km2)

    def _kept_file(self, identity: str, box, data: bytes, fresh_copy: bool) -> Path:
        """The answer as an .osm file under the cache's worlds/ folder (written when new)."""
        west, south, east, north = box
        digest = identity.split("|")[2]
        name = f"overpass-{south:.4f}_{west:.4f}_{north:.4f}_{east:.4f}.osm"
        path = self.cache.root / "worlds" / FOLDER / digest / name
        if fresh_copy or not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{name}.{os.getpid()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, path)
        return path

    def _fetch(self, query: str, identity: str, etag: str | None) -> bytes | None:
        """The answer to `query` from the server, kept in the cache; None where the server says
        the kept one is unchanged (304). Raises _Fault saying why none could be had."""
        deadline = self.clock() + self.timeout_s
        headers = {
            "User-Agent": USER_AGENT,
            "Accept-Encoding": "gzip",
            "Content-Type": "application/x-www-form-urlencoded; charset=utf-8",
        }
        if etag:
            headers["If-None-Match"] = etag
        payload = urllib.parse.urlencode({"data": query}).encode()
        for attempt in range(RETRIES + 1):
            left = deadline - self.clock()
            if left <= 0:
                raise _Fault("did not answer within the time allowed (timeout_s)")
            request = urllib.request.Request(self.source.endpoint, payload, headers, method="POST")
            self.requests += 1
            try:
                with urllib.request.urlopen(request, timeout=left) as resp:
                    raw = resp.read()
                    got = {k.lower(): v for k, v in resp.headers.items()}
            except urllib.error.HTTPError as exc:
                got = {k.lower(): v for k, v in (exc.headers or {}).items()}
                if exc.code == 304:
                    self.cache.refresh(identity, *KEPT_AT, got)
                    return None
                if exc.code not in BUSY:
                    raise _Fault(
                        f"refused the query (HTTP {exc.code}: {_http_error_text(exc)})"
                    ) from None
                wait = retry_after_s(got["retry-after"]) if "retry-after" in got else None
                busy = f"is too busy (HTTP {exc.code})"
                if wait is None:
                    raise _Fault(f"{busy}; try again later") from None
                if wait > min(RETRY_WAIT_MAX_S, deadline - self.clock()):
                    raise _Fault(f"{busy} and asks to wait {wait:.0f} s; try again later") from None
                if attempt == RETRIES:
                    raise _Fault(
                        f"{busy} after waiting {RETRIES} times as asked; try again later"
                    ) from None
                self.sleep(wait)
                continue
            except TimeoutError:
                raise _Fault("did not answer in time") from None
            except urllib.error.URLError as exc:
                raise _Fault(f"could not be reached ({exc.reason})") from None
            except (HTTPException, ConnectionError) as exc:
                raise _Fault(f"cut the answer off ({type(exc).__name__})") from None
            data = self._decoded(raw, got)
            self.cache.put(identity, *KEPT_AT, data, got)
            self.cache.trim()
            return data
        raise _Fault("gave no answer")  # not reached: every attempt returns or raises

    @staticmethod
    def _decoded(raw: bytes, headers: dict[str, str]) -> bytes:
        """The answer's OSM XML (gunzipped); raises _Fault for anything else, an error remark
        (Overpass's runtime errors come as 200 with a remark) included."""
        raw = _gunzipped(raw, headers)
        head = raw[:512].lstrip()
        if not (head.startswith(b"<?xml") or head.startswith(b"<osm")) or b"<osm" not in raw[:2048]:
            raise _Fault(
                f"did not answer with OSM XML ({_text(raw[:400], 120) or 'an empty answer'})"
            )
        remark = _REMARK.search(raw)
        if remark:
            raise _Fault(f"answered with an error: {_text(remark.group(1))}")
        return raw


def buildings_layers(
    source: OverpassSource,
    box: tuple[float, float, float, float],
    cache: TileCache,
    messages: Messages,
    what: str,
    timeout_s: float,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[Layer, ...]:
    """The city layer of the buildings Overpass gives for the (west, south, east, north) deg
    box, () where none could be had (said in `messages` under `what`). The layer is `fetched`:
    where none of its buildings can be drawn near the track, that is said and the scene opens
    without it."""
    answer = OverpassFetch(source, cache, timeout_s, clock, sleep).answer(box, messages, what)
    if answer is None or answer.path is None:
        return ()
    return (
        Layer.of(answer.path, attribution=source.attribution, fetched=f"{what} ({source.label})"),
    )
