"""Cursor on Target out (`--cot URL`): a sink of the sharing hub (app.share.hub) that sends the
aircraft, its point of interest, the footprint and the marks (app.share.cot) to a TAK receiver:
`udp://HOST:PORT` (one datagram per event; unicast, or multicast such as ATAK's mesh
239.2.3.1:6969), `tcp://HOST:PORT` (a stream of events) or `tls://HOST:PORT` (a TAK Server's
TLS port, with a client certificate: app.share.target says where its files come from).

It never blocks the hub: `send_frame` makes the events due (each kind at most RATES_HZ times a
second) and puts them on a bounded outbox that drops its oldest when full; a thread of its own
connects, sends, and drops what went stale while it waited. A target that cannot be reached or
refuses is said once in the run's Messages (by its address; no password or key is ever in a
message) and tried again with a growing pause (BACKOFF_START_S doubling to BACKOFF_MAX_S); what
it says back on a stream is read and thrown away, and its closing the stream is a reason to
connect again. The marks are sent again every MARK_RESEND_S, so a receiver that joins late gets
them, and a mark removed is deleted on the receivers.

The standard library's socket and ssl do the sending. pytak (the kept TAK library) was weighed:
its transports live in an asyncio loop that a `pytak.cli()` application owns, configured
through environment variables or an INI section, with its own queues and reconnection; here
the hub's worker hands events to a thread and wants them dropped, counted and said in its own
Messages, and the wire format (CoT XML, datagram or back to back on a stream) is a few lines.
PKCS#12 (what TAK Server's certificate tools and ATAK's data packages hold) is read with
`cryptography`, as pytak reads it too.
"""

from __future__ import annotations

import os
import secrets
import select
import socket
import ssl
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives.serialization import (
    BestAvailableEncryption,
    Encoding,
    PrivateFormat,
    pkcs12,
)

from app.core.errors import GeofuseError
from app.core.messages import Messages
from app.share.cot import (
    KIND_AIRCRAFT,
    KIND_DELETE,
    KIND_FOOTPRINT,
    KIND_MARK,
    KIND_POI,
    MARK_RESEND_S,
    CotEvent,
    CotIdentity,
    aircraft_event,
    delete_event,
    footprint_events,
    mark_events,
    motion,
    poi_event,
)
from app.share.frames import SharedFrame
from app.share.target import CotTarget, TlsFiles, tls_files

__all__ = ["CotTargets", "TakSink", "cot_targets", "tls_context"]

RATES_HZ = {KIND_AIRCRAFT: 2.0, KIND_POI: 2.0, KIND_FOOTPRINT: 1.0}  # at most, per kind
OUTBOX = 256  # events waiting to be sent; the oldest dropped past it
CONNECT_TIMEOUT_S = 5.0
SEND_TIMEOUT_S = 5.0
BACKOFF_START_S = 0.5
BACKOFF_MAX_S = 30.0
CLOSE_FLUSH_S = 1.0  # at close, what is waiting is sent for at most this long
CLOSE_WAIT_S = 0.5  # and the thread waited for this much longer
MULTICAST_TTL = 1  # the LAN's own segment, as ATAK's mesh SA
PKCS12 = (".p12", ".pfx")
KINDS = (KIND_AIRCRAFT, KIND_POI, KIND_FOOTPRINT, KIND_MARK, KIND_DELETE)


def _pkcs12(path: Path, password: str | None):
    """(key, certificate, other certificates) of a PKCS#12 file; GeofuseError naming it."""
    try:
        return pkcs12.load_key_and_certificates(
            path.read_bytes(), password.encode("utf-8") if password else None
        )
    except ValueError as exc:
        raise GeofuseError(
            f"{path}: cannot open this PKCS#12 file ({exc}); set its password in "
            "GEOFUSE_COT_PASSWORD or the [[tak]] table's password_env"
        ) from None


