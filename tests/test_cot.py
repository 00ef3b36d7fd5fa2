"""Cursor on Target out (issue 53; app.share.cot, app.share.tak): every event received is checked
against MITRE's CoT schemas (tests/data/cot: the base event, and the sensor, track and remarks
sub-schemas for those details) and against the frame it comes from: the aircraft at the
sensor's position, the point of interest within 0.5 m of where `locate` puts the centre pixel,
the footprint's vertices the SharedFrame's. Real receivers run on the loopback (UDP, TCP, and
TLS requiring a client certificate of the test's own authority); the hub and `live` send to
them; a target nobody listens on is said once and stops nothing. Waits are on conditions."""

from __future__ import annotations

import copy
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import shapely
from lxml import etree

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.cli import main
from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.geodesy.enu import LocalFrame
from app.locate.location import Locator
from app.locate.marks import Mark, marks_geojson
from app.scene import shapes
from app.scene.ground_plane import ground_under_track
from app.scene.mesh import MeshData
from app.share import cot
from app.share.frames import SharedFrame
from app.share.hub import Offer, Share
from app.share.tak import OUTBOX, TakSink, cot_targets
from app.share.target import CotTarget, TlsFiles, parse_target, tls_files
from tests.conftest import ROOT
from tests.cot_listener import P12_PASSWORD, Listener, make_pki
from tests.test_live import _run_with_sender, feed  # noqa: F401 (the module's feed fixture)
from tests.waiting import wait_until

SCHEMAS = ROOT / "tests" / "data" / "cot"
FRAME = LocalFrame(47.0, 8.0, 400.0)
INTR = Intrinsics.from_fov(640, 480, 60.0)
WHO = cot.CotIdentity.of("DRONE 1", host="test")
NOW = 1_790_000_000.0


@pytest.fixture(scope="module")
def schemas() -> dict[str, etree.XMLSchema]:
    return {
        n: etree.XMLSchema(etree.parse(SCHEMAS / f"{n}.xsd"))
        for n in ("event", "sensor", "track", "remarks")
    }


def check(xml: bytes, schemas) -> etree._Element:
    """The event, valid against the base schema, its sensor, track and remarks details against
    their sub-schemas."""
    doc = etree.fromstring(xml)
    schemas["event"].assertValid(doc)
    for child in doc.find("detail"):
        if child.tag in ("sensor", "track", "remarks"):
            schemas[child.tag].assertValid(etree.ElementTree(copy.deepcopy(child)))
    return doc


def point(doc) -> tuple[float, float, float]:
    p = doc.find("point")
    return float(p.get("lat")), float(p.get("lon")), float(p.get("hae"))


def links(doc) -> list[tuple[float, ...]]:
    return [tuple(float(v) for v in link.get("point").split(",")) for link in doc.iter("link")]


def at(doc, want) -> None:
    """The event's point is `want` (lat, lon, h): as written, to 1e-9 deg (0.1 mm) and 1 mm."""
    same(point(doc)[:2], want[:2])
    assert point(doc)[2] == pytest.approx(want[2], abs=5e-4)


def same(got, want, atol: float = 1e-9) -> None:
    """The same positions (degrees: 1e-9 is 0.1 mm, what an event writes)."""
    np.testing.assert_allclose(np.asarray(got, float), np.asarray(want, float), rtol=0, atol=atol)


def of_type(docs, cot_type: str) -> list:
    return [d for d in docs if d.get("type") == cot_type]


def _frame(footprint: dict, hpr=(359.99996, -35.0, -179.99999), media_s=1.5) -> SharedFrame:
    return SharedFrame(
        "a.ts", 7, media_s, NOW - 60.0, (47.001, 8.002, 520.0), 470.0, hpr, 60.0, 46.8,
        (47.0, 8.0, 400.5), 350.5, 170.0, footprint, "registered", "used",
    )  # fmt: skip


def _marks() -> dict:
    pts = np.array([[10.0, 20.0, 1.0], [30.0, 20.0, 1.5], [30.0, 40.0, 2.0]])
    marks = [
        Mark("point", "casualty", "a.ts", 3, 0.1, pts[:1]),
        Mark("line", "road block", "a.ts", 4, 0.13, pts[:2]),
        Mark("polygon", "", "a.ts", 5, 0.17, pts),
    ]
    return marks_geojson(marks, FRAME)


