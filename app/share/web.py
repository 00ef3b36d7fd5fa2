"""The browser map (issue 53): a small web server, in a thread of its own, whose page shows on a
web map (Leaflet, kept in app/share/static and served from here, never fetched from the
internet) the aircraft, its track, the live footprint, the current frame's picture, the point
of interest and the marks, updated as frames are shared (server-sent events); read-only, for any
number of browsers at once.

- Every request must carry the access token (`?token=`, or the cookie the page's first request
  sets): without it, 403. The token is random (secrets.token_urlsafe) unless given.
- Bound to the loopback (127.0.0.1) unless told otherwise (`bind`); `warning` says when it is
  not, since anyone who can reach the port and holds the URL then sees the operation.
- A browser that connects gets the current state at once (the last frame, the track so far, the
  marks), then each newer frame as an event: a slow browser skips frames, never falls behind.
- Imagery: where a world's imagery source is given (app.world), the page draws it through this
  server (`/tiles/{z}/{x}/{y}`), fetched through app.world's fetcher and disk cache, so that a
  key never reaches the browser; with none, a plain background with a grid and a scale.

Endpoints (all GET, all needing the token): `/` the page; `/state` the current state as JSON;
`/events` the event stream (`state` first, then `frame` and `marks` events); `/thumbnail.jpg`
the last frame's picture; `/tiles/Z/X/Y` imagery; `/static/...` the page's files.

Frames: coordinates as the SharedFrame gives them (app.share.frames): WGS84 degrees, heights in
metres above the ellipsoid; the footprint a GeoJSON geometry (lon, lat); the track a list of the
sensor's [lon, lat, h] as shared. Why server-sent events, not WebSocket: the map only listens,
EventSource reconnects by itself, and a plain HTTP client reads the stream; tornado (already
installed with dask's distributed) serves both.
"""

from __future__ import annotations

import asyncio
import hmac
import io
import ipaddress
import json
import math
import re
import secrets
import socket
import threading
import urllib.request
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import tornado.httpserver
import tornado.iostream
import tornado.netutil
import tornado.web
from PIL import Image

from app.core.messages import INFO, Messages
from app.share.frames import SharedFrame
from app.world.cache import TileCache
from app.world.fetch import SourceFetcher
from app.world.sources import TileSource

__all__ = [
    "DEFAULT_BIND",
    "MapServer",
    "WebMapSink",
    "bind_refusal",
    "is_loopback",
    "parse_bind",
    "read_events",
    "web_sink_maker",
]

STATIC_DIR = Path(__file__).with_name("static")
DEFAULT_BIND = ("127.0.0.1", 0)  # the loopback; port 0: a free one, chosen by the system
HEARTBEAT_S = 15.0  # an idle event stream gets a comment this often (finds browsers gone)
MAX_TRACK_POINTS = 36_000  # 2 hours at 5 Hz; past it the older half is dropped (said)
TRACK_JUMP_BACK_S = 1.0  # a frame this much earlier than the last (a loop, a scrub): a new track
TILE_JPEG_QUALITY = 85
TILE_WORKERS = 4
SHUTDOWN_S = 5.0
TOKEN_PATTERN = re.compile(r"[A-Za-z0-9._~-]{8,128}")


