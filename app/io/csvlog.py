"""geofuse's generic CSV logs: one file per stream, a header row, comma separated.

Columns (case-insensitive; units in brackets in the header override the defaults):
- time: `t` / `time` / `time_s` (seconds), or `time_ms` / `time_us` / `time_ns` / `timestamp_ns`;
- accelerometer, gyroscope, magnetometer: `x, y, z` in the device frame; defaults m/s^2, rad/s,
  uT; accepted units `[m/s^2]`, `[g]`, `[rad/s]`, `[deg/s]`, `[uT]`, `[nT]`, `[G]` (gauss);
- GNSS: `lat, lon, h` (degrees, degrees, ellipsoidal metres), optional `speed` (m/s) and
  `bearing` (degrees from true north), or `vel_e, vel_n, vel_u` (m/s), optional `h_acc` (m);
- orientation (reference attitude): `qw, qx, qy, qz`, device -> ENU.

Rows with unparsable or NaN values are dropped and counted; a missing column is an error naming
the file and column; times that go backwards or repeat are dropped and counted (streams.py).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from app.core.errors import DataFormatError
from app.io.streams import (
    GnssTrack,
    Messages,
    OrientationStream,
    VectorStream,
    checked_vector,
    clean_times,
    plausible_fixes,
    require_samples,
)

TIME_SCALE = {
    "t": 1.0,
    "time": 1.0,
    "time_s": 1.0,
    "time_ms": 1e-3,
    "time_us": 1e-6,
    "time_ns": 1e-9,
    "timestamp_ns": 1e-9,
}
UNIT_SCALE = {
    "acc": {"m/s^2": 1.0, "m/s2": 1.0, "g": 9.80665},
    "gyr": {"rad/s": 1.0, "deg/s": np.pi / 180.0, "dps": np.pi / 180.0},
    "mag": {"ut": 1.0, "nt": 1e-3, "g": 100.0, "gauss": 100.0, "mg": 0.1},
}
DEFAULT_UNIT = {"acc": "m/s^2", "gyr": "rad/s", "mag": "uT"}
_HEADER = re.compile(r"^\s*([A-Za-z_][\w]*)\s*(?:\[([^\]]*)\])?\s*$")
GYRO_DEG_SUSPECT = 20.0  # rad/s: a phone gyroscope above this is almost surely in deg/s


def read_table(path: Path) -> tuple[dict[str, int], dict[str, str], list[list[str]], int]:
    """(column -> index, column -> unit, data rows, first data line number) of a CSV file."""
    if not path.is_file():
        raise DataFormatError(path, "file does not exist")
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(path, f"cannot read as UTF-8 CSV ({exc})") from exc
    if not rows:
        raise DataFormatError(path, "empty file (expected a header row)", line=1)
    columns: dict[str, int] = {}
    units: dict[str, str] = {}
    for i, cell in enumerate(rows[0]):
        m = _HEADER.match(cell)
        if not m:
            raise DataFormatError(
                path, f"bad column name {cell!r} (expected NAME or NAME[unit])", line=1
            )
        name = m.group(1).lower()
        columns[name] = i
        if m.group(2):
            units[name] = m.group(2).strip()
    return columns, units, rows[1:], 2


def numeric(
    path: Path,
    rows: list[list[str]],
    columns: dict[str, int],
    wanted: list[str],
    first_line: int,
    messages: Messages,
) -> tuple[np.ndarray, np.ndarray]:
    """(values (N, len(wanted)) float64 of the good rows, their line numbers). Rows with missing,
    unparsable or NaN cells are dropped and counted; missing columns are an error."""
    missing = [w for w in wanted if w not in columns]
    if missing:
        raise DataFormatError(
            path,
            f"missing column(s) {missing}; the header has {sorted(columns)}",
            line=1,
            field=missing[0],
        )
    idx = [columns[w] for w in wanted]
    out = np.full((len(rows), len(wanted)), np.nan)
    bad = 0
    first_bad = None
    for r, row in enumerate(rows):
        try:
            out[r] = [float(row[i]) for i in idx]
        except (ValueError, IndexError):
            bad += 1
            first_bad = first_bad or first_line + r
    finite = np.all(np.isfinite(out), axis=1)
    nan_rows = int((~finite).sum()) - bad
    if bad:
        messages.add(
            f"{path.name}: {bad} rows with missing or unparsable numbers dropped (first at line {first_bad})"
        )
    if nan_rows:
        first_nan = first_line + int(np.flatnonzero(~finite & ~np.isnan(out[:, 0]) | ~finite)[0])
        messages.add(
            f"{path.name}: {nan_rows} rows with NaN values dropped (first at line {first_nan})"
        )
    lines = np.arange(first_line, first_line + len(rows))
    return out[finite], lines[finite]


def _time(path: Path, columns: dict[str, int], units: dict[str, str]) -> tuple[str, float]:
    for name, scale in TIME_SCALE.items():
        if name in columns:
            unit = units.get(name, "")
            if unit:
                scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}.get(unit.lower(), None)
                if scale is None:
                    raise DataFormatError(
                        path,
                        f"unknown time unit {unit!r} (expected s, ms, us or ns)",
                        line=1,
                        field=name,
                    )
            return name, scale
    raise DataFormatError(path, f"no time column (expected one of {list(TIME_SCALE)})", line=1)


def _timed(
    path: Path, wanted: list[str], label: str, messages: Messages
) -> tuple[np.ndarray, np.ndarray, dict[str, str]]:
    columns, units, rows, first = read_table(path)
    tname, tscale = _time(path, columns, units)
    values, lines = numeric(path, rows, columns, [tname, *wanted], first, messages)
    # Large integer nanosecond stamps lose precision in float64 seconds only below ~0.1 us.
    t = values[:, 0] * tscale
    keep = clean_times(t, lines, path, label, messages)
    return t[keep], values[keep, 1:], units


def read_vector(
    path: str | Path, kind: str, messages: Messages | None = None
) -> VectorStream | None:
    """An accelerometer ("acc"), gyroscope ("gyr") or magnetometer ("mag") CSV in SI-ish units;
    None for a magnetometer that reads nothing (streams.checked_vector)."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    if kind not in UNIT_SCALE:
        raise ValueError(f"kind must be one of {list(UNIT_SCALE)}")
    t, v, units = _timed(path, ["x", "y", "z"], kind, messages)
    unit = units.get("x", DEFAULT_UNIT[kind])
    scale = UNIT_SCALE[kind].get(unit.lower().replace("µ", "u").replace("²", "^2"))
    if scale is None:
        raise DataFormatError(
            path,
            f"unknown unit {unit!r} for {kind} (expected one of {list(UNIT_SCALE[kind])})",
            line=1,
            field="x",
        )
    v = v * scale
    require_samples(len(t), 2, path, kind)
    if kind == "gyr" and "x" not in units and np.percentile(np.abs(v), 99) > GYRO_DEG_SUSPECT:
        v = np.radians(v)
        messages.add(
            f"{path.name}: gyroscope values up to {np.abs(v).max() * 180 / np.pi:.0f} look like deg/s (no unit in the header); converted to rad/s"
        )
    return checked_vector(VectorStream(kind, t, v, DEFAULT_UNIT[kind], str(path)), messages)