def test_each_event_follows_the_schema_and_says_the_frame(schemas):
    two = {
        "type": "MultiPolygon",
        "coordinates": [
            [[[8.0, 47.0], [8.001, 47.0], [8.001, 47.001], [8.0, 47.0]]],
            [[[8.01, 47.0], [8.011, 47.0], [8.011, 47.001], [8.01, 47.0]]],
        ],
    }
    f = _frame(two)
    before = replace(_frame(two, media_s=0.5), sensor=(47.001 - 10.0 / 111_200, 8.002, 519.0))
    moving = cot.motion(before, f)
    # 10 m north and 1 m up in 1 s (the metres per degree of latitude at 47 deg, to 0.5 %)
    assert moving.course_deg == pytest.approx(0.0, abs=0.01)
    assert moving.speed_m_s == pytest.approx(math.hypot(10.0, 1.0), rel=0.005)
    assert moving.slope_deg == pytest.approx(math.degrees(math.atan2(1.0, 10.0)), rel=0.005)
    assert cot.motion(f, before) is None  # backwards in time: no motion

    air = check(cot.aircraft_event(f, WHO, NOW, moving).xml, schemas)
    assert air.get("type") == "a-f-A-M-F-Q" and air.get("uid") == WHO.uid
    assert air.get("how") == "m-f"  # the registered pose: fused
    at(air, f.sensor)
    sensor = air.find("detail/sensor")
    assert sensor.get("azimuth") == "0.000" and sensor.get("roll") == "180.000"  # wrapped
    assert float(sensor.get("elevation")) == -35.0 and float(sensor.get("range")) == 170.0
    assert float(sensor.get("fov")) == 60.0 and float(sensor.get("vfov")) == 46.8
    assert air.find("detail/contact").get("callsign") == "DRONE 1"
    assert air.find("detail/__geofuse").get("frame") == "7"
    assert air.get("time") == "2026-09-21T14:13:20.000Z"  # when sent, not the frame's UTC
    assert air.get("stale") == "2026-09-21T14:13:25.000Z"  # a few seconds on: fades out
    assert air.find("detail/__geofuse").get("utc") == "2026-09-21T14:12:20.000Z"

    spi = check(cot.poi_event(f, WHO, NOW).xml, schemas)
    assert spi.get("type") == "b-m-p-s-p-i"
    at(spi, f.centre)
    parent = spi.find("detail/link")
    assert (parent.get("uid"), parent.get("relation")) == (WHO.uid, "p-p")
    assert cot.poi_event(replace(f, centre=None), WHO, NOW) is None

    prints = [check(e.xml, schemas) for e in cot.footprint_events(f, WHO, NOW)]
    assert [d.get("type") for d in prints] == ["u-d-f", "u-d-f"]
    assert len({d.get("uid") for d in prints}) == 2
    for d, polygon in zip(prints, two["coordinates"], strict=True):
        # the SharedFrame's vertices, closed (first repeated), as lat, lon
        same(links(d), [(lat, lon) for lon, lat in polygon[0]])

    events = cot.mark_events(_marks(), WHO, NOW)
    docs = [check(e.xml, schemas) for e in events]
    names = [d.find("detail/contact").get("callsign") for d in docs]
    assert names == ["casualty", "road block", "polygon 3"]  # unnamed: its kind and number
    assert [d.get("type") for d in docs] == ["b-m-p-s-m", "u-d-f", "u-d-f"]
    assert len(links(docs[1])) == 2  # a line stays open
    ring = links(docs[2])
    assert len(ring) == 4 and ring[0] == ring[-1]  # an area is closed
    assert docs[0].get("stale") == "2026-09-21T14:23:20.000Z"  # marks last longer
    assert "20.00 m along the ground" in docs[1].find("detail/remarks").text
    # the same mark keeps its uid from one sending to the next
    assert [e.uid for e in cot.mark_events(_marks(), WHO, NOW + 60)] == [e.uid for e in events]
    gone = check(cot.delete_event(events[0].uid, NOW).xml, schemas)
    assert gone.get("type") == "t-x-d-d" and gone.find("detail/link").get("uid") == events[0].uid
    assert gone.find("detail/__forcedelete") is not None