def parse_bind(text: str) -> tuple[str, int]:
    """`HOST:PORT` (IPv6 as `[::1]:8080`; port 0: any free one) -> (host, port). ValueError
    saying what is expected."""
    m = re.fullmatch(r"\[([0-9A-Fa-f:.]+)\]:(\d{1,5})|([^:\[\]\s]+):(\d{1,5})", text.strip())
    if m is None:
        raise ValueError(f"expected HOST:PORT (e.g. 127.0.0.1:8080, 0.0.0.0:8080), got {text!r}")
    host, port = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    if not 0 <= int(port) <= 65535:
        raise ValueError(f"port {port} is outside 0..65535")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """Whether `host` (an address or 'localhost') is reachable from this machine only."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def bind_refusal(host: str) -> str | None:
    """The warning a bind beyond the loopback deserves, None on the loopback."""
    if is_loopback(host):
        return None
    return (
        f"the browser map listens on {host}, beyond this machine: anyone who reaches the port and "
        "holds the URL (its token) sees the operation, over plain HTTP (not encrypted)"
    )


def _finite_json(value: object) -> str:
    """JSON of `value` (one line) with any NaN or infinity written as null (browsers refuse
    them)."""
    try:
        return json.dumps(value, allow_nan=False, separators=(",", ":"))
    except ValueError:
        return json.dumps(_nulled(value), separators=(",", ":"))


def _nulled(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _nulled(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_nulled(v) for v in value]
    return value


def _event(name: str, data: str) -> str:
    """One server-sent event (data: one line of JSON)."""
    return f"event: {name}\ndata: {data}\n\n"


class _Client:
    """One browser's event stream: what it has been sent (frame seq, track epoch and length,
    marks version), and the event that wakes it."""

    def __init__(self) -> None:
        self.wake = asyncio.Event()
        self.seq = -1
        self.epoch = -1
        self.track_sent = 0
        self.marks_version = -1
        self.gone = False


class MapServer:
    """See the module docstring. bind: (host, port), port 0 for any free one; token: the access
    token (None: a random one); imagery: a world's imagery source drawn under the map (None: a
    plain background); attribution: what the imagery must be credited with; messages: where
    refused requests and tile faults are said (once each)."""

    def __init__(
        self,
        bind: tuple[str, int] = DEFAULT_BIND,
        token: str | None = None,
        imagery: TileSource | None = None,
        attribution: str = "",
        messages: Messages | None = None,
    ) -> None:
        if token is not None and not TOKEN_PATTERN.fullmatch(token):
            raise ValueError(
                "a token is 8 to 128 characters of A-Z, a-z, 0-9 and . _ ~ - (it goes in a URL)"
            )
        self.host, self.port = bind
        self.token = token or secrets.token_urlsafe(18)
        self.messages = messages if messages is not None else Messages()
        if imagery is not None and not getattr(imagery, "web_mercator", True):
            self.messages.add(
                f"the browser map draws Web Mercator (XYZ) imagery only: {imagery.label} is in a grid of its own, so the map shows a plain background"
            )
            imagery = None
        self.imagery = imagery
        self.attribution = attribution or (imagery.attribution if imagery is not None else "")
        self.warning = bind_refusal(self.host)
        # counters (written in the server's thread, read anywhere)
        self.clients = 0  # event streams open now
        self.frames_published = 0
        self.delivered_index: int | None = None  # the index of the last frame a browser was sent
        self.refused = 0  # requests without the token
        # the state (the server's thread only)
        self._seq = 0
        self._frame: SharedFrame | None = None
        self._frame_json: str | None = None
        self._thumbnail: bytes | None = None
        self._track: list[list[float]] = []
        self._epoch = 0
        self._marks_json: str | None = None
        self._marks_version = 0
        self._streams: set[_Client] = set()
        self._closing = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._http: tornado.httpserver.HTTPServer | None = None
        self._tiles = ThreadPoolExecutor(TILE_WORKERS, thread_name_prefix="map-tiles")
        self._fetcher: SourceFetcher | None = None
        self._fetcher_lock = threading.Lock()

    # -- life -------------------------------------------------------------------------------------

    def start(self) -> MapServer:
        """Listen (OSError where the address cannot be had: said at once) and serve in a thread."""
        sockets = tornado.netutil.bind_sockets(self.port, address=self.host)
        self.port = sockets[0].getsockname()[1]
        ready = threading.Event()
        self._thread = threading.Thread(
            target=self._serve, args=(sockets, ready), name="browser-map", daemon=True
        )
        self._thread.start()
        ready.wait()
        return self

    @property
    def address(self) -> str:
        """host:port listened on."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    @property
    def url(self) -> str:
        """The page's URL with its token (a bind to every interface named by this machine's
        name)."""
        host = self.host
        if host in ("0.0.0.0", "::", ""):
            host = socket.gethostname()
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.port}/?token={self.token}"

    def close(self) -> None:
        """Stop serving: the event streams ended, the port released (from any thread)."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or self._closing:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(SHUTDOWN_S + 1.0)
        except Exception:  # a loop already gone: nothing left to stop
            pass
        try:
            loop.call_soon_threadsafe(loop.stop)
        except RuntimeError:
            pass
        thread.join(SHUTDOWN_S)
        self._tiles.shutdown(wait=False, cancel_futures=True)
        if self._fetcher is not None:
            self._fetcher.close()

    def _serve(self, sockets: list[socket.socket], ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        try:
            self._http = tornado.httpserver.HTTPServer(self._application())
            self._http.add_sockets(sockets)
        finally:
            ready.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _shutdown(self) -> None:
        self._closing = True
        for client in list(self._streams):
            client.wake.set()
        if self._http is not None:
            self._http.stop()
            await asyncio.sleep(0.05)  # the streams end their responses
            try:
                await asyncio.wait_for(self._http.close_all_connections(), SHUTDOWN_S)
            except TimeoutError:
                pass

    def _application(self) -> tornado.web.Application:
        kw = {"server": self}
        return tornado.web.Application(
            [
                (r"/", _Page, kw),
                (r"/state", _State, kw),
                (r"/events", _Events, kw),
                (r"/thumbnail\.jpg", _Thumbnail, kw),
                (r"/tiles/(\d+)/(\d+)/(\d+)", _Tiles, kw),
                (r"/static/(.*)", _Static, {**kw, "path": str(STATIC_DIR)}),
            ],
            default_handler_class=_Missing,
            default_handler_args=kw,
            log_function=self._logged,
            compress_response=False,
        )

    # -- what is shared (from any thread) ----------------------------------------------------------

    def publish_frame(self, frame: SharedFrame) -> None:
        """A frame shared: the map's newest (returns at once; the server's thread takes it)."""
        self._call(self._on_frame, frame)

    def publish_marks(self, marks: dict) -> None:
        """The marks (a GeoJSON FeatureCollection, lon/lat) as they are now."""
        self._call(self._on_marks, marks)

    def _call(self, fn: Callable, *args) -> None:
        loop = self._loop
        if loop is None or self._closing:
            return
        try:
            loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:  # closed meanwhile
            pass

    # -- the state (the server's thread) -----------------------------------------------------------

    def _on_frame(self, frame: SharedFrame) -> None:
        last = self._frame
        if last is not None and (
            frame.clip != last.clip or frame.media_s < last.media_s - TRACK_JUMP_BACK_S
        ):
            self._track, self._epoch = [], self._epoch + 1  # another clip, or back in time
        self._track.append([frame.sensor[1], frame.sensor[0], frame.sensor[2]])
        if len(self._track) > MAX_TRACK_POINTS:
            self._track, self._epoch = self._track[len(self._track) // 2 :], self._epoch + 1
            self.messages.add_once(
                "map-track",
                f"the browser map's track passed {MAX_TRACK_POINTS} positions: its older half is no longer drawn",
                INFO,
            )
        self._frame = frame
        self._frame_json = _finite_json(frame.as_dict())
        self._thumbnail = frame.thumbnail
        self._seq += 1
        self.frames_published += 1
        self._wake_all()

    def _on_marks(self, marks: dict) -> None:
        self._marks_json = _finite_json(marks)
        self._marks_version += 1
        self._wake_all()

    def _wake_all(self) -> None:
        for client in self._streams:
            client.wake.set()

    def map_config(self) -> dict[str, object]:
        """What the page needs to set itself up: the imagery (None: a plain background), its
        finest zoom and credit; never where it comes from (its address, its key)."""
        imagery = None
        if self.imagery is not None:
            imagery = {
                "max_zoom": int(self.imagery.max_zoom),
                "attribution": self.attribution,
            }
        return {"imagery": imagery, "loopback": self.warning is None}

    def state_json(self) -> str:
        """The whole state as JSON: seq, frame (or null), track, track_epoch, marks, map."""
        if self._frame is not None:
            self.delivered_index = self._frame.index
        return (
            f'{{"seq":{self._seq},"track_epoch":{self._epoch},'
            f'"frame":{self._frame_json or "null"},"track":{_finite_json(self._track)},'
            f'"marks":{self._marks_json or "null"},"map":{_finite_json(self.map_config())}}}'
        )

    def _events_for(self, client: _Client) -> list[str]:
        """What `client` has not been sent yet: the marks if newer, the newest frame with the
        track points it lacks."""
        out = []
        if client.marks_version != self._marks_version and self._marks_json is not None:
            out.append(_event("marks", f'{{"marks":{self._marks_json}}}'))
            client.marks_version = self._marks_version
        if client.seq != self._seq and self._frame_json is not None:
            start = client.track_sent if client.epoch == self._epoch else 0
            points = _finite_json(self._track[start:])
            out.append(
                _event(
                    "frame",
                    f'{{"seq":{self._seq},"track_epoch":{self._epoch},"track_start":{start},'
                    f'"track":{points},"frame":{self._frame_json}}}',
                )
            )
            client.seq, client.epoch, client.track_sent = self._seq, self._epoch, len(self._track)
            self.delivered_index = self._frame.index
        return out

    def _first_events(self, client: _Client) -> str:
        """The state event a new stream starts with (it then holds everything up to now)."""
        client.seq, client.epoch, client.track_sent = self._seq, self._epoch, len(self._track)
        client.marks_version = self._marks_version
        return _event("state", self.state_json())

    # -- requests ----------------------------------------------------------------------------------

    def authorised(self, handler: tornado.web.RequestHandler) -> bool:
        given = handler.get_query_argument("token", None) or handler.get_cookie(
            self.cookie_name, None
        )
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    @property
    def cookie_name(self) -> str:
        return f"geofuse-map-{self.port}"

    def _logged(self, handler: tornado.web.RequestHandler) -> None:
        """Tornado's access log, replaced: a request refused is said once per address."""
        if handler.get_status() == 403:
            self.refused += 1
            ip = handler.request.remote_ip
            self.messages.add_once(
                f"map-refused {ip}",
                f"the browser map refused a request from {ip} without the right token ({handler.request.path})",
            )

    def tile_jpeg(self, z: int, x: int, y: int) -> bytes | None:
        """Imagery tile (z, x, y) (XYZ rows) as JPEG through app.world's fetcher and cache; None
        where it cannot be had (a fault said once)."""
        source = self.imagery
        n = 1 << z
        if source is None or not (0 <= z <= source.max_zoom and 0 <= x < n and 0 <= y < n):
            return None
        with self._fetcher_lock:
            if self._fetcher is None:
                self._fetcher = SourceFetcher(source, TileCache(), math.inf)
            fetcher = self._fetcher
        rgb = fetcher.get(z, x, y)
        if rgb is None:
            fetcher.report(self.messages, "the browser map's imagery")
            return None
        out = io.BytesIO()
        Image.fromarray(rgb).save(out, "JPEG", quality=TILE_JPEG_QUALITY)
        return out.getvalue()


