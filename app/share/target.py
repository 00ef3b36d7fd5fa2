"""Where Cursor on Target goes (`--cot URL`): the address checked at once, and the TLS files of
a TAK Server (a client certificate and key, the server's certificate authority) from the
command line or from a `[[tak]]` table of the settings file. Imports nothing heavy: the command
line's parser checks `--cot` with it before anything else loads.

    udp://239.2.3.1:6969          ATAK's mesh SA multicast (every TAK client on the LAN)
    udp://192.168.1.20:4242       one device, unicast
    tcp://HOST:PORT               a stream of events (a TAK Server's plain port, often 8087)
    tls://HOST:PORT               a TAK Server's TLS port (often 8089), with a client certificate

Settings (settings.toml in the platform's config folder, app.core.paths.config_dir):

    [[tak]]
    url = "tls://tak.example.org:8089"     # which --cot this table serves (host and port)
    cert = "~/tak/geofuse.p12"             # PEM certificate (with --cot-key's key), or PKCS#12
    key = "~/tak/geofuse.key"              # PEM key (none with PKCS#12)
    ca = "~/tak/truststore-root.p12"       # the server's CA: PEM or PKCS#12
    password_env = "TAK_CERT_PASSWORD"     # the environment variable holding the password
    check_hostname = true                  # false where the server's certificate names no host

A password is never taken on the command line (others see it there): it comes from the
environment variable a table names, else from GEOFUSE_COT_PASSWORD.
"""

from __future__ import annotations

import ipaddress
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

from app.core.errors import GeofuseError
from app.core.paths import config_dir

__all__ = ["CotTarget", "TlsFiles", "parse_target", "tls_files"]

SCHEMES = ("udp", "tcp", "tls")
EXPECTED = "udp://HOST:PORT, tcp://HOST:PORT or tls://HOST:PORT (e.g. udp://239.2.3.1:6969)"
ENV_PASSWORD = "GEOFUSE_COT_PASSWORD"
TABLE_KEYS = {"url", "cert", "key", "ca", "password_env", "check_hostname"}


@dataclass(frozen=True)
class CotTarget:
    """A CoT receiver: scheme (udp, tcp, tls), host (a name or an IP address, IPv6 without
    brackets) and port."""

    scheme: str
    host: str
    port: int

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"

    @property
    def multicast(self) -> bool:
        try:
            return ipaddress.ip_address(self.host).is_multicast
        except ValueError:
            return False


def parse_target(text: str) -> CotTarget:
    """The target a `--cot` URL names; ValueError (one line, saying what is expected) for
    another scheme, no host, a port that is not one, or a user name or password in it."""
    try:
        parts = urlsplit(text.strip())
        port = parts.port
    except ValueError:
        raise ValueError(f"expected {EXPECTED}; {text!r} has no valid port (1-65535)") from None
    if parts.scheme.lower() not in SCHEMES:
        raise ValueError(f"expected {EXPECTED}, got {text!r}")
    if parts.username is not None or parts.password is not None:
        raise ValueError(
            f"expected {EXPECTED} without a user or password (a TAK Server's client certificate "
            "goes to --cot-cert)"
        )
    if not parts.hostname:
        raise ValueError(f"expected {EXPECTED}; {text!r} names no host")
    if port is None or not 1 <= port <= 65535:
        raise ValueError(f"expected {EXPECTED}; {text!r} has no port (1-65535)")
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        raise ValueError(f"expected {EXPECTED}, got {text!r} (a path or query after the port)")
    return CotTarget(parts.scheme.lower(), parts.hostname, port)


@dataclass(frozen=True)
class TlsFiles:
    """A TLS target's files: cert (PEM, or PKCS#12 holding the key too), key (PEM, or None),
    ca (PEM or PKCS#12; None: the system's authorities), the password of the key or PKCS#12
    (None: none), and whether the server's certificate must name its host."""

    cert: Path | None = None
    key: Path | None = None
    ca: Path | None = None
    password: str | None = field(default=None, repr=False)  # never printed
    check_hostname: bool = True


def _table_for(target: CotTarget, path: Path) -> dict | None:
    """The [[tak]] table of the settings file whose url names the target's host and port."""
    if not path.is_file():
        return None
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeofuseError(f"{path}: cannot read as TOML: {exc}") from exc
    tables = doc.get("tak", [])
    if not isinstance(tables, list):
        raise GeofuseError(f"{path}: 'tak' must be [[tak]] tables")
    for i, table in enumerate(tables):
        where = f"{path}: [[tak]] #{i + 1}"
        unknown = set(table) - TABLE_KEYS
        if unknown:
            raise GeofuseError(
                f"{where}: unknown key(s) {', '.join(sorted(unknown))} (expected {', '.join(sorted(TABLE_KEYS))})"
            )
        try:
            named = parse_target(str(table.get("url", "")))
        except ValueError as exc:
            raise GeofuseError(f"{where}: url: {exc}") from None
        if (named.host, named.port) == (target.host, target.port):
            return table
    return None


def tls_files(
    target: CotTarget,
    cert: Path | None = None,
    key: Path | None = None,
    ca: Path | None = None,
    settings: Path | None = None,
) -> TlsFiles:
    """The TLS files for a tls:// target: those given (the command line's) over those of the
    settings file's [[tak]] table for its host and port. Raises GeofuseError naming a file that
    does not exist, or an unset password variable a table names."""
    path = settings or config_dir() / "settings.toml"
    table = _table_for(target, path) or {}

    def pick(given: Path | None, name: str) -> Path | None:
        value = given if given is not None else table.get(name)
        if value is None:
            return None
        p = Path(str(value)).expanduser()
        if not p.is_file():
            where = f"--cot-{name}" if given is not None else f"{path}: [[tak]] {name}"
            raise GeofuseError(f"{where}: {p} is not a file")
        return p

    password = None
    env = table.get("password_env")
    if env is not None:
        password = os.environ.get(str(env))
        if password is None:
            raise GeofuseError(
                f"{path}: [[tak]] password_env: the environment variable {env} is not set"
            )
    else:
        password = os.environ.get(ENV_PASSWORD)
    return TlsFiles(
        pick(cert, "cert"),
        pick(key, "key"),
        pick(ca, "ca"),
        password,
        bool(table.get("check_hostname", True)),
    )
