"""GNSS that fails or lies, written into a simulated session (app.simulate.session): a copy of
the session whose gnss.csv jumps, drags off, freezes, replays an earlier stretch, lies about its
height or stops from a given clip time, or (`multipath`, no lie: a clean session's hard case)
suffers bursts of multipath it partly states, the rest (video, IMU, truth) shared with the
original.
For the tests and the bench of issue 52 (tests/test_gnss_lies.py, bench/bench_gnss_lies.py).

Clip time is seconds from the simulation's first frame (app.simulate.session.START_UNIX_S);
offsets are local ENU metres of the site (east, north, up).
"""

from __future__ import annotations

import csv
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.geodesy.enu import LocalFrame
from app.simulate.sensors import Multipath, multipath
from app.simulate.session import START_UNIX_S
from app.simulate.stadium import SITE_ORIGIN

KINDS = ("clean", "jump", "drag", "frozen", "replay", "height", "outage", "multipath")


@dataclass(frozen=True)
class Lie:
    """kind (KINDS) from clip time from_s: `jump` moves every fix from then by size_m east;
    `drag` by speed_mps * (t - from_s) east (a spoofer walking the receiver off, smoothly);
    `frozen` repeats the fix at from_s (the receiver stops moving while the aircraft flies on);
    `replay` repeats the fixes of back_s seconds earlier (a recorded stretch played again);
    `height` raises every fix by height_m (up; horizontally right); `outage` removes the fixes
    from from_s to until_s; `multipath` pulls the fixes off in bursts, their stated accuracy
    grown in part (app.simulate.sensors.multipath with `bursts`, drawn from `seed`: not a lie,
    what a clean session in a city suffers). Fixes outside [from_s, until_s) are left alone
    (until_s None: to the end)."""

    kind: str
    from_s: float = 30.0
    until_s: float | None = None
    size_m: float = 200.0
    speed_mps: float = 2.0
    back_s: float = 20.0
    height_m: float = 40.0
    seed: int = 0
    bursts: Multipath = Multipath()

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown lie {self.kind!r}: one of {', '.join(KINDS)}")

    def offset_m(self, t_clip: npt.ArrayLike) -> np.ndarray:
        """(N,) eastward offset (m) the lie adds at clip times t_clip (s)."""
        return self.offset_enu(t_clip)[:, 0]

    def offset_enu(self, t_clip: npt.ArrayLike) -> np.ndarray:
        """(N, 3) offset (ENU m) the lie adds at clip times t_clip (s) to the fix it carries
        (source_index)."""
        t = np.atleast_1d(np.asarray(t_clip, np.float64))
        inside = self.inside(t)
        out = np.zeros((len(t), 3))
        if self.kind == "jump":
            out[:, 0] = np.where(inside, self.size_m, 0.0)
        elif self.kind == "drag":
            out[:, 0] = np.where(inside, self.speed_mps * (t - self.from_s), 0.0)
        elif self.kind == "height":
            out[:, 2] = np.where(inside, self.height_m, 0.0)
        elif self.kind == "multipath" and inside.any():
            out[inside] = self.multipath(t[inside], np.ones(int(inside.sum())))[0]
        return out

    def multipath(
        self, t_clip: np.ndarray, accuracy_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """A `multipath` lie's (extra error (N, 3) ENU m, stated accuracy (N,) m) at clip times
        t_clip (N,) s inside it, from the clean stated accuracy (N,) m (the same bursts for the
        same seed)."""
        return multipath(t_clip, accuracy_m, np.random.default_rng(self.seed), self.bursts)

    def accuracy(self, t_clip: npt.ArrayLike, accuracy_m: npt.ArrayLike) -> np.ndarray:
        """(N,) the stated horizontal accuracy (m) of fixes at clip times t_clip (s) whose clean
        one is accuracy_m (N,): a `multipath` lie's grown inside it, the others as they were."""
        t = np.atleast_1d(np.asarray(t_clip, np.float64))
        out = np.asarray(accuracy_m, np.float64).copy()
        inside = self.inside(t)
        if self.kind == "multipath" and inside.any():
            out[inside] = self.multipath(t[inside], out[inside])[1]
        return out

    def source_index(self, t_clip: npt.ArrayLike) -> np.ndarray:
        """(N,) for fixes at clip times t_clip (s, increasing), the index of the fix whose
        position each one carries: its own, but inside a `frozen` lie the first fix inside it
        and inside a `replay` the fix nearest back_s seconds earlier."""
        t = np.atleast_1d(np.asarray(t_clip, np.float64))
        out = np.arange(len(t))
        inside = self.inside(t)
        if not inside.any():
            return out
        if self.kind == "frozen":
            out[inside] = int(np.flatnonzero(inside)[0])
        elif self.kind == "replay":
            back = t[inside] - self.back_s
            j = np.clip(np.searchsorted(t, back), 1, len(t) - 1)
            nearer = np.where(np.abs(t[j - 1] - back) <= np.abs(t[j] - back), j - 1, j)
            out[inside] = np.where(back < t[0], 0, nearer)
        return out

    def apply(self, t_clip: npt.ArrayLike, enu: npt.ArrayLike) -> np.ndarray:
        """(N, 3) fixes at clip times t_clip (s) with positions enu (N, 3) (ENU m) as the lie
        says them (an outage's fixes kept: remove them with `inside`)."""
        p = np.asarray(enu, np.float64).reshape(-1, 3)
        return p[self.source_index(t_clip)] + self.offset_enu(t_clip)

    def inside(self, t_clip: npt.ArrayLike) -> np.ndarray:
        """Which clip times (s) the lie covers."""
        t = np.asarray(t_clip, np.float64)
        end = np.inf if self.until_s is None else self.until_s
        return (t >= self.from_s) & (t < end)


def falsify(session_dir: str | Path, out: str | Path, lie: Lie) -> Path:
    """A copy of the simulated session in `session_dir` written to `out` with its gnss.csv
    falsified by `lie` (the video linked, not copied, where the file system allows); returns the
    copy's manifest. A frozen fix says speed 0; a replayed one its original's speed and bearing;
    under multipath the stated accuracy (h_acc) grows (Lie.accuracy)."""
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
    shift = lie.offset_enu(t)
    source = lie.source_index(t)
    frame = LocalFrame(*SITE_ORIGIN)
    was = [list(r) for r in body]
    if lie.kind == "multipath" and "h_acc" in col:
        acc = lie.accuracy(t, [float(r[col["h_acc"]]) for r in body])
        for r, a in zip(body, acc, strict=True):
            r[col["h_acc"]] = f"{a:.1f}"
    for i, r in enumerate(body):
        src_row = was[source[i]]
        lat, lon, h = (float(src_row[col[k]]) for k in ("lat", "lon", "h"))
        if shift[i].any():
            enu = frame.geodetic_to_enu(np.array([lat]), np.array([lon]), np.array([h]))[0]
            lat, lon, h = frame.enu_to_geodetic((enu + shift[i])[None, :])[0]
        r[col["lat"]], r[col["lon"]], r[col["h"]] = f"{lat:.9f}", f"{lon:.9f}", f"{h:.3f}"
        if lie.kind == "frozen" and source[i] != i and "speed" in col:
            r[col["speed"]] = "0.000"
        elif lie.kind == "replay" and source[i] != i:
            for k in ("speed", "bearing"):
                if k in col:
                    r[col[k]] = src_row[col[k]]
    with open(out / "gnss.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(r for r, k in zip(body, keep, strict=True) if k)
    return out / "session.toml"