class _Handler(tornado.web.RequestHandler):
    """Every handler: the token checked first (403 without it), nothing cached, no referrer."""

    server: MapServer

    def initialize(self, server: MapServer, **kwargs) -> None:
        self.server = server

    def prepare(self) -> None:
        if not self.server.authorised(self):
            raise tornado.web.HTTPError(403)

    def set_default_headers(self) -> None:
        self.set_header("Cache-Control", "no-store")
        self.set_header("X-Content-Type-Options", "nosniff")
        self.set_header("Referrer-Policy", "no-referrer")
        self.set_header("X-Frame-Options", "DENY")

    def write_error(self, status_code: int, **kwargs) -> None:
        self.set_header("Content-Type", "text/plain; charset=utf-8")
        why = {
            403: "the browser map needs its access token: open the URL geofuse printed, with its ?token=",
            404: "not found",
        }
        self.finish(f"{status_code}: {why.get(status_code, self._reason)}\n")


class _Page(_Handler):
    def get(self) -> None:
        s = self.server
        given = self.get_query_argument("token", None)
        if given is not None:  # for what the page's style sheets fetch by themselves
            self.set_cookie(s.cookie_name, given, httponly=True, samesite="Strict", path="/")
        html = (STATIC_DIR / "index.html").read_text(encoding="utf-8")
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.set_header(
            "Content-Security-Policy",
            "default-src 'self'; img-src 'self' data: blob:; style-src 'self' 'unsafe-inline'; "
            "connect-src 'self'; frame-ancestors 'none'",
        )
        self.finish(html.replace("__TOKEN__", s.token))


