"""Corrected KLV out (issue 53): a drone's downlink sent over the loopback by the test, received and
drawn by `geofuse live`'s pipeline, and sent on (`--restream`) to a UDP port the test listens on.
The transport stream that arrives there is read with PyAV and its KLV with an independent reader
(klvdata): its video packets are the downlink's, and each frame drawn has one set carrying the
pose it was drawn with (within ST 0601's integer steps), with item 98 (a Geo-Registration Local
Set) exactly where live registration had corrected it. The tests wait for conditions, never for
wall-clock time."""

from __future__ import annotations

import io
import socket
import threading
from dataclasses import replace
from fractions import Fraction
from pathlib import Path
from types import SimpleNamespace

import av
import klvdata
import numpy as np
import pytest

from app import __version__
from app.cli import main
from app.core.messages import Messages
from app.export.klv import (
    GEOREGISTRATION_TAG,
    REGISTRATION_ALGORITHM,
    ST1601_VERSION,
    frame_set,
    is_registered,
)
from app.export.records import FrameRecord
from app.geodesy import rotations
from app.io.misb import read_ber, read_oid
from app.live.restream import Restreamer, restream_refusal
from app.live.run import LiveOptions, run_live
from app.scene.layers import Layer
from app.scene.loader import Placement
from app.simulate.feed import Sender, free_udp_port, port_held, sending_clock, write_feed
from app.simulate.sample import SAMPLE_DIR, SAMPLE_SCENE
from app.simulate.session import quick_config, write_sample_session
from app.simulate.stadium import SITE_ORIGIN
from tests.test_live_register import downlink  # noqa: F401 (the biased downlink, a fixture)
from tests.waiting import wait_until

TICK = Fraction(1, 90000)  # MPEG-TS time stamps
# Half of ST 0601's integer steps: latitude 180 deg / 2^32, longitude 360 / 2^32, the ellipsoid
# height 19900 m / 65535, the heading 360 deg / 65535, relative elevation and roll 360 / 2^32,
# the fields of view 180 deg / 65535.
LAT_DEG, LON_DEG, HEIGHT_M = 2.2e-8, 4.3e-8, 0.152
HEADING_DEG, ANGLE_DEG, FOV_DEG = 0.0028, 1e-6, 0.0014


