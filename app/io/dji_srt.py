"""DJI drone subtitle telemetry (.SRT): one entry per second or per video frame, in the layouts DJI
has written over its generations (see docs/FORMATS.md for each, with the traps):

- P4 / P4 RTK / Mavic 2 era, one line: `GPS (lon, lat, sats)`, `HOME (lon, lat, alt m)`, `D`, `H`
  (height above take-off), `H.S`, `V.S`, `F.PRY (pitch, roll, yaw)` (aircraft) and `G.PRY (...)`
  (gimbal = camera);
- Mavic Pro era: `HOME(lon,lat) YYYY.MM.DD hh:mm:ss` then `GPS(lon,lat,n) BAROMETER:h` (height
  above take-off);
- Matrice 300 era: a `YYYY.MM.DD hh:mm:ss` line then `GPS(lat,lon,altM) BAROMETER:hM` (latitude
  first: the altitude carries an `M`);
- Mavic Air 2 / Air 2S / Mini era, per frame: `SrtCnt`, `DiffTime`, `YYYY-MM-DD hh:mm:ss,mmm,uuu`,
  `[latitude: ..] [longitude: ..]` (or `longtitude`), `[altitude: ..]` or `[rel_alt: .. abs_alt: ..]`,
  `[focal_len: ..]`, sometimes `[gb_yaw: .. gb_pitch: .. gb_roll: ..]`, and the digital zoom:
  `[dzoom_ratio: 10000, delta:0]` (Mini 3 era: ten-thousandths), `[dzoom_ratio: 1.00]` (Matrice
  3T/4T thermal: the ratio) or `[dzoom: 1.00]` (Mini 4 Pro, Air 3, Matrice 30: the ratio; their
  entries carry both, `dzoom` read first). The ratio crops the picture: the effective focal
  length is focal_len times it (app.footage.clips draws each frame with its own).

Entries without a position are kept (time only) and counted, as are those at exactly 0, 0 (what DJI
writes while the aircraft has no fix); a file cut mid-entry keeps its complete
entries with a warning; a byte-order mark and CR/LF line ends are accepted; one file may mix layouts.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.io.streams import GnssTrack, plausible_fixes

_TIMING = re.compile(r"(\d+):(\d\d):(\d\d)[,.](\d{1,3})\s*-->\s*(\d+):(\d\d):(\d\d)[,.](\d{1,3})")
_NUM = r"([-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?)"
_GPS_PAREN = re.compile(
    r"GPS\s*\(\s*" + _NUM + r"\s*,\s*" + _NUM + r"\s*,\s*" + _NUM + r"(M?)\s*\)", re.I
)
_HOME = re.compile(
    r"HOME\s*\(\s*" + _NUM + r"\s*,\s*" + _NUM + r"(?:\s*,\s*" + _NUM + r"\s*m?)?\s*\)", re.I
)
_LAT = re.compile(r"\[?\s*latitude\s*:\s*" + _NUM, re.I)
_LON = re.compile(r"\[?\s*long?t?itude\s*:\s*" + _NUM, re.I)  # DJI also writes "longtitude"
_ALT = re.compile(r"\[\s*altitude\s*:\s*" + _NUM, re.I)
_REL_ALT = re.compile(r"rel_alt\s*:\s*" + _NUM, re.I)
_ABS_ALT = re.compile(r"abs_alt\s*:\s*" + _NUM, re.I)
_BARO = re.compile(r"BAROMETER\s*:\s*" + _NUM, re.I)
_H = re.compile(r"(?<![.\w])H\s+" + _NUM + r"\s*m", re.I)
_PRY = {
    "F": re.compile(r"F\.PRY\s*\(\s*" + _NUM + r"\S*\s*,\s*" + _NUM + r"\S*\s*,\s*" + _NUM, re.I),
    "G": re.compile(r"G\.PRY\s*\(\s*" + _NUM + r"\S*\s*,\s*" + _NUM + r"\S*\s*,\s*" + _NUM, re.I),
}
_GB = {k: re.compile(rf"gb_{k}\s*:\s*" + _NUM, re.I) for k in ("yaw", "pitch", "roll")}
_DRONE = {
    k: re.compile(rf"drone_{k}\s*:\s*" + _NUM, re.I) for k in ("yaw", "pitch", "roll")
}  # newer Mini / Air
_DRONE_BRACKET = re.compile(
    r"\[\s*Drone\s*:\s*Yaw\s*:\s*"
    + _NUM
    + r"\s*,\s*Pitch\s*:\s*"
    + _NUM
    + r"\s*,\s*Roll\s*:\s*"
    + _NUM,
    re.I,
)
_FOCAL = re.compile(r"focal_len\s*:\s*" + _NUM, re.I)
_DZOOM = re.compile(r"(?<![\w])dzoom\s*:\s*" + _NUM, re.I)  # the ratio itself
_DZOOM_RATIO = re.compile(r"dzoom_ratio\s*:\s*" + _NUM, re.I)
DZOOM_RANGE = (1.0, 200.0)  # a digital zoom ratio a DJI camera can have (hybrid zoom to 200x)
_DATE_DASH = re.compile(
    r"(\d{4})-(\d\d)-(\d\d)\s+(\d\d):(\d\d):(\d\d)(?:[,.](\d{1,3}))?(?:[,.](\d{1,3}))?"
)
_DATE_DOT = re.compile(r"(\d{4})\.(\d\d)\.(\d\d)\s+(\d\d):(\d\d):(\d\d)")


@dataclass(frozen=True)
class SrtTrack:
    """Per entry: t (N,) seconds from the clip start (the entry's start time); lat, lon (deg; NaN
    where the entry has none); height (m) and whether it is relative to take-off; wall-clock time
    (Unix s, local time of the aircraft taken as UTC: DJI writes no zone) or NaN; gimbal and
    aircraft pitch, roll, yaw (deg) or NaN; 35 mm equivalent focal length (mm; read in each layout's unit) or NaN;
    the digital zoom ratio (1: none) or NaN where the entry gives none or one outside DZOOM_RANGE."""

    path: str
    t: np.ndarray
    t_end: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    height: np.ndarray
    height_relative: bool
    wall_clock: np.ndarray
    gimbal_pry: np.ndarray
    aircraft_pry: np.ndarray
    focal_len: np.ndarray
    layouts: tuple[str, ...]
    dzoom: np.ndarray | None = None  # (N,) the digital zoom ratio; None: a reader that had none

    @property
    def has_position(self) -> np.ndarray:
        return np.isfinite(self.lat) & np.isfinite(self.lon)

    @property
    def has_gimbal(self) -> bool:
        return bool(np.isfinite(self.gimbal_pry).all(axis=1).any())

    def aircraft_yaw(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(t s, yaw deg clockwise from north) of the entries that carry the aircraft's own yaw
        (F.PRY, drone_yaw, [Drone: Yaw ...]), or None."""
        ok = np.isfinite(self.aircraft_pry[:, 2])
        return (self.t[ok], self.aircraft_pry[ok, 2] % 360.0) if ok.sum() >= 2 else None


def _seconds(h: str, m: str, s: str, ms: str) -> float:
    return int(h) * 3600 + int(m) * 60 + int(s) + int(ms.ljust(3, "0")) / 1000.0


def zoom_ratio(text: str) -> float:
    """A DJI digital zoom value as a ratio: written with a decimal point it is the ratio (1.50);
    a whole number from 1000 up is in ten-thousandths (10000: 1x, 15000: 1.5x); a smaller one
    is the ratio (2)."""
    value = float(text)
    return value / 10000.0 if "." not in text and value >= 1000.0 else value


def _entry_fields(text: str) -> tuple[dict[str, float], str]:
    """The numbers of one entry's text and the name of its layout."""
    f: dict[str, float] = {}
    layout = "unknown"
    gps = _GPS_PAREN.search(text)
    if gps:
        a, b, c, m = float(gps.group(1)), float(gps.group(2)), float(gps.group(3)), gps.group(4)
        if m or abs(b) > 90.0:  # Matrice 300 era: latitude first, altitude with an M
            f["lat"], f["lon"], f["alt"] = a, b, c
            layout = "GPS(lat,lon,altM)"
        else:  # older: longitude first, then satellites (or a rough altitude)
            f["lon"], f["lat"] = a, b
            layout = "GPS(lon,lat,n)"
            if abs(a) <= 90.0 and abs(b) > 90.0:
                f["lon"], f["lat"] = b, a
    lat, lon = _LAT.search(text), _LON.search(text)
    if lat and lon:
        f["lat"], f["lon"] = float(lat.group(1)), float(lon.group(1))
        layout = "[latitude][longitude]"
    for key, rx in (
        ("rel", _REL_ALT),
        ("abs", _ABS_ALT),
        ("altitude", _ALT),
        ("baro", _BARO),
        ("H", _H),
    ):
        m = rx.search(text)
        if m:
            f[key] = float(m.group(1))
    m = _DZOOM.search(text) or _DZOOM_RATIO.search(text)
    if m:
        f["dzoom"] = zoom_ratio(m.group(1))
    m = _FOCAL.search(text)
    if (
        m
    ):  # `[focal_len: 24.00]` (Mavic 3, Air 2S): mm; the older `[focal_len : 240]`: tenths of a mm
        f["focal"] = float(m.group(1)) / (1.0 if "." in m.group(1) else 10.0)
    for k, rx in _PRY.items():
        m = rx.search(text)
        if m:
            f[f"{k}p"], f[f"{k}r"], f[f"{k}y"] = (float(m.group(i)) for i in (1, 2, 3))
    if all(rx.search(text) for rx in _GB.values()):
        f["Gp"], f["Gr"], f["Gy"] = (
            float(_GB[k].search(text).group(1)) for k in ("pitch", "roll", "yaw")
        )
    if all(rx.search(text) for rx in _DRONE.values()):
        f["Fp"], f["Fr"], f["Fy"] = (
            float(_DRONE[k].search(text).group(1)) for k in ("pitch", "roll", "yaw")
        )
    m = _DRONE_BRACKET.search(text)
    if m:
        f["Fy"], f["Fp"], f["Fr"] = (float(m.group(i)) for i in (1, 2, 3))
    d = _DATE_DASH.search(text)
    if d:
        g = d.groups()
        base = datetime(*(int(x) for x in g[:6]), tzinfo=UTC).timestamp()
        f["wall"] = (
            base + (int(g[6]) / 1000.0 if g[6] else 0.0) + (int(g[7]) / 1e6 if g[7] else 0.0)
        )
    else:
        d = _DATE_DOT.search(text)
        if d:
            f["wall"] = datetime(*(int(x) for x in d.groups()), tzinfo=UTC).timestamp()
    return f, layout


def read_srt(
    path: str | Path, messages: Messages | None = None, positioned: bool = True
) -> SrtTrack:
    """Every entry of a DJI .SRT. Raises DataFormatError naming the file and entry for an empty
    file, a file without a single complete entry, or (where `positioned`) one without any
    position; without `positioned` such a file is read (said: a clip searched for from an area,
    app.register.coldstart)."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    if not path.is_file():
        raise DataFormatError(path, "subtitle file does not exist")
    raw = path.read_bytes()
    if not raw.strip():
        raise DataFormatError(path, "empty subtitle file (expected DJI telemetry entries)")
    text = raw.decode("utf-8-sig", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    blocks = split_entries(text)
    rows = []
    layouts: set[str] = set()
    incomplete = []
    usual = int(np.median([len(b) for b in blocks]))
    undated = 0
    for n, lines in enumerate(blocks, start=1):
        if n == len(blocks) and n > 1 and len(lines) < usual:
            incomplete.append(n)  # the file stops inside its last entry
            continue
        timing = next((_TIMING.search(line) for line in lines[:3] if _TIMING.search(line)), None)
        body = "\n".join(
            line for line in lines if not _TIMING.search(line) and not line.strip().isdigit()
        )
        fields, layout = _entry_fields(re.sub(r"<[^>]+>", " ", body))
        if (
            timing is None and "wall" in fields
        ):  # older layouts: a date-time line instead of the timing line
            rows.append((np.nan, np.nan, fields))
            layouts.add(layout + ", dated entries")
            undated += 1
            continue
        if timing is None or not body.strip():
            incomplete.append(n)
            continue
        g = timing.groups()
        layouts.add(layout)
        rows.append((_seconds(*g[:4]), _seconds(*g[4:]), fields))
    if undated:
        rows = _times_from_dates(rows)
    if incomplete:
        last = incomplete[-1] == len(blocks)
        where = "the last entry" if incomplete == [len(blocks)] else f"entries {incomplete[:5]}"
        messages.add(
            f"{path.name}: {where} {'is cut short' if last else 'are incomplete'}; the {len(rows)} complete entries are kept"
        )
    if not rows:
        raise DataFormatError(
            path,
            f"no complete subtitle entry among {len(blocks)} blocks (expected 'index, start --> end, telemetry')",
        )

    def col(key: str) -> np.ndarray:
        return np.array([r[2].get(key, np.nan) for r in rows], np.float64)

    lat, lon = col("lat"), col("lon")
    unfixed = (lat == 0.0) & (lon == 0.0)  # DJI's "no fix"
    lat[unfixed], lon[unfixed] = np.nan, np.nan
    missing = ~(np.isfinite(lat) & np.isfinite(lon))
    if missing.all():
        none = f"none of the {len(rows)} entries has a position (GPS, latitude/longitude; 0, 0 is no fix)"
        if positioned:
            raise DataFormatError(path, none)
        messages.add(f"{path.name}: {none}")
    elif missing.any():
        messages.add(
            f"{path.name}: {int(missing.sum())} entries without a position (first: entry {int(np.flatnonzero(missing)[0]) + 1})"
        )
    if len(layouts - {"unknown"}) > 1:
        messages.add(f"{path.name}: mixes layouts {sorted(layouts - {'unknown'})}")
    # Heights: relative to take-off where the layout says so (H, rel_alt, BAROMETER), else absolute.
    for key, relative in (
        ("rel", True),
        ("H", True),
        ("baro", True),
        ("abs", False),
        ("altitude", False),
        ("alt", False),
    ):
        h = col(key)
        if np.isfinite(h).any():
            height, height_relative = h, relative
            break
    else:
        height, height_relative = np.full(len(rows), np.nan), True
    t = np.array([r[0] for r in rows])
    dzoom = col("dzoom")
    odd = np.isfinite(dzoom) & ((dzoom < DZOOM_RANGE[0]) | (dzoom > DZOOM_RANGE[1]))
    if odd.any():
        first = int(np.flatnonzero(odd)[0])
        messages.add(
            f"{path.name}: {int(odd.sum())} entries give a digital zoom (dzoom) of {dzoom[first]:g} or the like (first: entry {first + 1}), expected a ratio from {DZOOM_RANGE[0]:g} to {DZOOM_RANGE[1]:g}: not applied there"
        )
        dzoom[odd] = np.nan
    return SrtTrack(
        str(path),
        t,
        np.array([r[1] for r in rows]),
        lat,
        lon,
        height,
        height_relative,
        col("wall"),
        np.column_stack([col("Gp"), col("Gr"), col("Gy")]),
        np.column_stack([col("Fp"), col("Fr"), col("Fy")]),
        col("focal"),
        tuple(sorted(layouts)),
        dzoom,
    )


def split_entries(text: str) -> list[list[str]]:
    """A subtitle's non-blank lines grouped into entries. An entry starts at its index line (digits
    alone) followed by a timing line (`start --> end`) or, in older layouts, by a date-time line;
    blank lines inside an entry (newer enterprise layouts) do not split it."""
    lines = [line for line in text.split("\n") if line.strip()]
    entries: list[list[str]] = []
    for i, line in enumerate(lines):
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        header = line.strip().isdigit() and bool(
            _TIMING.search(nxt) or _DATE_DASH.match(nxt.strip()) or _DATE_DOT.match(nxt.strip())
        )
        if header or not entries:
            entries.append([])
        entries[-1].append(line)
    return entries


def _cadence_within_seconds(wall: np.ndarray) -> np.ndarray:
    """Date-times truncated to the second (1 Hz logging layouts: several entries share one
    second) are timestamp resolution, not a position jump: each entry's time from the entries'
    cadence, fitted to where each new second begins (seconds per entry by least squares), so
    that every entry keeps its own time. Times with sub-second digits are returned as they are."""
    ok = np.isfinite(wall)
    w = wall[ok]
    if len(w) < 3 or np.any(w != np.round(w)) or len(np.unique(w)) == len(w):
        return wall
    index = np.flatnonzero(ok)
    starts = np.flatnonzero(np.diff(w, prepend=w[0] - 1.0) > 0)  # first entry of each second
    if len(starts) < 2:
        step = 1.0 / len(w)
        return np.where(ok, w[0] + step * (np.arange(len(wall)) - index[0]), np.nan)
    slope, intercept = np.polyfit(index[starts], w[starts] - w[0], 1)
    return np.where(ok, w[0] + intercept + slope * np.arange(len(wall)), np.nan)


def _times_from_dates(
    rows: list[tuple[float, float, dict[str, float]]],
) -> list[tuple[float, float, dict[str, float]]]:
    """Entries of a layout without timing lines: times from their date-time lines, counted from
    the first entry's; each lasts until the next (the last one the median step)."""
    wall = np.array([r[2].get("wall", np.nan) for r in rows])
    if not np.isfinite(wall).any():
        return [r for r in rows if np.isfinite(r[0])]
    w0 = float(np.nanmin(wall))
    wall = _cadence_within_seconds(wall)
    out = [
        (float(w - w0), np.nan, f) if not np.isfinite(t0) else (t0, t1, f)
        for (t0, t1, f), w in zip(rows, wall, strict=True)
    ]
    starts = np.array([r[0] for r in out])
    step = float(np.median(np.diff(starts))) if len(starts) > 1 else 1.0
    ends = np.append(starts[1:], starts[-1] + step)
    return [
        (t0, t1 if np.isfinite(t1) else float(e), f)
        for (t0, t1, f), e in zip(out, ends, strict=True)
    ]


