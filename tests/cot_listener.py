"""A Cursor on Target receiver on the loopback, for tests and bench/bench_cot.py: UDP (one event
per datagram), TCP or TLS (events back to back on a stream; TLS requiring a client certificate
from the test's own authority), each event kept with the monotonic time it arrived. And the
test's public key infrastructure: an authority, a server certificate for 127.0.0.1 and a client
certificate (PEM, and PKCS#12 under a password), made with `cryptography` at test time."""

from __future__ import annotations

import datetime as dt
import ipaddress
import socket
import ssl
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.serialization import pkcs12
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

END = b"</event>"
P12_PASSWORD = "atakatak"  # TAK Server's default for the certificates it makes


class Listener:
    """kind: udp, tcp or tls (server_ctx given); `events` [(arrival monotonic s, xml bytes)],
    `refused` TLS handshakes that failed (a client without a valid certificate)."""

    def __init__(self, kind: str, server_ctx: ssl.SSLContext | None = None) -> None:
        self.kind, self.server_ctx = kind, server_ctx
        self.events: list[tuple[float, bytes]] = []
        self.refused: list[str] = []
        self.connections = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        udp = kind == "udp"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        if not udp:
            self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.url = f"{kind}://127.0.0.1:{self.port}"
        self._threads = [threading.Thread(target=self._udp if udp else self._accept, daemon=True)]
        self._threads[0].start()

    def xml(self) -> list[bytes]:
        with self._lock:
            return [x for _, x in self.events]

    def close(self) -> None:
        self._stop.set()
        for t in list(self._threads):
            t.join(2.0)
        self.sock.close()

    def _keep(self, data: bytes) -> None:
        with self._lock:
            self.events.append((time.monotonic(), data.strip()))

    def _udp(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            self._keep(data)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            t = threading.Thread(target=self._stream, args=(conn,), daemon=True)
            self._threads.append(t)
            t.start()

    def _stream(self, conn: socket.socket) -> None:
        conn.settimeout(0.05)
        if self.server_ctx is not None:
            try:
                conn.settimeout(5.0)
                conn = self.server_ctx.wrap_socket(conn, server_side=True)
                conn.settimeout(0.05)
            except (ssl.SSLError, OSError) as exc:
                self.refused.append(str(exc))
                conn.close()
                return
        self.connections += 1
        buf = b""
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except (TimeoutError, ssl.SSLWantReadError):
                    continue
                except OSError:
                    return
                if not data:
                    return
                buf += data
                while END in buf:
                    event, buf = buf.split(END, 1)
                    self._keep(event + END)


@dataclass(frozen=True)
class Pki:
    """The files of a test authority: ca.pem; server.pem/server.key (127.0.0.1, localhost);
    client.pem/client.key and client.p12 (P12_PASSWORD)."""

    folder: Path

    def __truediv__(self, name: str) -> Path:
        return self.folder / name

    def server_context(self) -> ssl.SSLContext:
        """A TLS server requiring a client certificate from the authority."""
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.load_cert_chain(self.folder / "server.pem", self.folder / "server.key")
        ctx.load_verify_locations(self.folder / "ca.pem")
        ctx.verify_mode = ssl.CERT_REQUIRED
        return ctx


def _name(common: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common)])


def _cert(subject, key, issuer, issuer_key, ca: bool, sans=None, usage=None) -> x509.Certificate:
    now = dt.datetime.now(dt.UTC)
    b = (
        x509.CertificateBuilder()
        .subject_name(_name(subject))
        .issuer_name(_name(issuer))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
    )
    if sans:
        b = b.add_extension(x509.SubjectAlternativeName(sans), critical=False)
    if usage:
        b = b.add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
    return b.sign(issuer_key, hashes.SHA256())


def make_pki(folder: Path) -> Pki:
    """A fresh authority with a server and a client certificate (see Pki)."""
    folder.mkdir(parents=True, exist_ok=True)
    pem = serialization.Encoding.PEM
    raw = serialization.NoEncryption()
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = _cert("geofuse test CA", ca_key, "geofuse test CA", ca_key, True)
    (folder / "ca.pem").write_bytes(ca.public_bytes(pem))
    sans = [x509.IPAddress(ipaddress.ip_address("127.0.0.1")), x509.DNSName("localhost")]
    for who, san, usage in (
        ("server", sans, ExtendedKeyUsageOID.SERVER_AUTH),
        ("client", None, ExtendedKeyUsageOID.CLIENT_AUTH),
    ):
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _cert(f"geofuse test {who}", key, "geofuse test CA", ca_key, False, san, usage)
        (folder / f"{who}.pem").write_bytes(cert.public_bytes(pem))
        (folder / f"{who}.key").write_bytes(
            key.private_bytes(pem, serialization.PrivateFormat.PKCS8, raw)
        )
        if who == "client":
            (folder / "client.p12").write_bytes(
                pkcs12.serialize_key_and_certificates(
                    b"geofuse",
                    key,
                    cert,
                    [ca],
                    serialization.BestAvailableEncryption(P12_PASSWORD.encode()),
                )
            )
    return Pki(folder)