class Listener:
    """Datagrams arriving at a loopback UDP port (chosen free), gathered by a thread until
    `stop`."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.datagrams.append(self.sock.recv(65_535))
            except TimeoutError:
                continue

    def stop(self) -> bytes:
        self._stop.set()
        self._thread.join(5.0)
        self.sock.close()
        return b"".join(self.datagrams)


def _packets(source, fmt: str | None = None) -> tuple[dict[int, bytes], list[tuple[int, bytes]]]:
    """({pts (90 kHz): bytes} of the video packets, [(pts, payload)] of the KLV ones) of a TS."""
    video, sets = {}, []
    with av.open(source, format=fmt) as c:
        v = c.streams.video[0]
        data = [s for s in c.streams if s.type == "data"]
        for p in c.demux(v, *data):
            if not p.size or p.pts is None:
                continue
            if p.stream is v:
                video[p.pts] = bytes(p)
            else:
                sets.append((p.pts, bytes(p)))
    return video, sets


def _nested(raw: bytes) -> dict[int, bytes]:
    """The items of a nested Local Set (no key, no checksum): tag -> value."""
    items, i = {}, 0
    while i < len(raw):
        tag, i = read_oid(raw, i)
        n, i = read_ber(raw, i)
        items[tag] = raw[i : i + n]
        i += n
    return items


def _which(ls) -> str:
    """What a set (klvdata's) says posed it: 'registered' where it carries item 98 naming
    geofuse's registration (ST 1601: document version, algorithm name and version), else
    'platform'."""
    raw = ls.items.get(bytes([GEOREGISTRATION_TAG]))
    if raw is None:
        return "platform"
    grls = _nested(bytes(raw.value))
    assert grls == {
        1: bytes([ST1601_VERSION]),
        2: REGISTRATION_ALGORITHM.encode(),
        3: __version__.encode(),
    }
    return "registered"


def _restream(feed: Path, options: LiveOptions):
    """The feed sent to live with --restream to a port the test listens on: (run, drawn
    [(Drawn, camera)], the TS that arrived)."""
    listener = Listener()
    port = free_udp_port()
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port))
    drawn = []
    opts = replace(options, restream=f"udp://127.0.0.1:{listener.port}")
    try:
        run = run_live(
            f"udp://127.0.0.1:{port}",
            opts,
            clock=sending_clock(sender, port),
            on_drawn=lambda d, c: drawn.append((d, c)),
        )
        # everything muxed has been sent (the restream is stopped with the feed): wait for the
        # loopback to hand it over
        assert wait_until(lambda: len(listener.datagrams) >= run.restream.datagrams)
    finally:
        sender.stop()
        data = listener.stop()
    return run, drawn, data


def _check(run, drawn, data: bytes, feed: Path) -> dict[str, int]:
    """The restreamed TS against the feed and what was drawn (see the module docstring);
    returns how many sets said each pose."""
    sent, _ = _packets(str(feed))
    video, sets = _packets(io.BytesIO(data), "mpegts")
    # The video packets are the downlink's, bytes and time stamps, from the first one received
    # on, none missing (but the last few the demuxer still held when the stream fell silent).
    order = sorted(sent)
    first, last = order.index(min(video)), order.index(max(video))
    assert sorted(video) == order[first : last + 1]
    assert len(order) - last <= 3 and len(video) >= 0.8 * len(order)
    assert all(video[pts] == sent[pts] for pts in video)
    assert run.restream.video == len(video) and run.restream.refused == 0
    # One set per frame drawn, at its presentation time, with the pose it was drawn with.
    at = {round((d.pts_s + run.origin_s) / TICK): (d, cam) for d, cam in drawn}
    assert [t for t, _ in sets] == sorted(at) and len(sets) == run.restream.sets
    said = {"registered": 0, "platform": 0}
    for t, payload in sets:
        d, cam = at[t]
        (ls,) = list(klvdata.StreamParser(payload))
        m = {k: v for k, v in ls.MetadataList().items() if k not in (1, 2, 65, 98)}
        value = {tag: float(v[3]) for tag, v in m.items() if tag not in (3, 4, 10, 11, 59)}
        lat, lon, h = run.frame.enu_to_geodetic(np.asarray(cam.position))
        heading, pitch, roll = rotations.hpr_from_camera_quat(np.asarray(cam.orientation)[None])[0]
        assert value[13] == pytest.approx(lat, abs=LAT_DEG)
        assert value[14] == pytest.approx(lon, abs=LON_DEG)
        assert value[75] == pytest.approx(h, abs=HEIGHT_M)
        assert (value[5] - heading + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=HEADING_DEG)
        assert value[6] == value[7] == value[18] == 0.0  # the camera is the (level) platform
        assert value[19] == pytest.approx(pitch, abs=ANGLE_DEG)
        assert (value[20] - roll + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=ANGLE_DEG)
        assert value[16] == pytest.approx(cam.intrinsics.hfov_deg, abs=FOV_DEG)
        assert value[17] == pytest.approx(cam.intrinsics.vfov_deg, abs=FOV_DEG)
        which = _which(ls)
        assert which == ("registered" if d.registered else "platform"), t
        said[which] += 1
    assert run.restream.registered == said["registered"]
    sets_line = f"{len(sets)} KLV sets sent ({said['registered']} with the registered pose)"
    assert "restreamed to udp://127.0.0.1:" in run.summary() and sets_line in run.summary()
    return said


@pytest.fixture(scope="module")
def feed(tmp_path_factory) -> Path:
    """3 s of the orbiting drone at 320x180, 30 fps, a KLV set per frame."""
    return write_feed(tmp_path_factory.mktemp("restream") / "feed.ts", 3.0, (320, 180))


def test_the_restream_carries_the_platforms_pose_of_each_frame_drawn(feed, tmp_path):
    """Over the assumed ground (no registration): every set carries the platform's pose, as
    drawn, and says so (no item 98); the platform's naming items are passed on, and its
    original KLV stays in the recording."""
    record = tmp_path / "rec.ts"
    run, drawn, data = _restream(feed, LiveOptions(silence_s=2.0, size=(160, 90), record=record))
    said = _check(run, drawn, data, feed)
    assert said["registered"] == 0 and said["platform"] >= 30
    _, sets = _packets(io.BytesIO(data), "mpegts")
    (ls,) = list(klvdata.StreamParser(sets[0][1]))
    names = {k: v[3] for k, v in ls.MetadataList().items()}
    assert names[10] == "geofuse orbit" and names[11] == "EO"
    # the recording keeps what arrived: the downlink's own sets, not geofuse's
    _, recorded = _packets(str(record))
    _, original = _packets(str(feed))
    assert recorded and set(recorded) <= set(original)


@pytest.mark.gl
def test_registered_frames_are_restreamed_with_the_registered_pose_and_say_so(downlink):  # noqa: F811
    """The downlink whose KLV puts the camera 3 m and 1.9 deg off, over the textured sample
    model: once keyframes register, the frames drawn corrected go out with the corrected pose
    and item 98; those drawn before, with the platform's and without."""
    scene = Layer.of(SAMPLE_DIR / "scene.glb", placement=Placement(origin=SITE_ORIGIN))
    run, drawn, data = _restream(
        downlink, LiveOptions(silence_s=2.0, size=(160, 90), layers=(scene,))
    )
    said = _check(run, drawn, data, downlink)
    assert run.registration is not None and run.registration.registered >= 1, run.summary()
    assert said["registered"] >= 60 and said["platform"] >= 1, said


@pytest.mark.parametrize(
    "url, said",
    [
        ("tcp://127.0.0.1:5000", "the restream is MPEG-TS over UDP (expected udp://HOST:PORT)"),
        ("udp://127.0.0.1:notaport", "'notaport' is not a port"),
        ("udp://127.0.0.1:99999999", "'99999999' is not a port"),
        ("udp://127.0.0.1", "no port (expected udp://HOST:PORT)"),
        ("udp://:5000", "no host to send to"),
        ("udp://239.1.2.3:5000?pkt_size=7", "pkt_size='7' is not understood"),
        ("udp://239.1.2.3:5000?ttl=0", "ttl='0' is not understood"),
    ],
)
def test_a_restream_target_that_cannot_be_is_refused_at_once_in_one_line(url, said, capsys):
    assert main(["live", "udp://127.0.0.1:5600", "--restream", url, "--for", "600"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert f"--restream {url}" in err and said in err and "Traceback" not in err


def test_targets_that_can_be_pass():
    for url in ("udp://127.0.0.1:5000", "udp://239.1.2.3:5000?ttl=4", "udp://[::1]:5000"):
        assert restream_refusal(url) is None, url


def test_a_target_nobody_listens_at_is_said_once_and_the_run_goes_on(feed, capsys):
    """`geofuse live --restream` to a loopback port nobody holds: the port-unreachable is said
    once, counted, and the feed is drawn to its end with every set still sent."""
    port, dead = free_udp_port(), free_udp_port()
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port))

    def send_once_listened() -> None:
        if wait_until(lambda: port_held(port)):
            sender.start()

    threading.Thread(target=send_once_listened, daemon=True).start()
    try:
        argv = ["live", f"udp://127.0.0.1:{port}", "--restream", f"udp://127.0.0.1:{dead}"]
        rc = main([*argv, "--size", "160x90", "--for", "8"])
    finally:
        sender.stop()
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert err.count("nothing listens there: the port is unreachable") == 1, err
    summary = out.strip().splitlines()[-1]
    assert (
        "datagrams not delivered" in summary and " KLV sets sent (0 with the registered" in summary
    )
    assert "Traceback" not in out + err


def test_a_host_that_cannot_be_resolved_is_said_and_nothing_waits_on_it():
    messages = Messages()
    r = Restreamer("udp://no-such-host.invalid:5000", messages).start()
    try:
        assert wait_until(lambda: r.counts.failed is not None)
    finally:
        r.stop()
    assert "cannot resolve no-such-host.invalid" in " ".join(messages.items)
    assert "nothing sent (cannot resolve" in r.counts.line()


# --- the file export says it the same way ------------------------------------------------------


@pytest.mark.gl
def test_export_klv_of_the_registered_source_says_so_in_every_set(tmp_path, capsys):
    """`export klv --source registered` (a short sample walk, registered against its model):
    item 98 in every set, as the restream writes it; under another source, none."""
    manifest = write_sample_session(tmp_path / "s", SAMPLE_SCENE, quick_config(4.0))
    out = tmp_path / "registered.ts"
    argv = ["export", "klv", str(manifest), "--every", "20"]
    assert main([*argv, "--source", "registered", "--out", str(out)]) == 0
    assert "each saying so (item 98)" in capsys.readouterr().out
    _, sets = _packets(str(out))
    assert len(sets) >= 5
    for _, payload in sets:
        (ls,) = list(klvdata.StreamParser(payload))
        assert _which(ls) == "registered"


def test_a_set_says_item_98_only_where_registered():
    """frame_set with and without registration (the same items otherwise, in order), and a
    track is registered only when it is the `registered` source with a keyframe used."""
    nan = float("nan")
    r = FrameRecord(
        index=0, media_s=0.0, session_s=0.0, utc_s=1.79e9, sensor=(34.8, 113.53, 150.0),
        hpr=(30.0, -20.0, 1.0), hfov_deg=60.0, vfov_deg=40.0, centre=(nan, nan, nan),
        slant_m=nan, corners=np.zeros((4, 3)), footprint=np.zeros((0, 3)), clipped=True,
        undulation=np.array([-19.5, nan]), ground=np.zeros((1, 1, 2)),
    )  # fmt: skip
    (a,) = list(klvdata.StreamParser(frame_set(r)))
    (b,) = list(klvdata.StreamParser(frame_set(r, registered=True)))
    assert _which(a) == "platform" and _which(b) == "registered"
    assert [k for k in b.items if k != bytes([GEOREGISTRATION_TAG])] == list(a.items)

    def track(source: str, used: list[bool]) -> SimpleNamespace:
        keyframes = tuple(SimpleNamespace(used=u) for u in used)
        return SimpleNamespace(source=source, registration=SimpleNamespace(keyframes=keyframes))

    assert is_registered(track("registered", [False, True]))
    assert not is_registered(track("registered", [False, False]))
    assert not is_registered(track("offline", [True]))
