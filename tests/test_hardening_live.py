"""Issue 51, live feeds and MAVLink, as a careless or hostile sender would feed them: messages
that cannot be true (a latitude of 214.7 deg, angles far outside -pi..pi, NaN), garbage datagrams
where MPEG-TS or MAVLink is expected, ports that are not ports, a feed of attitudes without a
position. Each is dropped and counted by reason, or refused in one line with exit status 2, and
said; never a traceback. Streams are sent over the loopback by the tests themselves; the tests
wait for conditions, never for wall-clock time."""

from __future__ import annotations

import math
import os
import socket
import threading
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from app.cli import main
from app.core.messages import Messages
from app.io.mavlink import MavlinkTelemetry
from app.live.buffer import JitterBuffer
from app.live.feed import LiveFeed, LiveOptions, LiveRun
from app.live.mavlink import MavlinkReceiver
from app.live.pose import LivePoses
from app.live.probe import (
    MAVLINK,
    MPEG_TS,
    UNKNOWN,
    Heard,
    datagram_kind,
    mavlink_refusal,
    stream_refusal,
)
from app.live.receiver import Receiver
from app.live.run import run_live
from app.simulate.feed import free_udp_port, port_held
from tests.waiting import wait_until

INT32_MAX = 2**31 - 1  # a latitude field full of ones: 214.7 deg
FIX = {"time_boot_ms": 1000, "lat": 348_000_000, "lon": 1_135_300_000, "alt": 150_000}
LEVEL = {"time_boot_ms": 1000, "roll": 0.0, "pitch": 0.0, "yaw": 0.0}
MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


