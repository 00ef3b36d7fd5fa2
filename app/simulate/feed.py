"""A drone's downlink, simulated: an aircraft orbiting a point with its sensor on the point, the
MISB ST 0601 Local Sets it sends (synchronous, a set per frame, or at their own rate), and the
H.264 MPEG-TS that carries them; for tests, `geofuse simulate feed` and `bench live`.

Geometry (ENU in the LocalFrame at the orbit's centre on the ground): the aircraft flies
counter-clockwise seen from above on a circle of radius_m at height_m, banked bank_deg into the
turn (left wing down: a negative roll) and pitched pitch_deg nose up; the sensor's relative angles
are whatever puts its line of sight on the centre, so the frame centre (tags 23-25, 78) is the
orbit's centre and the slant range is hypot(radius, height).
"""

from __future__ import annotations

import errno
import math
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.misb import encode, local_set, ypr_matrix
from app.simulate.phone import write_video

UTC_START_S = 1_790_000_000.0  # 2026-09-21, the simulated flight's first set (Unix s)


@dataclass(frozen=True)
class Orbit:
    """The simulated flight: centre on the ground (deg, ellipsoidal m), circle and attitude."""

    lat_deg: float = 34.8
    lon_deg: float = 113.53
    ground_h_m: float = 100.0
    radius_m: float = 150.0
    height_m: float = 80.0
    period_s: float = 60.0
    bank_deg: float = -8.0
    pitch_deg: float = 2.0
    hfov_deg: float = 50.0
    platform: str = "geofuse orbit"
    sensor: str = "EO"

    def frame(self) -> LocalFrame:
        return LocalFrame(self.lat_deg, self.lon_deg, self.ground_h_m)

    def position(self, t: float) -> np.ndarray:
        """The aircraft's ENU position (m) at t s."""
        a = 2 * math.pi * t / self.period_s
        return np.array([self.radius_m * math.cos(a), self.radius_m * math.sin(a), self.height_m])

    def angles(self, t: float) -> tuple[float, float, float, float, float, float]:
        """(platform heading, pitch, roll, sensor azimuth, elevation, roll), degrees as ST 0601
        defines them, with the line of sight on the orbit's centre."""
        a = 2 * math.pi * t / self.period_s
        heading = math.degrees(math.atan2(-math.sin(a), math.cos(a))) % 360.0
        p = self.position(t)
        los_ned = np.array([-p[1], -p[0], p[2]]) / np.linalg.norm(p)  # to the centre, N E D
        body = ypr_matrix(heading, self.pitch_deg, self.bank_deg)
        x, y, z = body.T @ los_ned
        az = math.degrees(math.atan2(y, x)) % 360.0
        el = -math.degrees(math.asin(max(-1.0, min(1.0, z))))
        return heading, self.pitch_deg, self.bank_deg, az, el, 0.0


def orbit_set(orbit: Orbit, t: float, vfov_deg: float, msl_only: bool = False) -> bytes:
    """The Local Set the aircraft sends at t s (msl_only: heights above sea level only, tag 15,
    as older encoders write)."""
    frame = orbit.frame()
    lat, lon, h = (float(v) for v in frame.enu_to_geodetic(orbit.position(t)))
    n = float(undulation(lat, lon))
    nc = float(undulation(orbit.lat_deg, orbit.lon_deg))
    heading, pitch, roll, az, el, sroll = orbit.angles(t)
    items = [
        (2, struct.pack(">Q", int(round((UTC_START_S + t) * 1e6)))),
        (65, bytes([17])),
        (10, orbit.platform.encode()),
        (11, orbit.sensor.encode()),
        (5, encode(5, heading)),
        (90, encode(90, pitch)),
        (91, encode(91, roll)),
        (13, encode(13, lat)),
        (14, encode(14, lon)),
        (15, encode(15, h - n)),
        (16, encode(16, orbit.hfov_deg)),
        (17, encode(17, vfov_deg)),
        (18, encode(18, az)),
        (19, encode(19, el)),
        (20, encode(20, sroll)),
        (21, encode(21, math.hypot(orbit.radius_m, orbit.height_m))),
        (23, encode(23, orbit.lat_deg)),
        (24, encode(24, orbit.lon_deg)),
        (25, encode(25, orbit.ground_h_m - nc)),
    ]
    if not msl_only:
        items += [(75, encode(75, h)), (78, encode(78, orbit.ground_h_m))]
    return local_set(items)


