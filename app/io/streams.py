"""The records every reader produces, and the validation they share.

Times are float64 seconds on the log's own clock (Unix seconds when the log has absolute times);
vectors are in the device frame (DESIGN.md): accelerometer m/s^2 (specific force, +up at rest),
gyroscope rad/s, magnetometer uT.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.core.constants import GAP_FACTOR, JUMP_SLACK_M, MAX_SPEED_MPS
from app.core.errors import DataFormatError
from app.core.messages import Messages

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class VectorStream:
    """One 3-axis sensor: t (N,) seconds, values (N, 3) in `unit`, device frame."""

    name: str
    t: FloatArray
    values: FloatArray
    unit: str
    path: str = ""  # the file it was read from (for messages)

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0


@dataclass(frozen=True)
class OrientationStream:
    """Device -> ENU quaternions [w, x, y, z] (N, 4) at t (N,) seconds, e.g. the phone's own fusion."""

    t: FloatArray
    q: FloatArray
    path: str = ""  # the file it was read from (for messages)
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
    path: str = ""  # the file it was read from (for messages)


def with_accuracy(track: GnssTrack, accuracy_m: float) -> tuple[GnssTrack, int]:
    """(the track with accuracy_m (m, 1 sigma per axis) as the stated horizontal accuracy of
    every fix that states none (no h_acc, or a non-finite or non-positive one), how many fixes
    took it)."""
    n = len(track.t)
    given = np.full(n, np.nan) if track.h_acc is None else np.asarray(track.h_acc, np.float64)
    none = ~(np.isfinite(given) & (given > 0))
    if not none.any():
        return track, 0
    return replace(track, h_acc=np.where(none, float(accuracy_m), given)), int(none.sum())


def usual_interval(times: npt.ArrayLike, last: int = 20) -> float | None:
    """The median interval (s) between the last `last` of increasing times (s), None with fewer
    than two (a live feed's fix rate: how old a fix may be before it is held, not current)."""
    t = np.asarray(times, np.float64)[-last:]
    return float(np.median(np.diff(t))) if len(t) >= 2 else None


def resample(t_target: npt.ArrayLike, t_source: npt.ArrayLike, values: npt.ArrayLike) -> FloatArray:
    """Linear interpolation of (M, K) samples at t_source onto t_target (held at the ends)."""
    t_target = np.asarray(t_target, np.float64)
    t_source = np.asarray(t_source, np.float64)
    v = np.asarray(values, np.float64)
    return np.column_stack([np.interp(t_target, t_source, v[:, k]) for k in range(v.shape[1])])


def clean_times(
    t: FloatArray, rows: npt.NDArray[np.int64], path: Path, label: str, messages: Messages
) -> npt.NDArray[np.bool_]:
    """Mask of samples to keep so that time strictly increases: drops NaN times, repeats and
    samples that go backwards (counted, with the first offending line). Notes gaps."""
    keep = np.isfinite(t)
    if (~keep).any():
        messages.add(
            f"{path.name}: {int((~keep).sum())} {label} rows with no time dropped (first at line {int(rows[~keep][0])})"
        )
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
        messages.add(
            f"{path.name}: {label} time goes backwards {back} times and repeats {repeat} times; those rows dropped (first at line {first_bad})"
        )
    tt = t[good]
    if len(tt) > 2:
        dt = np.diff(tt)
        med = np.median(dt)
        gaps = dt > GAP_FACTOR * med
        if gaps.any():
            messages.add(
                f"{path.name}: {int(gaps.sum())} gaps in {label} longer than {GAP_FACTOR:g}x the median step ({med * 1000:.1f} ms), longest {dt.max():.3f} s"
            )
    return good


def require_samples(n: int, minimum: int, path: Path, label: str) -> None:
    if n < minimum:
        raise DataFormatError(path, f"{label}: {n} usable samples, expected at least {minimum}")


# --- where numbers enter: one set of plausibility checks for every reader ---------------------------

RATE_RANGE_HZ = (
    0.5,
    20_000.0,
)  # an IMU sample rate outside this is a time-unit mistake or a broken log
DEAD_SENSOR = {"acc": 0.5, "mag": 0.5}  # median norm (m/s^2, uT) below which a sensor reads nothing
# Norms no sensor of a phone, action camera or drone reports (rad/s, m/s^2, uT): twice a 2000 deg/s
# gyroscope's range, 50 g, a hundred times the Earth's field; samples beyond are not measurements.
SENSOR_LIMIT = {"gyr": 70.0, "acc": 500.0, "mag": 5000.0}
MAX_CLIMB_MPS = 60.0  # vertical speed beyond which a height is a jump, not motion
STEP_S = 2.0  # s: fixes that hold together this long after an impossible step are a step, kept
STEP_FIXES = 5  # and at least this many of them (a 1 Hz receiver's glitch of 3 fixes is a spike)
MAX_DOP = 5.0  # fixes with a worse dilution of precision are not positions to use
HEIGHT_RANGE_M = (-1_000.0, 20_000.0)  # ellipsoidal heights a fix can have


