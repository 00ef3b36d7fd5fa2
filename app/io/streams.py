"""The records every reader produces, and the validation they share.

Times are float64 seconds on the log's own clock (Unix seconds when the log has absolute times);
vectors are in the device frame (DESIGN.md): accelerometer m/s^2 (specific force, +up at rest),
gyroscope rad/s, magnetometer uT.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.errors import DataFormatError

FloatArray = npt.NDArray[np.float64]
GAP_FACTOR = 5.0  # a step longer than this many median steps counts as a gap


@dataclass
class Warnings:
    """Counted, human-readable notes about repaired input (dropped rows, gaps, unit guesses)."""

    items: list[str] = field(default_factory=list)
    keys: set[str] = field(default_factory=set)

    def add(self, message: str) -> None:
        self.items.append(message)

    def add_once(self, key: str, message: str) -> None:
        """Add `message` unless a note with the same key was added before (solving the same
        source twice must not repeat its notes)."""
        if key not in self.keys:
            self.keys.add(key)
            self.items.append(message)

    def extend(self, other: "Warnings") -> None:
        self.items.extend(other.items)

    def __len__(self) -> int:
        return len(self.items)


@dataclass(frozen=True)
class VectorStream:
    """One 3-axis sensor: t (N,) seconds, values (N, 3) in `unit`, device frame."""

    name: str
    t: FloatArray
    values: FloatArray
    unit: str
    source: str = ""

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0


@dataclass(frozen=True)
class OrientationStream:
    """Device -> ENU quaternions [w, x, y, z] (N, 4) at t (N,) seconds, e.g. the phone's own fusion."""

    t: FloatArray
    q: FloatArray
    source: str = ""
    note: str = ""


@dataclass(frozen=True)
class GnssTrack:
    """GNSS fixes: t (N,) s; lat, lon deg; h m ellipsoidal; optional velocity (N, 3) m/s ENU,
    horizontal accuracy (N,) m."""

    t: FloatArray
    lat: FloatArray
    lon: FloatArray
    h: FloatArray
    vel_enu: FloatArray | None = None
    h_acc: FloatArray | None = None
    source: str = ""


def resample(t_target: npt.ArrayLike, t_source: npt.ArrayLike, values: npt.ArrayLike) -> FloatArray:
    """Linear interpolation of (M, K) samples at t_source onto t_target (held at the ends)."""
    t_target = np.asarray(t_target, np.float64)
    t_source = np.asarray(t_source, np.float64)
    v = np.asarray(values, np.float64)
    return np.column_stack([np.interp(t_target, t_source, v[:, k]) for k in range(v.shape[1])])


def clean_times(t: FloatArray, rows: npt.NDArray[np.int64], path: Path, label: str, warnings: Warnings) -> npt.NDArray[np.bool_]:
    """Mask of samples to keep so that time strictly increases: drops NaN times, repeats and
    samples that go backwards (counted, with the first offending line). Notes gaps."""
    keep = np.isfinite(t)
    if (~keep).any():
        warnings.add(f"{path.name}: {int((~keep).sum())} {label} rows with no time dropped (first at line {int(rows[~keep][0])})")
    idx = np.flatnonzero(keep)
    good = np.zeros(len(t), bool)
    last = -np.inf
    back = repeat = 0
    first_bad = None
    for i in idx:  # one pass; logs are at most a few million rows
        if t[i] > last:
            good[i] = True
            last = t[i]
        else:
            if t[i] == last:
                repeat += 1
            else:
                back += 1
            first_bad = first_bad or int(rows[i])
    if back or repeat:
        warnings.add(f"{path.name}: {label} time goes backwards {back} times and repeats {repeat} times; those rows dropped (first at line {first_bad})")
    tt = t[good]
    if len(tt) > 2:
        dt = np.diff(tt)
        med = np.median(dt)
        gaps = dt > GAP_FACTOR * med
        if gaps.any():
            warnings.add(f"{path.name}: {int(gaps.sum())} gaps in {label} longer than {GAP_FACTOR:g}x the median step ({med * 1000:.1f} ms), longest {dt.max():.3f} s")
    return good


def require_samples(n: int, minimum: int, path: Path, label: str) -> None:
    if n < minimum:
        raise DataFormatError(path, f"{label}: {n} usable samples, expected at least {minimum}")