class _State(_Handler):
    def get(self) -> None:
        self.set_header("Content-Type", "application/json")
        self.finish(self.server.state_json())


class _Thumbnail(_Handler):
    def get(self) -> None:
        jpeg = self.server._thumbnail
        if jpeg is None:
            raise tornado.web.HTTPError(404)
        self.set_header("Content-Type", "image/jpeg")
        self.finish(jpeg)


class _Events(_Handler):
    """The event stream: `state` at once, then `frame` and `marks` as they come."""

    client: _Client | None = None

    async def get(self) -> None:
        s = self.server
        self.set_header("Content-Type", "text/event-stream")
        self.set_header("X-Accel-Buffering", "no")
        client = self.client = _Client()
        s._streams.add(client)
        s.clients = len(s._streams)
        try:
            self.write("retry: 2000\n" + s._first_events(client))
            await self.flush()
            while not s._closing and not client.gone:
                try:
                    await asyncio.wait_for(client.wake.wait(), HEARTBEAT_S)
                except TimeoutError:
                    self.write(": still here\n\n")
                    await self.flush()
                    continue
                client.wake.clear()
                if s._closing or client.gone:
                    break
                events = s._events_for(client)
                if events:
                    self.write("".join(events))
                    await self.flush()
        except tornado.iostream.StreamClosedError:
            pass
        finally:
            s._streams.discard(client)
            s.clients = len(s._streams)

    def on_connection_close(self) -> None:
        if self.client is not None:
            self.client.gone = True
            self.client.wake.set()


