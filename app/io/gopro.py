"""GoPro MP4 telemetry (GPMF) as stored, read through the MP4 boxes and the GPMF parser (app.io.gpmf).

- The telemetry track is found through PyAV by its handler name ("GoPro MET"); each payload's
  samples are spread evenly over the payload's MP4 time span (plus TIMO where present), on the same
  clock as the video frames' presentation times (seconds from the clip start).
- Axes: ORIN maps the stored values to the IMU's X, Y, Z (a lowercase letter is a negated axis).
  Turning the IMU's axes into the device frame (fitted against CORI), levelling CORI and checking
  MAGN against the World Magnetic Model are attitude work: app/attitude/gopro.py.
- GPS5/GPS9: samples of payloads without a 2D/3D fix (GPSF < 2, or GPS9's own fix field) are
  dropped and counted; GPSP (precision, DOP x 100) is kept; GPSU gives the absolute time.
- Lens: the recorded lens mode's diagonal field of view (ZFOV, and the mode VFOV, in the GPMF
  box of moov/udta) where present, otherwise a documented default per model; `--fov` overrides.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import av
import numpy as np

from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.io.gpmf import Counts, StreamChunk, chunks, parse
from app.io.mp4box import user_data
from app.io.streams import GnssTrack, plausible_fixes
from app.io.video import probe

DEFAULT_ORIN = {
    "HERO5": "ZXY",
    "HERO6": "YxZ",
    "Fusion": "yXZ",
}  # documented data orders where ORIN is absent
GPS_BIN_S = 0.5  # 18 Hz GPS averaged into 2 Hz fixes: smoother velocities for the Hermite track
HFOV_DEG = {
    "max": 92.0,
    "fusion": 100.0,
    "default": 94.4,
}  # horizontal FOV of the linear-ish default lens modes (assumption)


Samples = tuple[np.ndarray, np.ndarray]  # (t (N,) clip seconds, values (N, K))


@dataclass(frozen=True)
class GoProRaw:
    """A GoPro clip's telemetry as stored. acc m/s^2 and gyr rad/s in the IMU's X, Y, Z (ORIN
    applied); cori: CORI quaternions [w, x, y, z] (camera orientation since capture start);
    magn uT in the IMU's axes; times: clip seconds (the video's presentation-time clock)."""

    path: Path
    model: str
    acc: Samples
    gyr: Samples
    cori: Samples | None
    magn: Samples | None
    gnss: GnssTrack | None
    gps_precision: np.ndarray | None  # (n, 2): time s, DOP
    gps_utc_at_zero: float | None  # Unix time of the clip's t = 0, from GPSU
    hfov_deg: float
    counts: Counts = field(default_factory=Counts)
    dropped_no_fix: int = 0
    orin_recorded: bool = True  # False: the file has no ORIN and a default order was applied
    acc_stored: np.ndarray | None = None  # ACCL as stored (no ORIN applied), for choosing an order
    gyr_stored: np.ndarray | None = None


def telemetry_stream(container):
    """The GPMF data stream of an opened PyAV container, or None."""
    for s in container.streams:
        if s.type == "data" and "gopro met" in s.metadata.get("handler_name", "").lower():
            return s
    return None


def read_payloads(path: Path) -> list[tuple[bytes, float, float]]:
    """(payload, t0, t1) of every telemetry sample, with its MP4 time span in seconds."""

    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError) as exc:
        raise DataFormatError(path, f"cannot open video ({exc})") from exc
    with container:
        stream = telemetry_stream(container)
        if stream is None:
            raise DataFormatError(
                path,
                "no GoPro telemetry track (GPMF) in this file: open it with a session manifest, or give a DJI subtitle with --srt",
            )
        tb = float(stream.time_base)
        out = []
        try:
            for p in container.demux(stream):
                if p.size and p.pts is not None:
                    out.append((bytes(p), p.pts * tb, (p.pts + (p.duration or 0)) * tb))
        except av.FFmpegError:
            pass  # a truncated file: keep what was read
    if not out:
        raise DataFormatError(path, "the telemetry track holds no payload (a truncated file?)")
    return out


def global_settings(path: str | Path) -> dict[str, object]:
    """The camera's global settings: the GPMF box in moov/udta (lens mode VFOV, field of view
    ZFOV in degrees, ...). Empty when absent. Reads only box headers and that box."""
    box = user_data(path).get("GPMF")
    if box is None:
        return {}
    try:
        return _flatten(parse(box, f"{path} udta"))
    except DataFormatError:
        return {}


def _flatten(klvs: list) -> dict[str, object]:
    """Every non-nested KLV of a tree by key (the first occurrence wins)."""
    out: dict[str, object] = {}
    for k in klvs:
        if isinstance(k.value, list) and k.value and hasattr(k.value[0], "key"):
            for key, value in _flatten(k.value).items():
                out.setdefault(key, value)
        else:
            out.setdefault(k.key, k.value)
    return out


def lens_hfov(settings: dict[str, object], width: int, height: int) -> float | None:
    """Horizontal FOV (deg) of a pinhole with the recorded diagonal field of view ZFOV (deg) over
    a width x height image; None without ZFOV. GoPro's wide modes are not rectilinear: the pinhole
    matches the diagonal, not the distortion (which geofuse, like the paper, does not model)."""
    z = settings.get("ZFOV")
    if not isinstance(z, np.ndarray) or not 1.0 < float(z.ravel()[0]) < 179.0:
        return None
    half_diag = np.tan(np.radians(float(z.ravel()[0])) / 2)
    return float(np.degrees(2 * np.arctan(half_diag * width / np.hypot(width, height))))


def orin_map(orin: str, values: np.ndarray) -> np.ndarray:
    """Stored values -> IMU X, Y, Z per the ORIN string (lowercase = negated axis). ValueError
    unless ORIN names X, Y and Z once each."""
    if (
        len(orin) < 3
        or sorted(orin[:3].upper()) != ["X", "Y", "Z"]
        or values.ndim != 2
        or values.shape[1] < 3
    ):
        raise ValueError(
            f"ORIN {orin!r} on {values.shape} samples: expected a permutation of X, Y, Z (lower case negated) on 3-axis samples"
        )
    out = np.zeros_like(values[:, :3])
    for i, ch in enumerate(orin[:3]):
        out[:, "XYZ".index(ch.upper())] = values[:, i] * (1.0 if ch.isupper() else -1.0)
    return out


def _times(c: StreamChunk) -> np.ndarray:
    n = len(c.samples)
    timo = (
        float(np.ravel(c.modifiers["TIMO"])[0])
        if isinstance(c.modifiers.get("TIMO"), np.ndarray)
        else 0.0
    )
    return c.t0 + timo + (np.arange(n) + 0.5) / max(n, 1) * (c.t1 - c.t0)


def _gather(parts: list[StreamChunk]) -> tuple[np.ndarray, np.ndarray]:
    t = np.concatenate([_times(c) for c in parts])
    v = np.concatenate([c.samples for c in parts])
    return t, v


def read_gopro_raw(path: str | Path, messages: Messages | None = None) -> GoProRaw:
    """The telemetry of a GoPro MP4 as stored: IMU samples in the IMU's axes (ORIN applied), CORI,
    MAGN, GPS, the lens's field of view. Turning them into the device frame is
    app.attitude.gopro's job."""
    path = Path(path)
    messages = messages if messages is not None else Messages()
    if not path.is_file():
        raise DataFormatError(path, "video file does not exist")
    counts = Counts()
    by_key: dict[str, list[StreamChunk]] = {}
    model = ""
    for i, (payload, t0, t1) in enumerate(read_payloads(path)):
        try:
            tree = parse(payload, f"{path} payload {i}", counts)
        except DataFormatError as exc:
            messages.add(f"{path.name}: telemetry payload {i} skipped ({exc.detail})")
            continue
        for c in chunks(tree, t0, t1):
            model = model or c.device
            by_key.setdefault(c.key, []).append(c)
    if counts.skipped:
        messages.add(f"{path.name}: telemetry keys skipped (undecodable): {counts.skipped}")
    for need in ("ACCL", "GYRO"):
        if need not in by_key:
            raise DataFormatError(
                path,
                f"the telemetry has no {need} stream (expected GoPro HERO5 or later)",
                field=need,
            )
    orin_default = next((v for k, v in DEFAULT_ORIN.items() if k.lower() in model.lower()), "XYZ")
    orin_a = str(by_key["ACCL"][0].modifiers.get("ORIN", orin_default))
    orin_g = str(by_key["GYRO"][0].modifiers.get("ORIN", orin_default))
    ta, a = _gather(by_key["ACCL"])
    tg, g = _gather(by_key["GYRO"])
    a_stored, g_stored = a, g
    orin_recorded = "ORIN" in by_key["ACCL"][0].modifiers and "ORIN" in by_key["GYRO"][0].modifiers
    try:
        a, g = orin_map(orin_a, a), orin_map(orin_g, g)
    except ValueError as exc:
        raise DataFormatError(path, str(exc), field="ORIN") from exc
    cori = _gather(by_key["CORI"]) if "CORI" in by_key else None
    magn = None
    if "MAGN" in by_key:
        tm, mv = _gather(by_key["MAGN"])
        try:
            magn = (tm, orin_map(str(by_key["MAGN"][0].modifiers.get("ORIN", orin_a)), mv))
        except ValueError as exc:
            messages.add(f"{path.name}: MAGN not used ({exc})")
    ratio = real_time_ratio(gpsu_times(by_key))
    if ratio is not None and ratio > TIMELAPSE_RATIO:
        raise DataFormatError(
            path,
            f"a time-lapse or TimeWarp clip: its GPS clock (GPSU) runs {ratio:.1f}x faster than the video; "
            "geofuse places only real-time video (record in normal video mode)",
            field="GPSU",
        )
    gnss, precision, utc0, dropped = _gps(by_key, path, messages)
    lens = next((v for k, v in HFOV_DEG.items() if k in model.lower()), HFOV_DEG["default"])
    w, h = probe(path).display_size
    recorded = lens_hfov(global_settings(path), w, h)
    if recorded is not None:
        lens = recorded
    else:
        messages.add(
            f"{path.name}: no lens field of view in the metadata: {lens:g} deg horizontal assumed for {model or 'this camera'}"
        )
    return GoProRaw(
        path,
        model or "GoPro",
        (ta, a),
        (tg, g),
        cori,
        magn,
        gnss,
        precision,
        utc0,
        lens,
        counts,
        dropped,
        orin_recorded,
        a_stored,
        g_stored,
    )


