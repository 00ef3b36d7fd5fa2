"""OpenStreetMap buildings fetched for a clip's area from an Overpass API (issue 48): a server on
the loopback plays Overpass (it reads the POSTed query, answers OSM XML written here, or the
faults Overpass has); the buildings stand at their tags in the session's ENU frame, a second
open is served from the cache with the server stopped, and every fault is said once while the
scene opens. No test reaches the internet, nor waits on the wall clock."""

from __future__ import annotations

import gzip
import math
import re
import threading
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.footage.clips import open_any
from app.geodesy.enu import LocalFrame
from app.world.build import MAX_REACH_M, world_layer
from app.world.cache import DEFAULT_FRESH_S, TileCache
from app.world.grids import M_PER_DEG_LAT
from app.world.overpass import (
    DEFAULT_ENDPOINT,
    MAX_AREA_KM2,
    RETRIES,
    RETRY_WAIT_MAX_S,
    SNAP_DEG,
    OverpassFetch,
    OverpassSource,
)
from app.world.settings import choose_world, manifest_world
from tests.test_osm_buildings import FRAME as OSM_FRAME
from tests.test_osm_buildings import _roof_and_floor, drone_clip  # noqa: F401 (a fixture)
from tests.test_world import _own_folders  # noqa: F401 (autouse: the test's own folders)

# The clip (test_osm_buildings' drone_clip) hovers 80 m over its take-off point, heights above
# take-off: the ground is at 0 m ellipsoidal there, and the session's ENU origin is that point
# as its subtitle prints it (8 decimals).
LAT, LON = (float(f"{v:.8f}") for v in OSM_FRAME.enu_to_geodetic(np.array([10.0, 5.0, 0.0]))[:2])
FRAME = LocalFrame(LAT, LON, 0.0)
HEIGHT_M = 80.0
REACH_M = min(500.0 + 10.0 * HEIGHT_M, MAX_REACH_M)  # a flown camera sees 500 m + 10x its height

# Buildings (ENU m of FRAME): A height=12, B building:levels=5 (3 m a level), C a multipolygon
# of one outer way, height "7.5 m"; none under the take-off point.
NODES = {
    1: (10, 10), 2: (30, 10), 3: (30, 20), 4: (10, 20),
    5: (-40, 5), 6: (-25, 5), 7: (-25, 17), 8: (-40, 17),
    9: (40, -30), 10: (60, -30), 11: (60, -12), 12: (40, -12),
}  # fmt: skip
WAYS = [
    (100, [1, 2, 3, 4, 1], {"building": "yes", "height": "12", "name": "Hall A"}),
    (101, [5, 6, 7, 8, 5], {"building": "office", "building:levels": "5"}),
]
RELATIONS = [(200, [110], {"type": "multipolygon", "building": "yes", "height": "7.5 m"})]
MEMBER_WAYS = [(110, [9, 10, 11, 12, 9])]  # sent by `>; out skel`: no tags
HEIGHTS = {"way/100": 12.0, "way/101": 15.0, "relation/200": 7.5}
FAR_NODES = {1: (1200, 1200), 2: (1220, 1200), 3: (1220, 1210), 4: (1200, 1210)}  # 1.7 km off

HEAD = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<osm version="0.6" generator="Overpass API 0.7.62.1 084b4234">\n'
    "<note>The data included in this document is from www.openstreetmap.org. "
    "The data is made available under ODbL.</note>\n"
    '<meta osm_base="2024-05-01T12:00:00Z"/>\n'
)
EMPTY = HEAD + "</osm>\n"
REMARK = (
    HEAD + '<remark> runtime error: Query timed out in "query" at line 3 after 26 seconds. '
    "</remark>\n</osm>\n"
)


def overpass_xml(nodes=NODES, ways=WAYS, relations=RELATIONS, members=MEMBER_WAYS) -> str:
    """OSM XML as Overpass answers `out body; >; out skel qt;`: the buildings with their tags,
    then their member ways and nodes (skel: no tags)."""
    lines = [HEAD]

    def tags(t: dict) -> list[str]:
        return [f'    <tag k="{k}" v="{v}"/>' for k, v in t.items()]

    for wid, refs, t in ways:
        lines += [f'  <way id="{wid}">', *(f'    <nd ref="{r}"/>' for r in refs), *tags(t)]
        lines.append("  </way>")
    for rid, refs, t in relations:
        lines.append(f'  <relation id="{rid}">')
        lines += [f'    <member type="way" ref="{r}" role="outer"/>' for r in refs]
        lines += [*tags(t), "  </relation>"]
    for nid, xy in nodes.items():
        lat, lon, _ = FRAME.enu_to_geodetic(np.array([*xy, 0.0], np.float64))
        lines.append(f'  <node id="{nid}" lat="{lat:.9f}" lon="{lon:.9f}"/>')
    for wid, refs in members:
        lines += [f'  <way id="{wid}">', *(f'    <nd ref="{r}"/>' for r in refs), "  </way>"]
    return "\n".join([*lines, "</osm>"]) + "\n"