def test_a_bad_cot_url_is_refused_at_once_saying_what_is_expected(capsys):
    assert parse_target("udp://239.2.3.1:6969") == CotTarget("udp", "239.2.3.1", 6969)
    assert parse_target("udp://239.2.3.1:6969").multicast
    assert str(parse_target("tls://[::1]:8089")) == "tls://[::1]:8089"
    for bad in (
        "http://host:80",
        "udp://host",
        "tcp://host:70000",
        "tls://u:secret@host:8089",
        "udp://:9",
    ):
        with pytest.raises(ValueError, match="expected udp://HOST:PORT"):
            parse_target(bad)
    assert main(["live", "udp://127.0.0.1:5000", "--cot", "tcp://host:http"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--cot" in err[0] and "tcp://HOST:PORT" in err[0]
    assert main(["live", "udp://127.0.0.1:5000", "--cot", "tls://u:hunter2@h:1"]) == 2
    assert "hunter2" not in capsys.readouterr().err


def test_tls_files_from_the_command_line_or_a_settings_table(tmp_path, monkeypatch):
    pki = make_pki(tmp_path / "pki")
    target = parse_target("tls://127.0.0.1:8089")
    settings = tmp_path / "settings.toml"
    settings.write_text(
        f'[[tak]]\nurl = "tls://127.0.0.1:8089"\ncert = "{pki / "client.p12"}"\n'
        f'ca = "{pki / "ca.pem"}"\npassword_env = "TEST_TAK_PASSWORD"\n'
    )
    monkeypatch.setenv("TEST_TAK_PASSWORD", P12_PASSWORD)
    files = tls_files(target, settings=settings)
    assert files.cert == pki / "client.p12" and files.password == P12_PASSWORD
    assert P12_PASSWORD not in repr(files)
    made = cot_targets([target], settings=settings)
    assert target in made.contexts
    # the command line's files win over the table's; PEM certificate and key
    files = tls_files(target, pki / "client.pem", pki / "client.key", pki / "ca.pem", settings)
    assert files.cert.suffix == ".pem"
    monkeypatch.setenv("TEST_TAK_PASSWORD", "wrong")
    with pytest.raises(GeofuseError, match="client.p12: cannot open") as wrong:
        cot_targets([target], settings=settings)
    assert "wrong" not in str(wrong.value).replace("wrong password", "")
    with pytest.raises(GeofuseError, match="--cot-cert: .*nothing.pem is not a file"):
        tls_files(target, tmp_path / "nothing.pem", settings=settings)
    monkeypatch.delenv("TEST_TAK_PASSWORD")
    with pytest.raises(GeofuseError, match="TEST_TAK_PASSWORD is not set"):
        tls_files(target, settings=settings)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_each_kind_at_most_its_rate_and_marks_sent_again(schemas):
    """An injected clock: the aircraft and point of interest at most twice a second, the
    footprint once; marks at once, and again after MARK_RESEND_S; a removed mark deleted."""
    listener, clock = Listener("udp"), Clock()
    sink = TakSink(parse_target(listener.url), Messages(), WHO, clock=clock, wall=lambda: NOW)
    square = {
        "type": "Polygon",
        "coordinates": [[[8.0, 47.0], [8.001, 47.0], [8.001, 47.001], [8.0, 47.0]]],
    }

    def types():
        return [etree.fromstring(x).get("type") for x in listener.xml()]

    try:
        for t, k in ((0.0, 0), (0.0, 1), (0.2, 2), (0.4, 3), (0.5, 4), (0.8, 5), (1.0, 6)):
            clock.t = t
            sink.send_frame(_frame(square, media_s=k / 5))
        sink.send_marks(_marks())  # behind the frames' events on the same outbox: their end
        assert wait_until(lambda: types().count("u-d-f") >= 4)
        got = types()
        assert got.count("a-f-A-M-F-Q") == 3 and got.count("b-m-p-s-p-i") == 3  # t 0, 0.5, 1.0
        assert got.count("u-d-f") == 2 + 2  # footprint at t 0 and 1.0, and two drawn marks
        for x in listener.xml():
            check(x, schemas)
        clock.t = 1.0 + cot.MARK_RESEND_S
        sink.send_frame(_frame(square, media_s=7.0))  # wakes the thread: marks due again
        assert wait_until(lambda: types().count("b-m-p-s-m") == 2)
        sink.send_marks({"type": "FeatureCollection", "features": []})  # every mark removed
        assert wait_until(lambda: types().count("t-x-d-d") == 3)
    finally:
        sink.close()
        listener.close()
    assert sink.sent[cot.KIND_AIRCRAFT] == 4 and sink.dropped == 0


def test_an_unreachable_target_is_said_once_and_kept_trying_without_a_backlog():
    closed = Listener("tcp")
    closed.close()  # its port now refuses
    messages = Messages()
    sink = TakSink(parse_target(closed.url), messages, WHO, rates_hz={})
    square = {
        "type": "Polygon",
        "coordinates": [[[8.0, 47.0], [8.001, 47.0], [8.001, 47.001], [8.0, 47.0]]],
    }
    try:
        for k in range(OUTBOX):  # three events each: more than the outbox holds
            sink.send_frame(_frame(square, media_s=k / 30))
        assert wait_until(lambda: sink.attempts >= 3)  # tried again, with a growing pause
    finally:
        sink.close()
    said = [m for m in messages.items if closed.url in m]
    assert len(said) == 1 and "cannot reach it" in said[0], said
    assert sink.dropped == 3 * OUTBOX - OUTBOX and sum(sink.sent.values()) == 0
    assert f"{closed.url}: 0 events sent, {3 * OUTBOX} not sent, never reached" in sink.line()


@pytest.fixture(scope="module")
def scene() -> MeshData:
    """A ground at 0 m with a 20 m cube on it, 40 m north of the origin."""
    ground = shapes.quad([-500.0, -500.0, 0.0], [1000.0, 0, 0], [0, 1000.0, 0]).primitive()
    cube = shapes.box([-10.0, 30.0, 0.0], [10.0, 50.0, 20.0]).primitive()
    for p in (ground, cube):
        p.colors[:] = (0.5, 0.5, 0.5, 1.0)
    return MeshData([ground, cube])


def _poi_where_locate_puts_the_centre(mesh: MeshData, frame: LocalFrame, camera: Camera, doc):
    locator = Locator(mesh, frame)
    try:
        (where,) = locator.locate(
            camera, [[camera.intrinsics.width / 2, camera.intrinsics.height / 2]]
        )
    finally:
        locator.release()
    got = frame.geodetic_to_enu(*point(doc))
    assert np.linalg.norm(got - np.asarray(where.enu)) < 0.5, (got, where.enu)
    return where


def test_the_hub_sends_to_udp_and_tls_and_the_marks_follow(scene, schemas, tmp_path, monkeypatch):
    """One camera looking at the cube's side: a UDP receiver and a TLS one that requires the
    client's certificate (a PKCS#12 under a password, as TAK Server makes them) get the
    aircraft at the frame's sensor, the point of interest on the cube where `locate` puts the
    centre pixel, and the footprint as the SharedFrame's; a third target refuses, said once."""
    pki = make_pki(tmp_path / "pki")
    monkeypatch.setenv("GEOFUSE_COT_PASSWORD", P12_PASSWORD)  # the PKCS#12's, never an option
    udp, tls = Listener("udp"), Listener("tls", pki.server_context())
    closed = Listener("tcp")
    closed.close()
    ctx = cot_targets(
        [parse_target(tls.url)], pki / "client.p12", None, pki / "ca.pem", "DRONE 1",
        settings=tmp_path / "none.toml",
    ).contexts  # fmt: skip
    assert TlsFiles().check_hostname  # the server's certificate names 127.0.0.1: checked
    messages = Messages()
    sinks = [
        TakSink(parse_target(udp.url), messages, WHO),
        TakSink(parse_target(tls.url), messages, WHO, next(iter(ctx.values()))),
        TakSink(parse_target(closed.url), messages, WHO),
    ]
    eye = np.array([0.0, -60.0, 40.0])
    camera = Camera.create(INTR, eye, look_at_quat(eye, [0.0, 30.0, 10.0]), 0.5, 5000.0)
    share = Share(scene, FRAME, INTR, sinks, messages).start()
    try:
        share.offer(Offer(camera, 11, 0.4, NOW - 5.0, "cam.mp4", "registered", "used"))
        for lst in (udp, tls):
            assert wait_until(lambda lst=lst: len(lst.xml()) >= 3), lst.kind
        share.set_marks(_marks())
        for lst in (udp, tls):
            assert wait_until(lambda lst=lst: b"b-m-p-s-m" in b"".join(lst.xml())), lst.kind
        first = [e.uid for e in cot.mark_events(_marks(), WHO, NOW)]
        fewer = _marks()
        fewer["features"] = fewer["features"][:2]
        share.set_marks(fewer)
        assert wait_until(lambda: f'<link uid="{first[2]}"'.encode() in b"".join(udp.xml()))
        shared = share.last
    finally:
        share.close()
        udp.close()
        tls.close()
    assert tls.connections == 1 and not tls.refused
    for lst in (udp, tls):
        docs = [check(x, schemas) for x in lst.xml()]
        (air,) = of_type(docs, "a-f-A-M-F-Q")
        at(air, shared.sensor)
        np.testing.assert_allclose(FRAME.geodetic_to_enu(*point(air)), eye, atol=0.01)
        (spi,) = of_type(docs, "b-m-p-s-p-i")
        where = _poi_where_locate_puts_the_centre(scene, FRAME, camera, spi)
        assert where.enu[1] == pytest.approx(30.0, abs=0.1)  # on the cube's south side
        (foot,) = [d for d in of_type(docs, "u-d-f") if d.get("uid").endswith(".footprint")]
        ring = shapely.geometry.shape(shared.footprint).exterior.coords
        same(links(foot), [(lat, lon) for lon, lat in ring])
        marks = [d for d in docs if ".mark." in d.get("uid") and d.get("type") != "t-x-d-d"]
        names = {d.find("detail/contact").get("callsign") for d in marks}
        assert names == {"casualty", "road block", "polygon 3"}
    deleted = [d for d in of_type([etree.fromstring(x) for x in udp.xml()], "t-x-d-d")]
    assert [d.find("detail/link").get("uid") for d in deleted] == [first[2]]
    said = [m for m in messages.items if closed.url in m]
    assert len(said) == 1 and "cannot reach it" in said[0]


def test_live_sends_each_drawn_frames_aircraft_and_point_of_interest(feed, tmp_path, schemas):  # noqa: F811
    """`live` with a TCP receiver and a target nobody listens on: the events are those of drawn
    frames, the aircraft where the frame was drawn from, the point of interest where `locate`
    puts the centre pixel on the feed's ground; the dead target is said once and the run goes
    on to its end."""
    tcp = Listener("tcp")
    closed = Listener("tcp")
    closed.close()
    made = cot_targets([parse_target(tcp.url), parse_target(closed.url)], callsign="orbit")
    try:
        run, _, cameras = _run_with_sender(feed, tmp_path, {}, sinks=made.makers())
        sent = sum(made.made[0].sent.values())
        assert wait_until(lambda: len(tcp.xml()) == sent)  # every event sent was received
    finally:
        tcp.close()
    assert run.drawn and "silent for 2 s" in run.ended
    docs = [check(x, schemas) for x in tcp.xml()]
    air = of_type(docs, "a-f-A-M-F-Q")
    spis = of_type(docs, "b-m-p-s-p-i")
    assert len(air) >= 2 and spis and of_type(docs, "u-d-f")
    drawn = {round(d.pts_s, 6): cam for d, cam in cameras}
    for doc in air:
        cam = drawn[round(float(doc.find("detail/__geofuse").get("media_s")), 6)]
        got = run.frame.geodetic_to_enu(*point(doc))
        assert np.linalg.norm(got - np.asarray(cam.position)) < 0.01
        assert doc.find("detail/contact").get("callsign") == "orbit"
    assert any(doc.find("detail/track") is not None for doc in air[1:])  # moving: a track
    frame = run.frame
    ground = ground_under_track(
        frame, np.array([frame.lat_deg]), np.array([frame.lon_deg]), frame.h_m, 3000.0
    )
    for doc in spis[:: max(1, len(spis) // 3)]:
        cam = drawn[round(float(doc.find("detail/__geofuse").get("media_s")), 6)]
        _poi_where_locate_puts_the_centre(ground, frame, cam, doc)
    said = [m for m in run.messages.items if closed.url in m]
    assert len(said) == 1 and "cannot reach it" in said[0]
    lines = made.lines()
    assert lines[0] == made.made[0].line() and f"{len(docs)} events sent" in lines[0]
    assert ": 0 events sent" in lines[1] and lines[1].endswith("never reached")


def test_live_and_view_take_cot_targets_and_live_says_what_each_got(monkeypatch, capsys):
    udp = Listener("udp")
    seen = {}

    def fake_run_live(url, options):
        messages = Messages()
        sinks = [make(messages) for make in options.sinks]
        sq = {
            "type": "Polygon",
            "coordinates": [[[8.0, 47.0], [8.001, 47.0], [8.001, 47.001], [8.0, 47.0]]],
        }
        for s in sinks:
            s.send_frame(_frame(sq))
        assert wait_until(lambda: len(udp.xml()) == 3)
        for s in sinks:
            s.close()
        return SimpleNamespace(messages=messages, summary=lambda: f"{url}: done", drawn=[1])

    class FakeViewer:
        def __init__(self, options):
            seen["options"] = options

        def run(self):
            return 0

    monkeypatch.setattr("app.cli.live.run_live", fake_run_live)
    monkeypatch.setattr("app.cli.view.Viewer", FakeViewer)
    try:
        assert (
            main(["live", "udp://127.0.0.1:5000", "--cot", udp.url, "--cot-callsign", "EAGLE"]) == 0
        )
        out = capsys.readouterr().out
        assert f"udp://127.0.0.1:5000: done; CoT {udp.url}: 3 events sent" in out
        assert b'callsign="EAGLE"' in udp.xml()[0]
        assert main(["view", "--cot", udp.url, "--cot", "udp://239.2.3.1:6969"]) == 0
        assert len(seen["options"].sinks) == 2
    finally:
        udp.close()