def srt_fixes(track: SrtTrack, messages: Messages, offset_s: float = 0.0) -> GnssTrack:
    """The subtitle's positions as a GNSS track (times + offset_s), through the same plausibility
    gate as every reader (streams.plausible_fixes); heights as the subtitle gives them (missing
    ones 0: above take-off, or the lowest flight height for absolute layouts)."""
    ok = track.has_position
    h = track.height[ok]
    missing = ~np.isfinite(h)
    if missing.any() and not missing.all():
        messages.add(
            f"{Path(track.path).name}: {int(missing.sum())} entries without a height: interpolated"
        )
        h = np.interp(track.t[ok], track.t[ok][~missing], h[~missing])
    elif missing.all():
        h = np.zeros(len(h))
    return plausible_fixes(
        GnssTrack(offset_s + track.t[ok], track.lat[ok], track.lon[ok], h, None, None, track.path),
        messages,
    )


def takeoff_heights(track: SrtTrack, offset_s: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
    """(times + offset_s s, heights m) of the entries that give a height above take-off (H,
    rel_alt, BAROMETER: the barometer's, there with or without a fix), or None (absolute heights
    only, or none)."""
    ok = np.isfinite(track.height)
    if not track.height_relative or not ok.any():
        return None
    return offset_s + track.t[ok], track.height[ok]


def check_duration(track: SrtTrack, video_duration_s: float, tolerance_s: float = 2.0) -> None:
    """An SRT whose entries run past the video (or stop far short of it) belongs to another clip."""
    end = float(track.t_end.max())
    if end > video_duration_s + tolerance_s or end < video_duration_s - max(
        tolerance_s, 0.2 * video_duration_s
    ):
        raise DataFormatError(
            track.path,
            f"its entries span 0-{end:.1f} s but the video lasts {video_duration_s:.1f} s: is it the subtitle of another clip?",
            field="timing",
        )