class OverpassServer:
    """An Overpass API on the loopback at {url}: POST data=QUERY. answers: (status, body,
    headers) given to the next requests in turn, then `default` (200, overpass_xml()); log: a
    dict per request (bbox (S, W, N, E), query, user_agent, gzip: the answer was gzipped)."""

    def __init__(self) -> None:
        self.answers: list[tuple[int, str, dict]] = []
        self.default: tuple[int, str, dict] = (200, overpass_xml(), {})
        self.log: list[dict] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_POST(self) -> None:  # noqa: N802 (http.server's name)
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                query = urllib.parse.parse_qs(body.decode())["data"][0]
                bbox = re.search(r"\[bbox:([^\]]+)\]", query)
                status, text, headers = server.answers.pop(0) if server.answers else server.default
                data = text.encode()
                zipped = "gzip" in self.headers.get("Accept-Encoding", "")
                if zipped:
                    data = gzip.compress(data)
                    headers = {**headers, "Content-Encoding": "gzip"}
                server.log.append(
                    {
                        "bbox": tuple(map(float, bbox.group(1).split(","))) if bbox else None,
                        "query": query,
                        "user_agent": self.headers.get("User-Agent", ""),
                        "gzip": zipped,
                        "path": self.path,
                    }
                )
                self.send_response(status)
                for k, v in headers.items():
                    self.send_header(k, v)
                self.send_header("Content-Type", "application/osm3s+xml")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/api/interpreter"
        self.thread = threading.Thread(
            target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True
        )
        self.thread.start()
        self.stopped = False

    def stop(self) -> None:
        if not self.stopped:
            self.stopped = True
            self.httpd.shutdown()
            self.httpd.server_close()


@pytest.fixture
def server():
    s = OverpassServer()
    yield s
    s.stop()


def _open(clip: Path, url: str):
    """The clip opened with `--buildings overpass:URL`'s world (as the commands open it)."""
    return open_any(clip, layers=(world_layer(choose_world(buildings=f"overpass:{url}")),))


def _clip_box() -> tuple[float, float, float, float]:
    """(S, W, N, E) deg of the clip's area worked out by hand: its one fix plus REACH_M, metres
    to degrees as the world's area takes them (M_PER_DEG_LAT, its cosine of the latitude)."""
    dlat = REACH_M / M_PER_DEG_LAT
    dlon = REACH_M / (M_PER_DEG_LAT * math.cos(math.radians(LAT)))
    return LAT - dlat, LON - dlon, LAT + dlat, LON + dlon


def _assert_holds_the_clips_area(bbox: tuple[float, ...]) -> None:
    """The query's box holds the clip's area, at most a snapping step (SNAP_DEG, outward) and
    the subtitle's last printed digit (1e-8 deg) larger on each side."""
    s, w, n, e = _clip_box()
    tol = SNAP_DEG + 1e-8
    got_s, got_w, got_n, got_e = bbox
    assert 0.0 <= s - got_s < tol and 0.0 <= w - got_w < tol, (bbox, (s, w, n, e))
    assert 0.0 <= got_n - n < tol and 0.0 <= got_e - e < tol, (bbox, (s, w, n, e))


def _check_roofs(session) -> None:
    """Each building's floor on the take-off ground (ENU z 0 at the origin) and its roof at its
    height tag above it, within 1 cm, in the session's ENU frame."""
    assert (session.frame.lat_deg, session.frame.lon_deg, session.frame.h_m) == (LAT, LON, 0.0)
    for oid, height in HEIGHTS.items():
        roof, floor = _roof_and_floor(session.mesh, oid)
        assert floor == pytest.approx(0.0, abs=0.01), oid
        assert roof == pytest.approx(height, abs=0.01), oid