def checked_vector(stream: VectorStream, messages: Messages) -> VectorStream | None:
    """A sensor stream as it enters: rows with non-finite values dropped and counted; a sample
    rate in RATE_RANGE_HZ (else DataFormatError: the time unit is wrong); samples whose norm
    exceeds SENSOR_LIMIT dropped and counted like them; a dead accelerometer
    (reads ~0 throughout) is an error, a dead magnetometer is dropped (None) with a warning."""
    path = Path(stream.path or stream.name)
    finite = np.isfinite(stream.values).all(axis=1) & np.isfinite(stream.t)
    limit = SENSOR_LIMIT.get(stream.name)
    with np.errstate(over="ignore", invalid="ignore"):
        beyond = finite & (
            np.linalg.norm(np.where(finite[:, None], stream.values, 0.0), axis=1)
            > (limit or np.inf)
        )
    if not finite.all():
        messages.add(
            f"{path.name}: {int((~finite).sum())} {stream.name} samples with non-finite values dropped"
        )
    if beyond.any():
        messages.add(
            f"{path.name}: {int(beyond.sum())} {stream.name} samples beyond {limit:g} {stream.unit} (no sensor reads that) dropped"
        )
    if not finite.all() or beyond.any():
        finite = finite & ~beyond
        stream = VectorStream(
            stream.name, stream.t[finite], stream.values[finite], stream.unit, stream.path
        )
    require_samples(len(stream.t), 2, path, stream.name)
    rate = stream.rate_hz
    if not RATE_RANGE_HZ[0] <= rate <= RATE_RANGE_HZ[1]:
        raise DataFormatError(
            path,
            f"{stream.name}: sample rate {rate:.3g} Hz, expected {RATE_RANGE_HZ[0]:g} to {RATE_RANGE_HZ[1]:g} Hz (are the times in the unit the file says?)",
            field="t",
        )
    floor = DEAD_SENSOR.get(stream.name)
    if floor is not None:
        norm = float(np.median(np.linalg.norm(stream.values, axis=1)))
        if norm < floor:
            if stream.name == "acc":
                raise DataFormatError(
                    path,
                    f"the accelerometer reads {norm:.3g} {stream.unit} (median norm): a dead or disconnected sensor, expected about 9.8 m/s^2 of gravity",
                    field="acc",
                )
            messages.add(
                f"{path.name}: the magnetometer reads {norm:.3g} {stream.unit} (median norm): a dead sensor, not used"
            )
            return None
    return stream


def plausible_fixes(
    track: GnssTrack,
    messages: Messages,
    fix_type: npt.ArrayLike | None = None,
    dop: npt.ArrayLike | None = None,
    minimum: int = 1,
) -> GnssTrack:
    """The fixes of a track that are positions, as they enter: dropped and counted, by class, are
    fixes that are not positions (non-finite, out of range, 0 N 0 E before a lock, heights beyond
    HEIGHT_RANGE_M), fixes the receiver itself marks poor (2D fixes where 3D ones exist, DOP above
    MAX_DOP), and jumps (a speed above MAX_SPEED_MPS or a climb above MAX_CLIMB_MPS from the last
    kept fix). DataFormatError when fewer than `minimum` fixes remain, or none is in range."""
    path = Path(track.path or "GNSS")
    t, lat, lon, h = track.t, track.lat, track.lon, track.h
    finite = np.isfinite(t) & np.isfinite(lat) & np.isfinite(lon)
    in_range = finite & (np.abs(np.nan_to_num(lat)) <= 90.0) & (np.abs(np.nan_to_num(lon)) <= 180.0)
    null_island = in_range & (np.abs(lat) < 1e-6) & (np.abs(lon) < 1e-6)
    bad_h = in_range & ~((h >= HEIGHT_RANGE_M[0]) & (h <= HEIGHT_RANGE_M[1]))
    keep = in_range & ~null_island & ~bad_h
    if not in_range[finite].any() and finite.any():
        raise DataFormatError(
            path,
            f"no fix has a latitude in [-90, 90] and a longitude in [-180, 180] degrees (first: {lat[finite][0]:g}, {lon[finite][0]:g})",
            field="lat",
        )
    notes = []
    for label, mask in (
        ("non-finite", ~finite),
        ("out of range", finite & ~in_range),
        ("at 0 N 0 E (no lock yet)", null_island),
        ("with impossible heights", bad_h),
    ):
        if mask.any():
            notes.append(f"{int(mask.sum())} {label}")
    if fix_type is not None:
        f = np.asarray(fix_type, np.float64)
        poor = keep & (f < 3) if (keep & (f >= 3)).any() else np.zeros_like(keep)
        if poor.any():
            notes.append(f"{int(poor.sum())} 2D fixes (3D ones exist)")
        keep &= ~poor
    if dop is not None:
        d = np.asarray(dop, np.float64)
        poor = keep & (d > MAX_DOP)
        if poor.any():
            notes.append(f"{int(poor.sum())} with DOP above {MAX_DOP:g}")
        keep &= ~poor
    jumps, steps = _jumps(t, lat, lon, h, keep)
    if steps:
        first = min(steps)
        messages.add(
            f"{path.name}: the fixes step faster than {MAX_SPEED_MPS:g} m/s {len(steps)} time(s) and hold there "
            f"(first at t = {t[first]:.1f} s, fix {first + 1}): kept, for the checks against the scene and the IMU "
            "to tell which side lies (`registered`, or an IMU's sources)"
        )
    if jumps.any():
        notes.append(
            f"{int(jumps.sum())} jumps (faster than {MAX_SPEED_MPS:g} m/s or climbing faster than {MAX_CLIMB_MPS:g} m/s)"
        )
    keep &= ~jumps
    if notes:
        messages.add(
            f"{path.name}: fixes that are not usable positions dropped: {', '.join(notes)}; {int(keep.sum())} of {len(t)} kept"
        )
    if keep.sum() < max(minimum, 1):
        raise DataFormatError(
            path,
            f"{int(keep.sum())} usable GNSS fixes of {len(t)}, expected at least {max(minimum, 1)}",
        )
    sub = lambda a: None if a is None else np.asarray(a)[keep]  # noqa: E731
    return GnssTrack(
        t[keep], lat[keep], lon[keep], h[keep], sub(track.vel_enu), sub(track.h_acc), track.path
    )


