"""GPX tracks (1.0 and 1.1) for GNSS: track points with time, optional elevation and GPX 1.0's
<speed>; empty segments skipped with a warning; points without time or with a clock that jumps
backwards are clear errors naming the file and point, since they cannot be placed on a timeline.

Heights: GPX <ele> is usually above mean sea level; the session manifest's `gnss.height_offset_m`
(the geoid separation at the site) turns it into the ellipsoidal height geofuse works in.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.io.streams import GnssTrack, plausible_fixes

GPS_EPOCH_UNIX_S = 315964800.0  # 1980-01-06: no GNSS receiver time can be earlier


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _parse_time(text: str) -> float:
    return datetime.fromisoformat(text.strip().replace("Z", "+00:00")).timestamp()


def read_gpx(path: str | Path, messages: Messages | None = None) -> GnssTrack:
    """All track points of all tracks, in file order. Times are Unix seconds (UTC)."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    if not path.is_file():
        raise DataFormatError(path, "file does not exist")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DataFormatError(path, f"not well-formed XML ({exc})", line=exc.position[0]) from exc
    if _local(root.tag) != "gpx":
        raise DataFormatError(path, f"root element is <{_local(root.tag)}>, expected <gpx>")
    rows = []
    speeds = []
    unparsable: dict[str, int] = {}
    point = 0
    for seg_index, seg in enumerate(e for e in root.iter() if _local(e.tag) == "trkseg"):
        pts = [e for e in seg if _local(e.tag) == "trkpt"]
        if not pts:
            messages.add(f"{path.name}: track segment {seg_index + 1} is empty; skipped")
            continue
        for p in pts:
            point += 1
            try:
                lat, lon = float(p.attrib["lat"]), float(p.attrib["lon"])
            except (KeyError, ValueError) as exc:
                raise DataFormatError(
                    path, f"track point {point}: bad or missing lat/lon ({exc})", field="trkpt"
                ) from exc
            fields = {_local(c.tag): (c.text or "") for c in p}
            if "time" not in fields:
                raise DataFormatError(
                    path,
                    f"track point {point} has no <time>: the track cannot be placed on a timeline",
                    field="time",
                )
            try:
                t = _parse_time(fields["time"])
            except ValueError as exc:
                raise DataFormatError(
                    path, f"track point {point}: unparsable <time> {fields['time']!r}", field="time"
                ) from exc
            ele = _optional_number(fields.get("ele", ""), unparsable, "ele")
            rows.append((t, lat, lon, ele))
            speeds.append(_optional_number(fields.get("speed", ""), unparsable, "speed"))
    if not rows:
        raise DataFormatError(path, "no track points (expected <trk><trkseg><trkpt>)")
    for name, count in unparsable.items():
        messages.add(
            f"{path.name}: {count} track points with an unparsable <{name}>: taken as missing"
        )
    arr = np.array(rows)
    early = arr[:, 0] < GPS_EPOCH_UNIX_S
    if early.any():
        k = int(np.flatnonzero(early)[0])
        when = datetime.fromtimestamp(arr[k, 0], UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        raise DataFormatError(
            path,
            f"track point {k + 1} is dated {when}, before GNSS time began (1980): a broken logger clock "
            f"({int(early.sum())} of {len(arr)} points); the track cannot be placed on a timeline",
            field="time",
        )
    dt = np.diff(arr[:, 0])
    if np.any(dt < 0):
        k = int(np.flatnonzero(dt < 0)[0])
        raise DataFormatError(
            path,
            f"the clock jumps backwards by {-dt[k]:.3f} s at track point {k + 2}; the track cannot be placed on a timeline",
            field="time",
        )
    repeat = dt == 0
    if repeat.any():
        messages.add(
            f"{path.name}: {int(repeat.sum())} track points repeat the previous time; dropped"
        )
        keep = np.concatenate([[True], ~repeat])
        arr, speeds = arr[keep], np.asarray(speeds)[keep]
    if np.isnan(arr[:, 3]).any():
        messages.add(
            f"{path.name}: {int(np.isnan(arr[:, 3]).sum())} track points without <ele>; heights interpolated"
        )
        ok = ~np.isnan(arr[:, 3])
        arr[:, 3] = np.interp(arr[:, 0], arr[ok, 0], arr[ok, 3]) if ok.any() else 0.0
    return plausible_fixes(
        GnssTrack(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], None, None, str(path)), messages
    )


def _optional_number(text: str, unparsable: dict[str, int], name: str) -> float:
    """A number, NaN when the element is absent or empty, NaN counted in `unparsable` when it is
    not a finite number."""
    if not text.strip():
        return np.nan
    try:
        value = float(text)
    except ValueError:
        value = np.nan
    if not np.isfinite(value):
        unparsable[name] = unparsable.get(name, 0) + 1
    return value