def moving_texture(size: tuple[int, int], seed: int = 0):
    """frame(k) -> (h, w, 3) uint8: 8-pixel random blocks sliding 4 pixels a frame (real work
    for an encoder and a decoder, unlike a flat colour)."""
    w, h = size
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 255, (-(-h // 8), -(-w // 8), 3), dtype=np.uint8)
    base = base.repeat(8, 0).repeat(8, 1)[:h, :w]
    return lambda k: np.roll(base, 4 * k, axis=1)


def write_feed(
    path: str | Path,
    seconds: float,
    size: tuple[int, int] = (640, 360),
    fps: float = 30.0,
    klv_hz: float | None = None,
    orbit: Orbit = Orbit(),
    crf: int = 28,
) -> Path:
    """An H.264 MPEG-TS of the orbit: `size` (w, h) at `fps`, with a KLV data stream, a set per
    frame at its presentation time (klv_hz None: synchronous) or at klv_hz with its own times."""
    times = np.arange(int(round(seconds * fps))) / fps
    klv_times = times if klv_hz is None else np.arange(int(seconds * klv_hz)) / klv_hz
    vfov = math.degrees(
        2 * math.atan(math.tan(math.radians(orbit.hfov_deg) / 2) * size[1] / size[0])
    )
    packets = [(float(t), orbit_set(orbit, float(t), vfov)) for t in klv_times]
    return write_video(Path(path), times, size, 0, frame=moving_texture(size), crf=crf, klv=packets)


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port nobody holds now on host (for tests and benchmarks that send to themselves)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


PROC_UDP = (Path("/proc/net/udp"), Path("/proc/net/udp6"))  # Linux's table of UDP sockets


def port_held(port: int, host: str = "127.0.0.1") -> bool:
    """Whether someone (a receiver) holds the UDP port on host. Where the system lists its
    sockets (Linux's /proc/net/udp) it is read there, touching nothing: a probe that binds the
    port itself, however briefly, can take it from a receiver binding at that moment (seen on a
    loaded machine, where the probe's thread is set aside while it holds the port). Elsewhere
    that probe: a bind that fails with EADDRINUSE."""
    tables = [p for p in PROC_UDP if p.is_file()]
    if tables:
        return any(_listed(table, port) for table in tables)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            return exc.errno == errno.EADDRINUSE
    return False


def _listed(table: Path, port: int) -> bool:
    """Whether a /proc/net/udp(6) table lists a socket bound to the port (its local address's
    port, hexadecimal after the colon), on any address."""
    try:
        lines = table.read_text().splitlines()[1:]
    except OSError:
        return False
    want = f"{port:04X}"
    return any(
        len(fields) > 1 and fields[1].rsplit(":", 1)[-1] == want
        for fields in (line.split() for line in lines)
    )


def sending_clock(
    sender: Sender,
    port: int,
    limit_s: float = 30.0,
    clock: Callable[[], float] = time.monotonic,
    on_start: Callable[[float], None] | None = None,
) -> Callable[[], float]:
    """`clock` (monotonic s) for run_live, starting `sender` the first time it is read (after
    the receiver has started), once the receiver's socket holds `port` (a busy machine opens it
    late; at most limit_s of real time); on_start(clock s): called as the sender starts (a
    MAVLink sender started beside it)."""
    started: list[bool] = []

    def read() -> float:
        if not started:
            started.append(True)
            end = time.monotonic() + limit_s
            while not port_held(port) and time.monotonic() < end:
                time.sleep(0.01)
            sender.start()
            if on_start is not None:
                on_start(clock())
        return clock()

    return read


class LockstepClock:
    """A monotonic clock (s) that never passes `cap(now)`: the time the receiving side may not
    see pass yet (a frame due then and not yet drawn, a keyframe being registered, a receiver
    behind what was sent). Tests of live feeds give it to the sender and the receiver alike: the
    sender paced by it waits, the receiver's jitter buffer sees one frame fall due at a time, so
    what is drawn does not depend on how fast this machine registers or draws (latency is the
    benchmarks'). It stands limit_s of `real` time at most at a stretch. Thread-safe."""

    def __init__(
        self,
        cap: Callable[[float], float],
        limit_s: float = 20.0,
        real: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cap = cap
        self.limit_s = limit_s
        self.real = real
        self.stood_s = 0.0  # the real time it stood still, in all
        self._last: float | None = None
        self._standing: float | None = None  # real time it began to stand
        self._lock = threading.Lock()

    def __call__(self) -> float:
        real = self.real()
        with self._lock:
            free = real - self.stood_s  # where it would be had it not stood since
            last = free if self._last is None else self._last
            stuck = self._standing is not None and real - self._standing >= self.limit_s
            now = free if stuck else max(last, min(free, self.cap(last)))
            if now >= free:
                self._standing = None
            elif self._standing is None:
                self._standing = real
            self.stood_s, self._last = real - now, now
            return now


TS_PACKET = 188
DATAGRAM_PACKETS = 7  # 1316 bytes: what MPEG-TS over UDP sends per datagram


def _pcr(packet: bytes) -> int | None:
    """A TS packet's program clock reference base (90 kHz), None when it carries none."""
    if (packet[3] >> 4) & 2 and packet[4] >= 7 and packet[5] & 0x10:
        b = packet[6:11]
        return (b[0] << 25) | (b[1] << 17) | (b[2] << 9) | (b[3] << 1) | (b[4] >> 7)
    return None


def _video_pes_pts(packet: bytes) -> int | None:
    """The PTS (90 kHz) of a video PES starting in this TS packet, None otherwise."""
    if not packet[1] & 0x40:  # payload_unit_start_indicator
        return None
    start = 4 + (packet[4] + 1 if (packet[3] >> 4) & 2 else 0)
    pes = packet[start:]
    if len(pes) < 14 or pes[:3] != b"\x00\x00\x01" or not 0xE0 <= pes[3] <= 0xEF:
        return None
    if not pes[7] & 0x80:
        return None
    b = pes[9:14]
    return ((b[0] >> 1) & 7) << 30 | b[1] << 22 | (b[2] >> 1) << 15 | b[3] << 7 | b[4] >> 1


class Sender:
    """Sends an MPEG-TS over UDP in real time, paced by its program clock: 1316-byte datagrams
    as an encoder's UDP output sends them, a fraction `loss` of them dropped and a fraction
    `reorder` swapped with the next (a seeded, repeatable network). `sent` maps each video
    frame's PTS (90 kHz) to when its last datagram left (clock s): latency is measured from it;
    `first_s` and `sent_s` are the first and the newest of those PTS in seconds of the stream's
    clock. The pace is `clock`'s: one that stands still (LockstepClock) holds the sender."""

    def __init__(
        self,
        data: bytes,
        address: tuple[str, int],
        loss: float = 0.0,
        reorder: float = 0.0,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.data = data
        self.address = address
        self.loss, self.reorder = loss, reorder
        self.rng = np.random.default_rng(seed)
        self.clock = clock
        self.sent: dict[int, float] = {}
        self.first_s: float | None = None
        self.sent_s: float | None = None
        self.datagrams = self.dropped = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-sender", daemon=True)

    def start(self) -> Sender:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(5.0)
        self.sock.close()

    def join(self, timeout: float | None = None) -> None:
        """Waits until everything is sent (returns at once when never started)."""
        if self._thread.ident is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        d = self.data
        n = len(d) // TS_PACKET
        step = DATAGRAM_PACKETS
        start = self.clock()
        pcr0 = None
        pts = None
        held: bytes | None = None
        for i in range(0, n, step):
            if self._stop.is_set():
                return
            chunk = d[i * TS_PACKET : min(n, i + step) * TS_PACKET]
            for k in range(0, len(chunk), TS_PACKET):
                p = chunk[k : k + TS_PACKET]
                pcr = _pcr(p)
                if pcr is not None:
                    pcr0 = pcr if pcr0 is None else pcr0
                    due = start + (pcr - pcr0) / 90000.0
                    while (wait := due - self.clock()) > 0 and not self._stop.is_set():
                        self._stop.wait(min(wait, 0.01))  # (read again: the clock may stand)
                v = _video_pes_pts(p)
                if v is not None:
                    pts = v
            self.datagrams += 1
            if self.rng.random() < self.loss:
                self.dropped += 1
            elif held is None and self.rng.random() < self.reorder:
                held = chunk  # sent after the next one
            else:
                self.sock.sendto(chunk, self.address)
                if held is not None:
                    self.sock.sendto(held, self.address)
                    held = None
            if pts is not None:
                self.sent[pts] = self.clock()
                self.sent_s = pts / 90000.0
                self.first_s = self.sent_s if self.first_s is None else self.first_s
        if held is not None:
            self.sock.sendto(held, self.address)