TIMELAPSE_RATIO = 1.5  # real seconds per video second above which a clip is a time-lapse
TIMELAPSE_MIN_SPAN_S = 3.0  # of video, for the ratio to mean anything (GPSU has 1 s payloads)


def _gpsu_seconds(text: str) -> float | None:
    try:
        return datetime.strptime(text[:16], "%y%m%d%H%M%S.%f").replace(tzinfo=UTC).timestamp()
    except ValueError:
        return None


def gpsu_times(by_key: dict[str, list[StreamChunk]]) -> list[tuple[float, float]]:
    """(video seconds of the payload, GPSU Unix seconds) for every GPS chunk that carries GPSU."""
    out = []
    for key in ("GPS9", "GPS5"):
        for c in by_key.get(key, []):
            u = c.modifiers.get("GPSU")
            s = _gpsu_seconds(u) if isinstance(u, str) else None
            if s is not None:
                out.append((c.t0, s))
        if out:
            break
    return out


def real_time_ratio(pairs: list[tuple[float, float]]) -> float | None:
    """Real seconds per video second over the clip (GPS clock against the MP4's), or None when
    the clip is too short or the GPS clock does not advance."""
    if len(pairs) < 2:
        return None
    (v0, u0), (v1, u1) = pairs[0], pairs[-1]
    if v1 - v0 < TIMELAPSE_MIN_SPAN_S or u1 <= u0:
        return None
    return (u1 - u0) / (v1 - v0)