def test_buildings_fetched_for_the_clip_stand_at_their_tags_and_reopen_offline(
    server,
    drone_clip,  # noqa: F811
    tmp_path,
    capsys,
):
    out = tmp_path / "poses.csv"
    args = ["solve", str(drone_clip), "--buildings", f"overpass:{server.url}", "--out", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "world given buildings: OpenStreetMap buildings over" in err and "fetched" in err
    assert "no scene given" not in err and "meets an assumed flat ground" in err
    (asked,) = server.log
    _assert_holds_the_clips_area(asked["bbox"])
    assert (
        "geofuse" in asked["user_agent"] and asked["gzip"] and asked["path"] == "/api/interpreter"
    )
    q = asked["query"]
    for part in ('way["building"]', 'way["building:part"]', 'relation["building"]', "out body;"):
        assert part in q
    assert q.index("out body;") < q.index(">;") < q.index("out skel qt;")

    server.stop()  # the second open: from the cache, with nothing to ask
    session = _open(drone_clip, server.url)
    _check_roofs(session)
    notes = "\n".join(session.messages.items)
    assert "from the cache" in notes and len(server.log) == 1
    assert not any(w for w in session.messages.of("warning") if "Overpass" in w or "buildings" in w)


def test_geofuse_cache_pre_fetches_the_buildings_a_clip_will_open_offline(
    server,
    drone_clip,  # noqa: F811
    tmp_path,
    capsys,
):
    area = tmp_path / "area.mbtiles"
    args = ["cache", str(drone_clip), "--buildings", f"overpass:{server.url}", "--out", str(area)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    osm = tmp_path / "area-buildings.osm"
    assert f"wrote {osm}: 1 buildings answer" in printed and f"--buildings {osm}" in printed
    assert osm.read_text() == overpass_xml()
    (asked,) = server.log
    _assert_holds_the_clips_area(asked["bbox"])
    server.stop()
    session = _open(drone_clip, server.url)  # the query the scene asks is the one pre-fetched
    _check_roofs(session)
    assert "from the cache" in "\n".join(session.messages.items) and len(server.log) == 1
    folder = tmp_path / "config" / "geofuse"
    folder.mkdir(parents=True)
    (folder / "settings.toml").write_text(
        f'[[world]]\nname = "osm"\nbuildings = "overpass:{server.url}"\n'
    )
    capsys.readouterr()
    assert main(["cache", "--clear", "osm"]) == 0  # a world's answers go with it
    assert f"removed buildings {server.url} bbox" in capsys.readouterr().out


class Clock:
    """A clock (s) that moves only when slept on; `slept` lists the waits asked for."""

    def __init__(self) -> None:
        self.t, self.slept = 1000.0, []

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s


BOX = (LON - 0.01, LAT - 0.01, LON + 0.01, LAT + 0.01)  # W, S, E, N: about 3 km2


def _fetch(server: OverpassServer, tmp_path: Path, clock: Clock | None = None, cache=None):
    clock = clock or Clock()
    cache = cache or TileCache(tmp_path / "tiles")
    return OverpassFetch(OverpassSource(server.url), cache, 60.0, clock, clock.sleep), clock


def _refused(fetch: OverpassFetch, box: tuple[float, ...] = BOX) -> str:
    """The one message said where `fetch` could not have the buildings of `box`."""
    notes = Messages()
    assert fetch.answer(box, notes, "test buildings") is None
    (said,) = notes.items
    return said


def test_too_busy_is_asked_again_after_its_retry_after_then_said_once(server, tmp_path):
    server.answers = [(429, "rate limited", {"Retry-After": "7"})]
    fetch, clock = _fetch(server, tmp_path)
    notes = Messages()
    answer = fetch.answer(BOX, notes, "test buildings")
    assert clock.slept == [7.0] and len(server.log) == 2  # waited as asked, once, then had it
    assert answer is not None and answer.path is not None and not notes.of("warning")

    server.default = (429, "rate limited", {"Retry-After": "3"})  # busy for good: asked 3 times
    fetch, clock = _fetch(server, tmp_path / "other")
    said = _refused(fetch)
    assert clock.slept == [3.0] * RETRIES and fetch.requests == RETRIES + 1
    assert f"too busy (HTTP 429) after waiting {RETRIES} times" in said

    server.default = (429, "rate limited", {"Retry-After": str(int(RETRY_WAIT_MAX_S) + 570)})
    fetch, clock = _fetch(server, tmp_path / "third")
    said = _refused(fetch)
    assert clock.slept == [] and fetch.requests == 1  # longer than the bound: not waited for
    assert "asks to wait 600 s" in said and "the scene opens without its buildings" in said


def test_a_504_is_said_once_and_the_scene_opens_on_its_flat_ground(server, drone_clip):  # noqa: F811
    server.default = (504, "<html><body>Gateway Timeout</body></html>", {})
    session = _open(drone_clip, server.url)
    said = [m for m in session.messages.items if "Overpass" in m]
    assert len(said) == 1 and "too busy (HTTP 504)" in said[0]
    assert "the scene opens without its buildings" in said[0] and len(server.log) == 1
    assert any(p.name == "assumed ground" for p in session.mesh.primitives)
    assert not session.mesh.features


def test_buildings_too_far_from_the_track_are_said_and_the_scene_opens(server, drone_clip):  # noqa: F811
    server.default = (200, overpass_xml(FAR_NODES, WAYS[:1], [], []), {})
    session = _open(drone_clip, server.url)
    (said,) = [m for m in session.messages.items if "scene opens without them" in m]
    assert "world given buildings" in said and "within 1000 m of the clip's track" in said
    assert any(p.name == "assumed ground" for p in session.mesh.primitives)


def test_an_empty_answer_an_error_remark_and_a_refused_query_are_said(server, tmp_path):
    server.answers = [(200, EMPTY, {})]
    fetch, _ = _fetch(server, tmp_path)
    notes = Messages()
    answer = fetch.answer(BOX, notes, "test buildings")
    assert answer is not None and answer.path is None
    (said,) = notes.items
    assert "no buildings in the area" in said and "Overpass (127.0.0.1:" in said
    assert fetch.answer(BOX, Messages(), "again").path is None and len(server.log) == 1  # kept

    server.answers = [(200, REMARK, {}), (200, REMARK, {})]
    fetch, _ = _fetch(server, tmp_path / "remark")
    said = _refused(fetch)
    assert 'answered with an error: runtime error: Query timed out in "query" at line 3' in said
    assert fetch.answer(BOX, Messages(), "again") is None and len(server.log) == 3  # not kept

    page = '<html><body><p><strong style="color:#FF0000">Error</strong>: line 2: parse error: Unknown type "wya"</p></body></html>'
    server.answers = [(400, page, {})]
    said = _refused(_fetch(server, tmp_path / "bad")[0])
    assert 'refused the query (HTTP 400: Error: line 2: parse error: Unknown type "wya")' in said


def test_a_stale_answer_is_used_when_overpass_cannot_be_reached(server, tmp_path):
    fetch, _ = _fetch(server, tmp_path)
    first = fetch.answer(BOX, Messages(), "test buildings")
    server.stop()
    later = TileCache(tmp_path / "tiles", clock=lambda: 2e9 + DEFAULT_FRESH_S)  # long past fresh
    fetch, _ = _fetch(server, tmp_path, cache=later)
    notes = Messages()
    answer = fetch.answer(BOX, notes, "test buildings")
    assert answer is not None and answer.stale and answer.path == first.path
    (said,) = notes.of("warning")
    assert "could not be reached" in said and "kept in the cache (stale) is used" in said


def test_an_area_too_large_is_refused_with_its_size(server, tmp_path):
    """0.1 x 0.1 deg at 46 N: on a sphere of the same area, R^2 dlon (sin n - sin s), about
    86 km2, refused (MAX_AREA_KM2) without a request."""
    west, south, east, north = 7.0, 46.0, 7.1, 46.1
    r_km = 6371.0
    expected = r_km**2 * math.radians(east - west)
    expected *= math.sin(math.radians(north)) - math.sin(math.radians(south))
    assert expected > MAX_AREA_KM2
    said = _refused(_fetch(server, tmp_path)[0], (west, south, east, north))
    size = float(re.search(r"the area is ([\d.]+) km²", said).group(1))
    assert size == pytest.approx(expected, rel=0.01) and not server.log
    assert f"more than the {MAX_AREA_KM2:.0f} km²" in said


def test_the_spelling_in_options_and_settings(tmp_path, capsys, drone_clip):  # noqa: F811
    assert choose_world(buildings="overpass:").buildings == OverpassSource(DEFAULT_ENDPOINT)
    given = choose_world(buildings="overpass:https://overpass.example.org/api/interpreter")
    assert (given.name, given.imagery, given.terrain) == ("given", None, None)
    assert given.buildings.label == "overpass.example.org/api/interpreter"
    with pytest.raises(GeofuseError, match="expected overpass: alone"):
        choose_world(buildings="overpass:ftp://example.org")
    with pytest.raises(GeofuseError, match="--world none keeps the flat ground"):
        choose_world("none", buildings="overpass:")
    folder = tmp_path / "config" / "geofuse"
    folder.mkdir(parents=True)
    settings = folder / "settings.toml"
    settings.write_text('[[world]]\nname = "osm"\nbuildings = "overpass:"\n')
    assert choose_world("osm").buildings.endpoint == DEFAULT_ENDPOINT
    assert manifest_world({"buildings": "overpass:"}, tmp_path).buildings == OverpassSource()
    settings.write_text('[[world]]\nname = "file"\nbuildings = "city.osm"\n')
    with pytest.raises(GeofuseError, match=r"settings.toml: \[\[world\]\] 'file': .*overpass:URL"):
        choose_world("file")
    args = ["solve", str(drone_clip), "--out", str(tmp_path / "p.csv"), "--buildings", "overpass:"]
    assert main([*args, "--buildings", "overpass:"]) == 2
    assert "--buildings overpass: once" in capsys.readouterr().err