def _load_client(ctx: ssl.SSLContext, files: TlsFiles) -> None:
    """The client certificate and key: PEM files, or one PKCS#12 (its key written, encrypted
    under a random password, to a private temporary folder only as long as ssl reads it)."""
    cert = files.cert
    if cert is None:
        return
    if cert.suffix.lower() not in PKCS12:
        try:
            ctx.load_cert_chain(cert, files.key, files.password)
        except (ssl.SSLError, OSError) as exc:
            raise GeofuseError(
                f"{cert}: cannot use it as the client certificate{' with ' + str(files.key) if files.key else ''} ({exc})"
            ) from None
        return
    key, leaf, chain = _pkcs12(cert, files.password)
    if key is None or leaf is None:
        raise GeofuseError(f"{cert}: this PKCS#12 file holds no client certificate and key")
    secret = secrets.token_bytes(32)
    with tempfile.TemporaryDirectory(prefix="geofuse-cot-") as folder:
        certfile, keyfile = Path(folder) / "cert.pem", Path(folder) / "key.pem"
        certfile.write_bytes(b"".join(c.public_bytes(Encoding.PEM) for c in [leaf, *chain]))
        fd = os.open(keyfile, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(
                key.private_bytes(
                    Encoding.PEM, PrivateFormat.PKCS8, BestAvailableEncryption(secret)
                )
            )
        ctx.load_cert_chain(certfile, keyfile, secret)


def _load_ca(ctx: ssl.SSLContext, files: TlsFiles) -> None:
    """The authorities the server's certificate must come from: a PEM file, the certificates of
    a PKCS#12 truststore, else the system's."""
    ca = files.ca
    if ca is None:
        ctx.load_default_certs()
        return
    try:
        if ca.suffix.lower() in PKCS12:
            _, leaf, others = _pkcs12(ca, files.password)
            certs: list[x509.Certificate] = ([leaf] if leaf is not None else []) + list(others)
            if not certs:
                raise GeofuseError(f"{ca}: this PKCS#12 truststore holds no certificate")
            ctx.load_verify_locations(
                cadata="".join(c.public_bytes(Encoding.PEM).decode("ascii") for c in certs)
            )
        else:
            ctx.load_verify_locations(cafile=ca)
    except ssl.SSLError as exc:
        raise GeofuseError(f"{ca}: cannot read the certificate authority ({exc})") from None


def tls_context(files: TlsFiles) -> ssl.SSLContext:
    """A TLS 1.2+ client context: the server verified against files.ca (its host name too
    unless files.check_hostname is False), the client certificate presented. GeofuseError for
    a file that cannot be used."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.check_hostname = files.check_hostname
    _load_ca(ctx, files)
    _load_client(ctx, files)
    return ctx


class TakSink:
    """A hub sink sending CoT to one target (see the module docstring). messages: where an
    unreachable target is said; context: a tls:// target's (tls_context); clock: monotonic s
    (rate limits, resends), wall: UTC Unix s (the events' times); both injected in tests."""

    def __init__(
        self,
        target: CotTarget,
        messages: Messages | None = None,
        identity: CotIdentity | None = None,
        context: ssl.SSLContext | None = None,
        rates_hz: dict[str, float] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        if target.scheme == "tls" and context is None:
            raise ValueError(f"{target}: a tls:// target needs its TLS context")
        self.target, self.name = target, f"CoT {target}"
        self.messages = messages if messages is not None else Messages()
        self.who = identity or CotIdentity.of()
        self.context = context
        self.rates_hz = dict(RATES_HZ if rates_hz is None else rates_hz)
        self.clock, self.wall = clock, wall
        self.sent = dict.fromkeys(KINDS, 0)
        self.dropped = 0  # pushed out of a full outbox
        self.expired = 0  # stale before they could be sent
        self.failed = 0  # a send that raised
        self.attempts = self.connects = 0  # tries to connect, and those that did
        self._outbox: deque[CotEvent] = deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._last: dict[str, float] = {}
        self._before: SharedFrame | None = None
        self._marks: dict | None = None
        self._mark_uids: set[str] = set()
        self._resend_at: float | None = None
        self._sock: socket.socket | None = None
        self._down = False  # the last try failed (said once; "reached again" said once)
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    # --- the hub's side: never waits on the network
    def send_frame(self, frame: SharedFrame) -> None:
        """The events of a shared frame that are due (RATES_HZ per kind), queued."""
        now, wall = self.clock(), self.wall()
        moving = motion(self._before, frame) if self._before is not None else None
        self._before = frame
        events: list[CotEvent] = []
        if self._due(KIND_AIRCRAFT, now):
            events.append(aircraft_event(frame, self.who, wall, moving))
        if self._due(KIND_POI, now):
            poi = poi_event(frame, self.who, wall)
            events += [poi] if poi is not None else []
        if self._due(KIND_FOOTPRINT, now):
            events += footprint_events(frame, self.who, wall)
        self._push(events)

    def send_marks(self, marks: dict) -> None:
        """Every mark (a GeoJSON FeatureCollection, lon/lat), and a delete for each mark sent
        before that is gone; sent again every MARK_RESEND_S."""
        wall = self.wall()
        events = mark_events(marks, self.who, wall)
        uids = {e.uid for e in events}
        events += [delete_event(uid, wall) for uid in sorted(self._mark_uids - uids)]
        with self._cond:
            self._marks, self._mark_uids = marks, uids
            self._resend_at = self.clock() + MARK_RESEND_S
        self._push(events)

    def close(self) -> None:
        """Stop: what waits is still sent where the target is connected (for at most
        CLOSE_FLUSH_S, waited for), then the thread closes the connection."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        # unconnected (a connect under way may take CONNECT_TIMEOUT_S) there is nothing to
        # flush: the thread (a daemon) ends and closes its socket by itself, unwaited for
        if self._sock is not None:
            self._thread.join(CLOSE_FLUSH_S + CLOSE_WAIT_S)

    def line(self) -> str:
        """What was sent, for a run's summary."""
        total = sum(self.sent.values())
        kinds = ", ".join(f"{k} {n}" for k, n in self.sent.items() if n)
        with self._cond:
            lost = self.dropped + self.expired + self.failed + len(self._outbox)
        unsent = f", {lost} not sent" if lost else ""
        if self._down and self.target.scheme != "udp":  # a datagram's fate is unknown
            unsent += ", never reached" if total == 0 else ", unreachable at the end"
        return f"{self.name}: {total} events sent{f' ({kinds})' if kinds else ''}{unsent}"

    def _due(self, kind: str, now: float) -> bool:
        rate = self.rates_hz.get(kind, 0.0)
        last = self._last.get(kind)
        if rate > 0 and last is not None and now - last < 1.0 / rate:
            return False
        self._last[kind] = now
        return True

    def _push(self, events: Sequence[CotEvent]) -> None:
        if not events:
            return
        with self._cond:
            for e in events:
                if len(self._outbox) >= OUTBOX:
                    self._outbox.popleft()
                    self.dropped += 1
                self._outbox.append(e)
            self._cond.notify()

    # --- the thread's side
    def _run(self) -> None:
        backoff = BACKOFF_START_S
        try:
            while not self._stop.is_set():
                if not self._wait():
                    continue
                if self._sock is None:
                    try:
                        self._connect()
                    except OSError as exc:
                        self._unreachable(exc)
                        self._stop.wait(backoff)
                        backoff = min(2.0 * backoff, BACKOFF_MAX_S)
                        continue
                    backoff = BACKOFF_START_S
                self._send_next()
            self._flush()
        finally:
            self._disconnect()

    def _wait(self) -> bool:
        """Wait for an event to send (True), the marks' resend, or the stop (False)."""
        with self._cond:
            while not self._outbox and not self._stop.is_set():
                resend = self._resend_at
                if resend is not None and self.clock() >= resend:
                    break
                self._cond.wait(None if resend is None else max(resend - self.clock(), 0.01))
            if self._resend_at is not None and self.clock() >= self._resend_at:
                marks, self._resend_at = self._marks, self.clock() + MARK_RESEND_S
            else:
                marks = None
        if marks is not None:
            self._push(mark_events(marks, self.who, self.wall()))
        return bool(self._outbox) and not self._stop.is_set()

    def _send_next(self) -> None:
        with self._cond:
            if not self._outbox:
                return
            event = self._outbox.popleft()
        if self.wall() > event.stale_s:
            self.expired += 1
            return
        try:
            self._send(event.xml)
        except OSError as exc:
            self.failed += 1
            self._unreachable(exc)
            if self.target.scheme != "udp":  # a stream is connected again; a datagram is not
                self._disconnect()
            return
        self.sent[event.kind] += 1
        if self._down and self.target.scheme != "udp":  # a datagram sent says nothing of that
            self._down = False
            self.messages.add_once(f"{self.name}: reached", f"{self.name}: reached again", "info")

    def _flush(self) -> None:
        """At close: what waits, while the connection holds, for at most CLOSE_FLUSH_S."""
        end = time.monotonic() + CLOSE_FLUSH_S
        while self._outbox and self._sock is not None and time.monotonic() < end:
            self._send_next()

    def _connect(self) -> None:
        t = self.target
        self.attempts += 1
        if t.scheme == "udp":
            family = socket.AF_INET6 if ":" in t.host else socket.AF_INET
            sock = socket.socket(family, socket.SOCK_DGRAM)
            try:
                if t.multicast:
                    level, ttl, loop = (
                        (
                            socket.IPPROTO_IPV6,
                            socket.IPV6_MULTICAST_HOPS,
                            socket.IPV6_MULTICAST_LOOP,
                        )
                        if family == socket.AF_INET6
                        else (socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, socket.IP_MULTICAST_LOOP)
                    )
                    sock.setsockopt(level, ttl, MULTICAST_TTL)
                    sock.setsockopt(level, loop, 1)  # a TAK client on this machine hears it too
                # connected, so that a port nobody listens on is reported (ICMP refused)
                sock.connect((t.host, t.port))
            except OSError:
                sock.close()
                raise
        else:
            sock = socket.create_connection((t.host, t.port), timeout=CONNECT_TIMEOUT_S)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if t.scheme == "tls":
                assert self.context is not None
                try:
                    sock = self.context.wrap_socket(
                        sock, server_hostname=t.host if self.context.check_hostname else None
                    )
                except OSError:
                    sock.close()
                    raise
            sock.settimeout(SEND_TIMEOUT_S)
        self._sock = sock
        self.connects += 1

    def _send(self, data: bytes) -> None:
        sock = self._sock
        assert sock is not None
        if self.target.scheme == "udp":
            sock.send(data)
            return
        sock.sendall(data)
        self._drain(sock)

    def _drain(self, sock: socket.socket) -> None:
        """Read and throw away what the receiver said (a TAK Server's pings, events for us);
        ConnectionResetError when it closed the stream."""
        while select.select([sock], [], [], 0)[0]:
            sock.setblocking(False)
            try:
                data = sock.recv(65536)
            except (BlockingIOError, ssl.SSLWantReadError, ssl.SSLWantWriteError):
                return
            finally:
                sock.settimeout(SEND_TIMEOUT_S)
            if not data:
                raise ConnectionResetError("the receiver closed the connection")

    def _disconnect(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    def _unreachable(self, exc: OSError) -> None:
        self._down = True
        reason = exc.strerror or str(exc) or type(exc).__name__
        self.messages.add_once(
            f"{self.name}: unreachable",
            f"{self.name}: cannot reach it ({reason}); geofuse keeps trying, and what goes stale meanwhile is dropped",
        )


class CotTargets:
    """The --cot targets of a run, checked, with their TLS contexts made: `makers()` for the
    hub's options (each makes a fresh sink per hub, with the hub's Messages), `made` the sinks
    made so far, `lines()` what each sent (the summary of `geofuse live`)."""

    def __init__(
        self,
        targets: Sequence[CotTarget],
        contexts: dict[CotTarget, ssl.SSLContext],
        identity: CotIdentity,
    ) -> None:
        self.targets, self.contexts, self.identity = list(targets), contexts, identity
        self.made: list[TakSink] = []

    def maker(self, target: CotTarget) -> Callable[[Messages], TakSink]:
        def make(messages: Messages) -> TakSink:
            sink = TakSink(target, messages, self.identity, self.contexts.get(target))
            self.made.append(sink)
            return sink

        return make

    def makers(self) -> tuple[Callable[[Messages], TakSink], ...]:
        return tuple(self.maker(t) for t in self.targets)

    def lines(self) -> list[str]:
        return [s.line() for s in self.made]


def cot_targets(
    targets: Sequence[CotTarget],
    cert: Path | None = None,
    key: Path | None = None,
    ca: Path | None = None,
    callsign: str = "geofuse",
    settings: Path | None = None,
) -> CotTargets:
    """The targets of `--cot` (already parsed), each tls:// one's context made now from
    --cot-cert/--cot-key/--cot-ca or its settings table (a file that cannot be used is said
    before anything starts: GeofuseError naming it)."""
    contexts = {}
    for t in targets:
        if t.scheme == "tls" and t not in contexts:
            try:
                contexts[t] = tls_context(tls_files(t, cert, key, ca, settings))
            except GeofuseError as exc:
                raise GeofuseError(f"--cot {t}: {exc}") from None
    return CotTargets(targets, contexts, CotIdentity.of(callsign))