def _gps(
    by_key: dict[str, list[StreamChunk]], path: Path, messages: Messages
) -> tuple[GnssTrack | None, np.ndarray | None, float | None, int]:
    key = "GPS9" if "GPS9" in by_key else "GPS5" if "GPS5" in by_key else None
    if key is None:
        messages.add(f"{path.name}: no GPS stream (GPS5/GPS9): the camera's position is unknown")
        return None, None, None, 0
    ts, vals, fixes, dops, dop, utc0, dropped = [], [], [], [], [], None, 0
    for c in by_key[key]:
        t = _times(c)
        fix = np.full(
            len(t),
            float(np.ravel(c.modifiers["GPSF"])[0])
            if isinstance(c.modifiers.get("GPSF"), np.ndarray)
            else 3.0,
        )
        if key == "GPS9" and c.samples.shape[1] >= 9:
            fix = c.samples[:, 8].astype(np.float64)
        ok = fix >= 2
        dropped += int((~ok).sum())
        precision = (
            float(np.ravel(c.modifiers["GPSP"])[0]) / 100.0
            if isinstance(c.modifiers.get("GPSP"), np.ndarray)
            else np.nan
        )
        ts.append(t[ok])
        vals.append(c.samples[ok, :5])
        fixes.append(fix[ok])
        dops.append(np.full(int(ok.sum()), precision))
        if np.isfinite(precision):
            dop.append((c.t0, precision))
        if utc0 is None and isinstance(c.modifiers.get("GPSU"), str):
            when = _gpsu_seconds(c.modifiers["GPSU"])
            if when is None:
                messages.add(f"{path.name}: unparsable GPSU {c.modifiers['GPSU']!r}")
            else:
                utc0 = when - c.t0
    if dropped:
        messages.add(f"{path.name}: {dropped} GPS samples without a fix dropped")
    t = np.concatenate(ts) if ts else np.zeros(0)
    v = np.concatenate(vals) if vals else np.zeros((0, 5))
    if len(t) < 2:
        messages.add(f"{path.name}: fewer than two GPS samples with a fix")
        return None, np.array(dop) if dop else None, utc0, dropped
    try:
        raw = plausible_fixes(
            GnssTrack(t, v[:, 0], v[:, 1], v[:, 2], None, None, str(path)),
            messages,
            np.concatenate(fixes),
            np.nan_to_num(np.concatenate(dops), nan=0.0),
        )
    except DataFormatError as exc:
        messages.add(f"{path.name}: GPS not used ({exc.detail})")
        return None, np.array(dop) if dop else None, utc0, dropped
    t = raw.t
    v = np.column_stack([raw.lat, raw.lon, raw.h, np.zeros((len(t), 2))])
    # Average into GPS_BIN_S bins: 18 Hz fixes jitter by decimetres, which Hermite velocities amplify.
    bins = np.floor((t - t[0]) / GPS_BIN_S).astype(int)
    keep = np.unique(bins)
    mean = np.array([v[bins == b].mean(axis=0) for b in keep])
    tb = np.array([t[bins == b].mean() for b in keep])
    return (
        GnssTrack(tb, mean[:, 0], mean[:, 1], mean[:, 2], None, None, str(path)),
        np.array(dop) if dop else None,
        utc0,
        dropped,
    )
