"""A generic validating reader of TOML files: typed look-ups (numbers finite and in range,
choices, files that must exist, geodetic triples) whose errors name the file and the key, unknown
tables and keys refused with the nearest known one, and arrays of tables walked one by one. It
knows no schema: app.session.config holds the manifest's.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.core.errors import ManifestError


def _suggestion(word: str, known: set[str]) -> str:
    close = difflib.get_close_matches(word, sorted(known), n=1, cutoff=0.5)
    prefix = [k for k in sorted(known) if k.startswith(word) or word.startswith(k)]
    best = close or prefix
    return (
        f"; did you mean {best[0]!r}?" if best else f"; expected one of {', '.join(sorted(known))}"
    )


def check_keys(path: Path, data: dict[str, Any], known: dict[str, set[str]]) -> None:
    """ManifestError naming the first table or key that `known` (table -> its keys) lacks, with
    the nearest known one."""
    for section, table in data.items():
        if section not in known:
            raise ManifestError(
                path,
                f"unknown table [{section}]{_suggestion(section, set(known))}",
                field=section,
            )
        tables = table if isinstance(table, list) else [table]
        for t in tables:
            if not isinstance(t, dict):
                continue  # the table's own reader says what it expected
            for key in t:
                if key not in known[section]:
                    raise ManifestError(
                        path,
                        f"unknown key{_suggestion(key, known[section])}",
                        field=f"{section}.{key}",
                    )


@dataclass(frozen=True)
class Manifest:
    """The TOML tables of a manifest, with typed look-ups whose errors name the key."""

    path: Path
    data: dict[str, Any]

    def section(self, name: str, required: bool = True) -> dict[str, Any]:
        value = self.data.get(name)
        if value is None:
            if required:
                raise ManifestError(self.path, f"missing section [{name}]", field=name)
            return {}
        if not isinstance(value, dict):
            raise ManifestError(self.path, f"[{name}] must be a table", field=name)
        return value

    def get(
        self,
        section: str,
        key: str,
        kind: type | tuple[type, ...],
        default: Any = ...,
        required_section: bool = True,
    ) -> Any:
        sec = self.section(section, required_section)
        if key not in sec:
            if default is ...:
                raise ManifestError(
                    self.path,
                    f"missing key (expected {getattr(kind, '__name__', kind)})",
                    field=f"{section}.{key}",
                )
            return default
        value = sec[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kinds):
            raise ManifestError(
                self.path,
                f"got {value!r}, expected {' or '.join(k.__name__ for k in kinds)}",
                field=f"{section}.{key}",
            )
        return value

    def number(
        self,
        section: str,
        key: str,
        default: Any = ...,
        *,
        low: float = -math.inf,
        high: float = math.inf,
        open_low: bool = False,
        required_section: bool = True,
    ) -> float | None:
        """A finite float in [low, high] (or (low, high] with open_low)."""
        value = self.get(section, key, float, default, required_section)
        if value is None:
            return None
        if not math.isfinite(value) or value < low or value > high or (open_low and value == low):
            bracket = "(" if open_low else "["
            raise ManifestError(
                self.path,
                f"got {value!r}, expected a finite number in {bracket}{low:g}, {high:g}]",
                field=f"{section}.{key}",
            )
        return value

    def choice(
        self,
        section: str,
        key: str,
        options: tuple[str, ...],
        default: str,
        required_section: bool = True,
    ) -> str:
        value = self.get(section, key, str, default, required_section)
        if value not in options:
            raise ManifestError(
                self.path,
                f"got {value!r}, expected {' or '.join(repr(o) for o in options)}",
                field=f"{section}.{key}",
            )
        return value

    def file(
        self, section: str, key: str, required: bool = True, required_section: bool = True
    ) -> Path | None:
        value = self.get(section, key, str, ... if required else None, required_section)
        if value is None:
            return None
        p = (self.path.parent / value).resolve()
        if not p.exists():
            raise ManifestError(
                self.path, f"names {value!r}, which does not exist ({p})", field=f"{section}.{key}"
            )
        return p

    def geodetic(self, section: str, key: str) -> tuple[float, float, float] | None:
        value = self.get(section, key, list, None)
        if value is None:
            return None
        if len(value) != 3 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            raise ManifestError(
                self.path,
                f"got {value!r}, expected [latitude, longitude, height]",
                field=f"{section}.{key}",
            )
        return checked_geodetic(self.path, f"{section}.{key}", *(float(v) for v in value))


def checked_geodetic(
    path: Path, field: str, lat: float, lon: float, h: float
) -> tuple[float, float, float]:
    """(latitude, longitude, height) when each is finite and in range (degrees, degrees,
    ellipsoidal metres); else ManifestError naming `field`."""
    if not (
        math.isfinite(lat)
        and -90.0 <= lat <= 90.0
        and math.isfinite(lon)
        and -180.0 <= lon <= 360.0
        and math.isfinite(h)
        and -12_000.0 <= h <= 100_000.0
    ):
        raise ManifestError(
            path,
            f"got ({lat}, {lon}, {h}), expected latitude in [-90, 90], longitude in [-180, 360] deg, height in [-12000, 100000] m",
            field=field,
        )
    return lat, lon, h


def load_manifest(path: str | Path) -> Manifest:
    """The TOML file at `path` as a Manifest; ManifestError when it is missing or not TOML."""
    path = Path(path)
    if not path.is_file():
        raise ManifestError(path, "manifest does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ManifestError(path, f"not valid TOML ({exc})") from exc
    return Manifest(path.resolve(), data)


def array_tables(m: Manifest, name: str) -> list[tuple[str, Manifest]]:
    """The [[name]] array of tables, each as (its name for errors, e.g. "clips[0]", a Manifest of
    that one table under that name): ManifestError unless it is a list of tables."""
    tables = m.data.get(name, [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ManifestError(m.path, f"expected [[{name}]] tables, each with a path", field=name)
    return [(f"{name}[{i}]", Manifest(m.path, {f"{name}[{i}]": t})) for i, t in enumerate(tables)]