class Spray:
    """Sends `datagrams()` (a list of bytes, drawn again each round) to a loopback port over
    and over from a thread, once someone holds the port, until stopped."""

    def __init__(self, port: int, datagrams: Callable[[], list[bytes]]) -> None:
        self.port, self.datagrams = port, datagrams
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Spray:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _run(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not self._stop.is_set():
                if not port_held(self.port):
                    self._stop.wait(0.01)
                    continue
                for d in self.datagrams():
                    s.sendto(d, ("127.0.0.1", self.port))
                    self.sent += 1
                self._stop.wait(0.005)


def _garbage() -> list[bytes]:
    return [os.urandom(1316)]


def _garbage_without_magic() -> list[bytes]:
    """Garbage with no byte that begins a MAVLink message (0xFD, 0xFE): random bytes would
    now and then hold one that passes its 16-bit checksum by chance."""
    return [os.urandom(1316).replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00")]


def _pack(message) -> bytes:
    return message.pack(MAV)


def _hostile_autopilot() -> list[bytes]:
    """One round of an autopilot gone wrong: good attitudes, NaN ones, ones of 50 rad, a
    latitude of INT32_MAX, a height of 2000 km, garbage bytes, a message with a broken
    checksum; and no usable position at all."""
    ms = int(time.monotonic() * 1000) % 2**32
    broken = bytearray(_pack(MAV.attitude_encode(ms, 0.1, 0.0, 0.0, 0, 0, 0)))
    broken[-1] ^= 0xFF
    return [
        _pack(MAV.attitude_encode(ms, 0.1, -0.2, 1.0, 0, 0, 0)),
        _pack(MAV.attitude_encode(ms, math.nan, 0.0, 0.0, 0, 0, 0)),
        _pack(MAV.attitude_encode(ms, 0.0, 0.0, 50.0, 0, 0, 0)),
        _pack(MAV.global_position_int_encode(ms, INT32_MAX, 10, 150_000, 40_000, 0, 0, 0, 0)),
        _pack(MAV.global_position_int_encode(ms, 348_000_000, 10, INT32_MAX, 0, 0, 0, 0, 0)),
        os.urandom(300),
        bytes(broken),
    ]


# --- messages that cannot be true (pure) --------------------------------------------------------


@pytest.mark.parametrize(
    "fields, reason",
    [
        ({"lat": INT32_MAX}, "latitude or longitude out of range"),
        ({"lat": -INT32_MAX}, "latitude or longitude out of range"),
        ({"lon": INT32_MAX}, "latitude or longitude out of range"),
        ({"lat": math.nan}, "latitude or longitude out of range"),
        ({"alt": INT32_MAX}, "a height no fix has"),
        ({"alt": -INT32_MAX}, "a height no fix has"),
        ({"relative_alt": -INT32_MAX}, "a height no fix has"),
        ({"lat": None}, "GLOBAL_POSITION_INT with a field missing or not a number"),
    ],
)
def test_a_position_that_cannot_be_true_is_dropped_and_counted_by_reason(fields, reason):
    tel = MavlinkTelemetry()
    assert not tel.add("GLOBAL_POSITION_INT", {**FIX, "relative_alt": 0, **fields}, 10.0)
    [(said, n)] = tel.counts.dropped.items()
    assert reason in said and n == 1
    assert tel.first() is None and tel.link_s is None  # nothing kept, not even its time
    assert tel.add("ATTITUDE", LEVEL, 10.0) and tel.at(1.0) is None
    assert "the camera cannot be placed" in tel.missing()


@pytest.mark.parametrize(
    "angles, reason",
    [
        ({"yaw": 50.0}, "angles beyond +-2 pi rad (expected -pi..pi)"),
        ({"roll": -1e9}, "angles beyond +-2 pi rad"),
        ({"pitch": math.nan}, "angles that are not numbers"),
        ({"roll": math.inf}, "angles that are not numbers"),
    ],
)
def test_attitudes_far_outside_minus_pi_to_pi_or_not_numbers_are_dropped_with_the_reason(
    angles, reason
):
    tel = MavlinkTelemetry()
    assert tel.add("GLOBAL_POSITION_INT", FIX, 10.0)
    assert not tel.add("ATTITUDE", {**LEVEL, **angles}, 10.0)
    assert reason in next(iter(tel.counts.dropped))
    assert tel.at(1.0) is None and "no attitude" in tel.missing()
    # an autopilot sending its yaw as 0..2 pi is taken
    assert tel.add("ATTITUDE", {**LEVEL, "yaw": 1.9 * math.pi}, 10.0)
    assert tel.at(1.0) is not None and tel.missing() is None


def test_gimbal_and_mount_angles_that_cannot_be_true_are_dropped():
    tel = MavlinkTelemetry()
    assert tel.add("ATTITUDE", LEVEL, 10.0)  # links the boot clock: MOUNT_STATUS is placed
    q0 = {"time_boot_ms": 1000, "q": [0.0, 0.0, 0.0, 0.0], "flags": 0}
    assert not tel.add("GIMBAL_DEVICE_ATTITUDE_STATUS", q0, 10.0)
    assert not tel.add(
        "MOUNT_STATUS", {"pointing_a": -(2**31), "pointing_b": 0, "pointing_c": 0}, 10.1
    )
    assert set(tel.counts.dropped) == {
        "GIMBAL_DEVICE_ATTITUDE_STATUS with a quaternion of zero length or not a number",
        "MOUNT_STATUS with angles beyond +-360 deg",
    }
    assert not tel.has_gimbal


# --- addresses that are not addresses ----------------------------------------------------------


@pytest.mark.parametrize(
    "url, said",
    [
        ("udp://127.0.0.1:notaport", "'notaport' is not a port"),
        ("udp://127.0.0.1:99999999", "'99999999' is not a port"),
        ("udp://127.0.0.1:-5", "'-5' is not a port"),
        ("udp://127.0.0.1:0", "'0' is not a port"),
        ("udp://127.0.0.1", "no port (expected udp://HOST:PORT)"),
        ("srt://[::1]:65536", "'65536' is not a port"),
    ],
)
def test_live_refuses_a_port_that_is_not_a_port_at_once_in_one_line(url, said, capsys):
    assert main(["live", url, "--for", "600"]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # refused before anything listens (nothing was received)
    assert err.count("\n") == 1 and said in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "argv",
    [
        ["view", "udp://127.0.0.1:notaport"],
        ["view", "udp://127.0.0.1:5600", "--mavlink", "udpin:0.0.0.0:99999999"],
    ],
)
def test_view_refuses_a_port_that_is_not_a_port_before_a_window_opens(argv, capsys):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "is not a port" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "address", ["udp:127.0.0.1:notaport", "udpin:0.0.0.0:99999999", "tcp:h:-1"]
)
def test_live_refuses_a_mavlink_port_that_is_not_a_port(address, capsys):
    assert main(["live", "udp://127.0.0.1:5600", "--mavlink", address, "--for", "600"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert f"{address}: " in err and "is not a port" in err and "Traceback" not in err


def test_ports_that_are_ports_and_connections_that_are_not_network_ones_pass():
    for url in ("udp://127.0.0.1:5600", "udp://@:5600", "rtsp://cam/live", "udp://[::1]:1"):
        assert stream_refusal(url) is None, url
    for address in ("udp:127.0.0.1:14550", "udpin:0.0.0.0:14550", "/dev/ttyUSB0,57600"):
        assert mavlink_refusal(address) is None, address
    assert mavlink_refusal("udp:14550") == "udp:14550: expected udp:HOST:PORT"


def test_the_viewers_receivers_refuse_a_bad_port_instead_of_retrying_it():
    """The viewer opens a typed URL through the same receivers: refused, said as an error,
    nothing tried (no thread), and a run over it ends at once instead of at --for."""
    messages = Messages()
    r = Receiver("udp://127.0.0.1:notaport", JitterBuffer(), LivePoses(0.1), messages).start()
    assert not r.alive and r.counts.refused and messages.of("error") == [r.counts.refused]
    r.stop()
    m = MavlinkReceiver("udp:127.0.0.1:99999999", MavlinkTelemetry(), messages).start()
    assert not m.wait_ready(60.0) and "'99999999' is not a port" in m.refused
    m.stop()
    run = run_live("udp://127.0.0.1:99999999", LiveOptions(seconds=600.0))
    assert run.ended == "ended: the address was refused" and run.frames_drawn == 0
    assert "'99999999' is not a port" in " ".join(run.messages.of("error"))


# --- garbage where MPEG-TS is expected ----------------------------------------------------------


def test_datagrams_are_named_by_what_they_look_like():
    assert datagram_kind(bytes([0x47]) + bytes(187)) == MPEG_TS
    assert datagram_kind(_pack(MAV.attitude_encode(1, 0.0, 0.0, 0.0, 0, 0, 0))) == MAVLINK
    assert datagram_kind(b"\xfe" + os.urandom(200)) == UNKNOWN
    assert datagram_kind(b"") == UNKNOWN


@pytest.mark.parametrize(
    "datagrams, hint",
    [
        (_garbage, None),
        (lambda: [_pack(MAV.attitude_encode(1, 0.0, 0.0, 0.0, 0, 0, 0))] * 20, "--mavlink"),
    ],
)
def test_garbage_datagrams_are_said_to_arrive_unreadable_not_called_silence(datagrams, hint):
    port = free_udp_port()
    messages = Messages()
    r = Receiver(f"udp://127.0.0.1:{port}", JitterBuffer(), LivePoses(0.1), messages).start()
    try:
        with Spray(port, datagrams):
            assert wait_until(lambda: r.counts.unreadable.datagrams > 0), messages.items
    finally:
        r.stop()
    [said] = [m for m in messages.items if "arrived but none was readable" in m]
    assert said.startswith(f"udp://127.0.0.1:{port}: ") and " datagrams (" in said
    assert "expected 188-byte packets beginning 0x47" in said
    assert (hint in said) if hint else ("(they are" not in said)
    assert not any("nothing arrived" in m for m in messages.items), messages.items
    assert r.counts.frames == 0


def test_live_on_a_feed_of_garbage_says_what_arrived_and_exits_1(capsys):
    port = free_udp_port()
    with Spray(port, _garbage) as spray:
        rc = main(["live", f"udp://127.0.0.1:{port}", "--for", "12", "--size", "64x36"])
    out, err = capsys.readouterr()
    assert spray.sent > 0 and rc == 1
    assert "arrived but none was readable as MPEG-TS" in err, err
    summary = out.strip().splitlines()[-1]
    assert "0 frames received" in summary and "arrived but none was readable as MPEG-TS" in summary
    assert "Traceback" not in out + err


def test_the_summary_says_unreadable_datagrams():
    heard = Heard()
    for _ in range(3):
        heard.add(os.urandom(100))
    run = LiveRun("udp://h:1", unreadable=heard, ended="ended after 1 s")
    assert "; 3 datagrams (300 bytes) arrived but none was readable as MPEG-TS" in run.summary()
    run.received = 10
    assert "; 3 datagrams before it opened were not MPEG-TS" in run.summary()


# --- a hostile autopilot ------------------------------------------------------------------------


def test_a_hostile_autopilot_is_counted_by_reason_and_its_missing_position_said():
    """A feed of attitudes (some NaN, some of 50 rad), positions at 214.7 deg or 2000 km up,
    garbage bytes and broken checksums: the good attitudes used, everything else dropped and
    counted by reason, each reason said once, and no position said (the camera cannot be
    placed); the video's port gets nothing."""
    mav_port = free_udp_port()
    feed = LiveFeed(
        f"udp://127.0.0.1:{free_udp_port()}",
        LiveOptions(mavlink=f"udp:127.0.0.1:{mav_port}", register=False),
    ).start()
    try:
        with Spray(mav_port, _hostile_autopilot):
            dropped = feed.poses.telemetry.counts.dropped
            assert wait_until(
                lambda: (
                    len(dropped) >= 4
                    and min(dropped.values()) >= 3
                    and feed.mav.unreadable_bytes > 900
                    and feed.poses.telemetry.counts.used.get("ATTITUDE", 0) >= 3
                )
            ), (dropped, feed.mav.unreadable_bytes)
    finally:
        run = feed.stop()
    said = run.messages.items
    address = f"udp:127.0.0.1:{mav_port}"
    for reason in (
        "ATTITUDE with angles that are not numbers",
        "ATTITUDE with angles beyond +-2 pi rad (expected -pi..pi)",
        "GLOBAL_POSITION_INT with a latitude or longitude out of range",
        "GLOBAL_POSITION_INT with a height no fix has",
    ):
        assert sum(reason in m and "dropped (counted)" in m for m in said) == 1, (reason, said)
    assert (
        f"{address}: bytes that are not MAVLink (or of no known type, or fail its checksum) are dropped (counted)"
        in said
    )
    assert (
        f"MAVLink {address}: attitudes but no position (GLOBAL_POSITION_INT with a fix, or "
        "HOME_POSITION and the height above it): the camera cannot be placed"
    ) in said
    line = run.mavlink.line()
    assert f"MAVLink {address}: " in line and " ATTITUDE" in line
    assert "dropped: " in line and " ATTITUDE with angles that are not numbers" in line
    assert "bytes unreadable (not MAVLink, of no known type, or failing its checksum)" in line
    assert "attitudes but no position" in line and "the camera cannot be placed" in line
    assert run.frames_drawn == 0


def test_live_with_a_mavlink_feed_of_garbage_says_none_was_readable(capsys):
    video_port, mav_port = free_udp_port(), free_udp_port()
    address = f"udp:127.0.0.1:{mav_port}"
    with Spray(mav_port, _garbage_without_magic) as spray:
        rc = main(["live", f"udp://127.0.0.1:{video_port}", "--mavlink", address, "--for", "3"])
    out, err = capsys.readouterr()
    assert spray.sent > 0 and rc == 1
    summary = out.strip().splitlines()[-1]
    assert f"MAVLink {address}: nothing used; " in summary
    assert "bytes arrived but none was readable as MAVLink (expected MAVLink 1 or 2" in summary
    assert "no position (GLOBAL_POSITION_INT with a fix) and no attitude (ATTITUDE)" in summary
    assert (
        "bytes that are not MAVLink (or of no known type, or fail its checksum) are dropped (counted)"
        in err
    )
    assert "Traceback" not in out + err


def test_live_with_a_silent_mavlink_port_says_nothing_arrived(capsys):
    address = f"udp:127.0.0.1:{free_udp_port()}"
    rc = main(["live", f"udp://127.0.0.1:{free_udp_port()}", "--mavlink", address, "--for", "1"])
    out, err = capsys.readouterr()
    assert rc == 1 and f"MAVLink {address}: nothing arrived; " in out
    assert f"MAVLink {address}: nothing arrived (is the autopilot sending there?)" in err
    assert "Traceback" not in out + err