class _Tiles(_Handler):
    async def get(self, z: str, x: str, y: str) -> None:
        s = self.server
        loop = asyncio.get_running_loop()
        jpeg = await loop.run_in_executor(s._tiles, s.tile_jpeg, int(z), int(x), int(y))
        if jpeg is None:
            raise tornado.web.HTTPError(404)
        self.set_header("Content-Type", "image/jpeg")
        self.set_header("Cache-Control", "private, max-age=3600")
        self.finish(jpeg)


class _Static(_Handler, tornado.web.StaticFileHandler):
    """The page's files and the kept Leaflet, behind the token like everything else."""

    def initialize(self, server: MapServer, path: str, **kwargs) -> None:
        self.server = server
        tornado.web.StaticFileHandler.initialize(self, path)

    def set_extra_headers(self, path: str) -> None:
        self.set_header("Cache-Control", "private, max-age=600")


class _Missing(_Handler):
    """Any other path: 403 without the token, 404 with it."""

    def get(self) -> None:
        raise tornado.web.HTTPError(404)


class WebMapSink:
    """A sharing hub's sink (app.share.hub.Sink) feeding a MapServer; owns: close the server
    when the sink is closed (a server made for one run), else leave it serving (one the viewer
    keeps across sessions)."""

    def __init__(self, server: MapServer, owns: bool = False) -> None:
        self.server, self.owns = server, owns
        self.name = f"the browser map {server.address}"

    def send_frame(self, frame: SharedFrame) -> None:
        self.server.publish_frame(frame)

    def send_marks(self, marks: dict) -> None:
        self.server.publish_marks(marks)

    def close(self) -> None:
        if self.owns:
            self.server.close()


def web_sink_maker(server: MapServer) -> Callable[[Messages], WebMapSink]:
    """A sink maker (LiveOptions.sinks, viewer Options.sinks, ViewerShare.add) whose sinks feed
    `server` and leave it serving when their hub closes."""

    def make(messages: Messages) -> WebMapSink:
        return WebMapSink(server)

    return make


def read_events(url: str, timeout_s: float = 60.0) -> Iterator[tuple[str, dict]]:
    """(event name, its data) of a map's event stream (`URL/events?token=...`) as they come,
    until the server ends it: a plain client of the map (the tests' and the benchmark's), no
    browser needed. urllib.error.HTTPError where it is refused (403 without the token);
    TimeoutError where nothing, not even the keep-alive comment, comes for timeout_s."""
    with urllib.request.urlopen(url, timeout=timeout_s) as response:
        name, data = "message", []
        for raw in response:
            line = raw.decode("utf-8").rstrip("\r\n")
            if not line:
                if data:
                    yield name, json.loads("\n".join(data))
                name, data = "message", []
            elif not line.startswith(":"):
                key, _, value = line.partition(":")
                value = value[1:] if value.startswith(" ") else value
                if key == "event":
                    name = value
                elif key == "data":
                    data.append(value)