def _jumps(
    t: FloatArray, lat: FloatArray, lon: FloatArray, h: FloatArray, keep: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.bool_], list[int]]:
    """Fixes whose speed from the last accepted fix is impossible: one pass forward and one
    backward from the fix nearest the track's median position (so a bad first fix cannot condemn
    all the others), in local metres. A step is not a jump: where the fixes from an impossible
    one on hold together for STEP_S (a receiver spoofed 200 m away, or honest again after a
    lie), they are all kept, for the checks against the scene and the IMU to tell which side
    lies (dropping them kept whichever side held the median and condemned the other side's
    fixes until the time since made the step look possible: 1.4 s of honest fixes before a
    200 m jump, at 30 Hz)."""
    out = np.zeros(len(t), bool)
    steps: list[int] = []
    idx = np.flatnonzero(keep)
    if len(idx) < 2:
        return out, steps
    k_lat = np.cos(np.radians(np.median(lat[idx])))
    anchor = int(
        np.argmin(
            np.hypot(lat[idx] - np.median(lat[idx]), (lon[idx] - np.median(lon[idx])) * k_lat)
        )
    )
    at = lambda i: (lat[i], lon[i], h[i])  # noqa: E731
    for order in (idx[anchor:], idx[anchor::-1]):
        last = order[0]
        for n in range(1, len(order)):
            i = order[n]
            if impossible_step(abs(t[i] - t[last]), at(last), at(i), k_lat):
                out[i] = not _holds(t, order[n:], at, k_lat)
                if out[i]:
                    continue
                steps.append(int(i))
            last = i
    return out, sorted(set(steps))


def _holds(t: FloatArray, run: npt.NDArray[np.int64], at, cos_lat: float) -> bool:
    """Whether the fixes `run` (indices in a pass's order, from an impossible one) go on
    without an impossible step among themselves for STEP_S or more, STEP_FIXES fixes at least:
    a step, not a spike."""
    for n, (p, q) in enumerate(zip(run[:-1], run[1:], strict=True), 2):
        if impossible_step(abs(t[q] - t[p]), at(p), at(q), cos_lat):
            return False
        if abs(t[q] - t[run[0]]) >= STEP_S and n >= STEP_FIXES:
            return True
    return False


def impossible_step(
    dt_s: float,
    a: tuple[float, float, float],
    b: tuple[float, float, float],
    cos_lat: float | None = None,
) -> bool:
    """Whether going from fix a to fix b (lat deg, lon deg, h m; h may be NaN) in dt_s seconds
    is a jump: faster than MAX_SPEED_MPS across or MAX_CLIMB_MPS up or down (5 m of slack for the
    fixes' own noise). cos_lat: the cosine of the latitude for east distances (a's by default)."""
    k = np.cos(np.radians(a[0])) if cos_lat is None else cos_lat
    dn = np.radians(b[0] - a[0]) * 6_371_000.0
    de = np.radians((b[1] - a[1] + 180.0) % 360.0 - 180.0) * 6_371_000.0 * k
    dh = b[2] - a[2] if np.isfinite(b[2]) and np.isfinite(a[2]) else 0.0
    return bool(
        np.hypot(dn, de) > MAX_SPEED_MPS * dt_s + JUMP_SLACK_M
        or abs(dh) > MAX_CLIMB_MPS * dt_s + JUMP_SLACK_M
    )
