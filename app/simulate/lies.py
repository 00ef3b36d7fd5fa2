"""GNSS that fails or lies, written into a simulated session (app.simulate.session): a copy of
the session whose gnss.csv jumps, drags off, freezes or stops from a given clip time, the rest
(video, IMU, truth) shared with the original. For the tests and the bench of issue 52
(tests/test_gnss_lies.py, bench/bench_gnss_lies.py).

Clip time is seconds from the simulation's first frame (app.simulate.session.START_UNIX_S);
offsets are local ENU metres of the site (east, north, up).
"""

from __future__ import annotations

import csv
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.geodesy.enu import LocalFrame
from app.simulate.session import START_UNIX_S
from app.simulate.stadium import SITE_ORIGIN

KINDS = ("clean", "jump", "drag", "frozen", "outage")


@dataclass(frozen=True)
class Lie:
    """kind (KINDS) from clip time from_s: `jump` moves every fix from then by size_m east;
    `drag` by speed_mps * (t - from_s) east (a spoofer walking the receiver off, smoothly);
    `frozen` repeats the fix at from_s; `outage` removes the fixes from from_s to until_s.
    Fixes outside [from_s, until_s) are left alone (until_s None: to the end)."""

    kind: str
    from_s: float = 30.0
    until_s: float | None = None
    size_m: float = 200.0
    speed_mps: float = 2.0

    def offset_m(self, t_clip: np.ndarray) -> np.ndarray:
        """(N,) eastward offset (m) the lie adds at clip times t_clip (s)."""
        inside = self.inside(t_clip)
        if self.kind == "jump":
            return np.where(inside, self.size_m, 0.0)
        if self.kind == "drag":
            return np.where(inside, self.speed_mps * (t_clip - self.from_s), 0.0)
        return np.zeros(len(t_clip))

    def inside(self, t_clip: np.ndarray) -> np.ndarray:
        """Which clip times (s) the lie covers."""
        end = np.inf if self.until_s is None else self.until_s
        return (t_clip >= self.from_s) & (t_clip < end)


def falsify(session_dir: str | Path, out: str | Path, lie: Lie) -> Path:
    """A copy of the simulated session in `session_dir` written to `out` with its gnss.csv
    falsified by `lie` (the video linked, not copied, where the file system allows); returns the
    copy's manifest."""
    src, out = Path(session_dir), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        if not f.is_file() or f.name == "gnss.csv":
            continue
        target = out / f.name
        target.unlink(missing_ok=True)
        try:
            target.hardlink_to(f)
        except OSError:
            shutil.copy(f, target)
    with open(src / "gnss.csv", newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    col = {name: i for i, name in enumerate(header)}
    t = np.array([float(r[col["t"]]) for r in body]) - START_UNIX_S
    keep = ~lie.inside(t) if lie.kind == "outage" else np.ones(len(t), bool)
    east = lie.offset_m(t)
    frozen = lie.kind == "frozen" and lie.inside(t).any()
    first = int(np.flatnonzero(lie.inside(t))[0]) if frozen else -1
    frame = LocalFrame(*SITE_ORIGIN)
    for i, r in enumerate(body):
        src_row = body[first] if frozen and lie.inside(t[i : i + 1])[0] else r
        lat, lon, h = (float(src_row[col[k]]) for k in ("lat", "lon", "h"))
        if east[i]:
            enu = frame.geodetic_to_enu(np.array([lat]), np.array([lon]), np.array([h]))[0]
            lat, lon, h = frame.enu_to_geodetic((enu + [east[i], 0.0, 0.0])[None, :])[0]
        r[col["lat"]], r[col["lon"]], r[col["h"]] = f"{lat:.9f}", f"{lon:.9f}", f"{h:.3f}"
        if frozen and lie.inside(t[i : i + 1])[0] and "speed" in col:
            r[col["speed"]] = "0.000"
    with open(out / "gnss.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(r for r, k in zip(body, keep, strict=True) if k)
    return out / "session.toml"