def read_gnss(
    path: str | Path, messages: Messages | None = None, allow_empty: bool = False
) -> GnssTrack:
    """A GNSS CSV: lat, lon, h and optional speed/bearing or vel_e/vel_n/vel_u, h_acc; two fixes
    at least, or none where allow_empty (an empty track: a clip that starts from an area)."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    columns, _, _, _ = read_table(path)
    extra = []
    if {"vel_e", "vel_n"} <= set(columns):
        extra = ["vel_e", "vel_n"] + (["vel_u"] if "vel_u" in columns else [])
    elif {"speed", "bearing"} <= set(columns):
        extra = ["speed", "bearing"]
    acc_col = ["h_acc"] if "h_acc" in columns else []
    t, v, _ = _timed(path, ["lat", "lon", "h", *extra, *acc_col], "GNSS", messages)
    if allow_empty and len(t) == 0:
        return GnssTrack(t, *np.zeros((3, 0)), path=str(path))
    require_samples(len(t), 2, path, "GNSS")
    vel = None
    if extra[:2] == ["vel_e", "vel_n"]:
        vel = np.column_stack([v[:, 3], v[:, 4], v[:, 5] if "vel_u" in extra else np.zeros(len(t))])
    elif extra == ["speed", "bearing"]:
        speed, bearing = v[:, 3], np.radians(v[:, 4])
        vel = np.column_stack([speed * np.sin(bearing), speed * np.cos(bearing), np.zeros(len(t))])
    h_acc = v[:, -1] if acc_col else None
    return plausible_fixes(GnssTrack(t, v[:, 0], v[:, 1], v[:, 2], vel, h_acc, str(path)), messages)


def read_orientation(path: str | Path, messages: Messages | None = None) -> OrientationStream:
    """A reference-attitude CSV: qw, qx, qy, qz (device -> ENU)."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    t, q, _ = _timed(path, ["qw", "qx", "qy", "qz"], "orientation", messages)
    n = np.linalg.norm(q, axis=1)
    if np.any(np.abs(n - 1.0) > 0.05):
        raise DataFormatError(
            path,
            f"quaternions are not unit length (norms {n.min():.3f}..{n.max():.3f})",
            field="qw",
        )
    require_samples(len(t), 2, path, "orientation")
    return OrientationStream(t, q / n[:, None], str(path))
