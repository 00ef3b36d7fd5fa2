"""GoPro MP4 telemetry (GPMF) as the streams of a session, in the conventions of DESIGN.md.

- The telemetry track is found through PyAV by its handler name ("GoPro MET"); each payload's
  samples are spread evenly over the payload's MP4 time span (plus TIMO where present), on the same
  clock as the video frames' presentation times (seconds from the clip start).
- Axes: ORIN maps the stored values to the IMU's X, Y, Z (a lowercase letter is a negated axis).
  The IMU axes are then turned into GoPro's camera frame (CORI/GRAV's: X right, Y down, Z out of
  the lens, which GRAV shows: gravity along +Y on an upright camera). That turn is fitted per file
  as the signed axis permutation under which the gyroscope matches the rates of the camera's own
  orientation (CORI); without CORI, the one fitted on the GoPro MAX sample is assumed. Finally the
  camera frame becomes our device frame (x right, y up, z toward the viewer): (x, -y, -z).
  Tested with gravity on a camera held upright: the accelerometer reads +g along device +y.
- GPS5/GPS9: samples of payloads without a 2D/3D fix (GPSF < 2, or GPS9's own fix field) are
  dropped and counted; GPSP (precision, DOP x 100) is kept; GPSU gives the absolute time.
- Lens: the recorded lens mode's diagonal field of view (ZFOV, and the mode VFOV, in the GPMF
  box of moov/udta) where present, otherwise a documented default per model; `--fov` overrides.
- MAGN is used only when its field strength is plausible for the place (within 50 % of the World
  Magnetic Model's); otherwise heading comes from the GNSS course.
- CORI (camera orientation since the start of capture) becomes the `camera` pose source: its
  conjugate maps the camera to the capture-start frame; tilt is aligned with gravity here and
  heading by the course later (app/clips.py).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from app import rotations
from app.errors import DataFormatError
from app.io.gpmf import Counts, StreamChunk, chunks, parse
from app.io.streams import GnssTrack, OrientationStream, VectorStream, Warnings, resample

CV_TO_DEVICE = np.diag([1.0, -1.0, -1.0])  # camera (X right, Y down, Z forward) -> device frame
DEFAULT_IMU_TO_CV = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])  # fitted on the MAX sample
DEFAULT_ORIN = {"HERO5": "ZXY", "HERO6": "YxZ", "Fusion": "yXZ"}  # documented data orders where ORIN is absent
GPS_BIN_S = 0.5  # 18 Hz GPS averaged into 2 Hz fixes: smoother velocities for the Hermite track
HFOV_DEG = {"max": 92.0, "fusion": 100.0, "default": 94.4}  # horizontal FOV of the linear-ish default lens modes (assumption)


@dataclass
class GoProRecording:
    path: str
    model: str
    acc: VectorStream
    gyr: VectorStream
    mag: VectorStream | None
    gnss: GnssTrack | None
    gps_precision: np.ndarray | None  # (n, 2): time s, DOP
    gps_utc_at_zero: float | None  # Unix time of the clip's t = 0, from GPSU
    camera: OrientationStream | None
    hfov_deg: float
    counts: Counts = field(default_factory=Counts)
    dropped_no_fix: int = 0


def telemetry_stream(container):
    """The GPMF data stream of an opened PyAV container, or None."""
    for s in container.streams:
        if s.type == "data" and "gopro met" in s.metadata.get("handler_name", "").lower():
            return s
    return None


def read_payloads(path: Path) -> list[tuple[bytes, float, float]]:
    """(payload, t0, t1) of every telemetry sample, with its MP4 time span in seconds."""
    import av

    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError) as exc:
        raise DataFormatError(path, f"cannot open video ({exc})") from exc
    with container:
        stream = telemetry_stream(container)
        if stream is None:
            raise DataFormatError(path, "no GoPro telemetry track (GPMF) in this file: open it with a session manifest, or give a DJI subtitle with --srt")
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


def _boxes(data: bytes, start: int, end: int):
    """(type, payload start, payload end) of the MP4 boxes in data[start:end]."""
    pos = start
    while pos + 8 <= end:
        size = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8].decode("latin-1")
        head = 8
        if size == 1:
            size = int.from_bytes(data[pos + 8 : pos + 16], "big")
            head = 16
        elif size == 0:
            size = end - pos
        if size < head or pos + size > end:
            return
        yield kind, pos + head, pos + size
        pos += size


def global_settings(path: str | Path) -> dict[str, object]:
    """The camera's global settings: the GPMF box in moov/udta (lens mode VFOV, field of view
    ZFOV in degrees, ...). Empty when absent. Reads only the file's box headers and that box."""
    path = Path(path)
    with path.open("rb") as f:
        data = f.read()
    for kind, a, b in _boxes(data, 0, len(data)):
        if kind != "moov":
            continue
        for kind2, a2, b2 in _boxes(data, a, b):
            if kind2 != "udta":
                continue
            for kind3, a3, b3 in _boxes(data, a2, b2):
                if kind3 == "GPMF":
                    try:
                        return _flatten(parse(data[a3:b3], f"{path} udta"))
                    except DataFormatError:
                        return {}
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
    """Stored values -> IMU X, Y, Z per the ORIN string (lowercase = negated axis)."""
    out = np.zeros_like(values[:, :3])
    for i, ch in enumerate(orin[:3]):
        out[:, "XYZ".index(ch.upper())] = values[:, i] * (1.0 if ch.isupper() else -1.0)
    return out


def _times(c: StreamChunk) -> np.ndarray:
    n = len(c.samples)
    timo = float(np.ravel(c.modifiers["TIMO"])[0]) if isinstance(c.modifiers.get("TIMO"), np.ndarray) else 0.0
    return c.t0 + timo + (np.arange(n) + 0.5) / max(n, 1) * (c.t1 - c.t0)


def _gather(parts: list[StreamChunk]) -> tuple[np.ndarray, np.ndarray]:
    t = np.concatenate([_times(c) for c in parts])
    v = np.concatenate([c.samples for c in parts])
    return t, v


def fit_imu_to_camera(t_gyr: np.ndarray, gyr: np.ndarray, t_cori: np.ndarray, cori: np.ndarray) -> tuple[np.ndarray, float]:
    """The signed axis permutation M (proper rotation) with camera rate = M @ gyro rate that best
    matches the rates of conj(CORI); returns (M, median residual / median rate)."""
    q = rotations.conjugate(cori / np.linalg.norm(cori, axis=1, keepdims=True))
    dq = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])
    w = rotations.to_scipy(dq).as_rotvec() / np.maximum(np.diff(t_cori), 1e-6)[:, None]
    tm = (t_cori[:-1] + t_cori[1:]) / 2
    g = resample(tm, t_gyr, gyr)
    best = (np.inf, DEFAULT_IMU_TO_CV)
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for i, (j, s) in enumerate(zip(perm, signs)):
                m[i, j] = s
            if np.linalg.det(m) < 0:
                continue
            r = float(np.median(np.linalg.norm(g @ m.T - w, axis=1)))
            if r < best[0]:
                best = (r, m)
    scale = float(np.median(np.linalg.norm(w, axis=1))) or 1.0
    return best[1], best[0] / scale


def read_gopro(path: str | Path, warnings: Warnings | None = None) -> GoProRecording:
    path = Path(path)
    warnings = warnings if warnings is not None else Warnings()
    if not path.is_file():
        raise DataFormatError(path, "video file does not exist")
    counts = Counts()
    by_key: dict[str, list[StreamChunk]] = {}
    model = ""
    for i, (payload, t0, t1) in enumerate(read_payloads(path)):
        try:
            tree = parse(payload, f"{path} payload {i}", counts)
        except DataFormatError as exc:
            warnings.add(f"{path.name}: telemetry payload {i} skipped ({exc.detail})")
            continue
        for c in chunks(tree, t0, t1):
            model = model or c.device
            by_key.setdefault(c.key, []).append(c)
    if counts.skipped:
        warnings.add(f"{path.name}: telemetry keys skipped (undecodable): {counts.skipped}")
    for need in ("ACCL", "GYRO"):
        if need not in by_key:
            raise DataFormatError(path, f"the telemetry has no {need} stream (expected GoPro HERO5 or later)", field=need)
    orin_default = next((v for k, v in DEFAULT_ORIN.items() if k.lower() in model.lower()), "XYZ")
    orin_a = str(by_key["ACCL"][0].modifiers.get("ORIN", orin_default))
    orin_g = str(by_key["GYRO"][0].modifiers.get("ORIN", orin_default))
    ta, a = _gather(by_key["ACCL"])
    tg, g = _gather(by_key["GYRO"])
    a, g = orin_map(orin_a, a), orin_map(orin_g, g)

    camera = None
    imu_to_cv = DEFAULT_IMU_TO_CV
    if "CORI" in by_key:
        tc, cq = _gather(by_key["CORI"])
        m, rel = fit_imu_to_camera(tg, g, tc, cq)
        if rel < 0.5:
            imu_to_cv = m
        else:
            warnings.add(f"{path.name}: the gyroscope does not match CORI under any axis order (residual {rel:.0%}); the MAX axis mapping is assumed")
        q_cv = rotations.conjugate(cq / np.linalg.norm(cq, axis=1, keepdims=True))
        q_dev = rotations.multiply(q_cv, np.array([0.0, 1.0, 0.0, 0.0]))  # device -> camera-cv is a half turn about x
        camera = OrientationStream(tc, q_dev, str(path), "GoPro CORI: camera orientation since capture start")
    else:
        warnings.add(f"{path.name}: no CORI stream: the IMU axis mapping fitted on the GoPro MAX is assumed")
    to_dev = CV_TO_DEVICE @ imu_to_cv
    acc = VectorStream("acc", ta, a @ to_dev.T, "m/s^2", str(path))
    gyr = VectorStream("gyr", tg, g @ to_dev.T, "rad/s", str(path))
    if camera is not None:
        camera = _level(camera, acc)

    gnss, precision, utc0, dropped = _gps(by_key, path, warnings)
    mag = None
    if "MAGN" in by_key:
        tm, mv = _gather(by_key["MAGN"])
        orin_m = str(by_key["MAGN"][0].modifiers.get("ORIN", orin_a))
        mag = VectorStream("mag", tm, orin_map(orin_m, mv) @ to_dev.T, "uT", str(path))
        mag = _plausible(mag, gnss, utc0, path, warnings)
    lens = next((v for k, v in HFOV_DEG.items() if k in model.lower()), HFOV_DEG["default"])
    settings = global_settings(path)
    from app.io.video import probe

    w, h = probe(path).display_size
    recorded = lens_hfov(settings, w, h)
    if recorded is not None:
        lens = recorded
    else:
        warnings.add(f"{path.name}: no lens field of view in the metadata: {lens:g} deg horizontal assumed for {model or 'this camera'}")
    return GoProRecording(str(path), model or "GoPro", acc, gyr, mag, gnss, precision, utc0, camera, lens, counts, dropped)


MAG_PLAUSIBLE = (0.5, 1.5)  # magnetometer strength / World Magnetic Model strength accepted


def _plausible(mag: VectorStream, gnss: GnssTrack | None, utc0: float | None, path: Path, warnings: Warnings) -> VectorStream | None:
    """The magnetometer, if its field strength is plausible for the place (WMM), else None."""
    from app.geomag import field_enu

    if gnss is None:
        warnings.add(f"{path.name}: no GPS fix to check the magnetometer against the World Magnetic Model: not used")
        return None
    expected = float(np.linalg.norm(field_enu(float(gnss.lat[0]), float(gnss.lon[0]), float(gnss.h[0]), utc0 or 0.0)))
    measured = float(np.median(np.linalg.norm(mag.values, axis=1)))
    if MAG_PLAUSIBLE[0] <= measured / expected <= MAG_PLAUSIBLE[1]:
        return mag
    warnings.add(f"{path.name}: magnetometer reads {measured:.0f} uT where the World Magnetic Model expects {expected:.0f} uT: not used; heading comes from the GNSS course")
    return None


def _level(camera: OrientationStream, acc: VectorStream) -> OrientationStream:
    """CORI's start frame has an arbitrary tilt: turn it so that the accelerometer's mean up (over
    the first second) points to world Up. Heading stays arbitrary until the course fixes it."""
    first = acc.t <= acc.t[0] + 1.0
    up_dev = acc.values[first].mean(axis=0)
    q0 = rotations.slerp(camera.t, camera.q, [acc.t[0] + 0.5])[0]
    up = rotations.rotate(q0, up_dev / np.linalg.norm(up_dev))
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    if s < 1e-9:
        return camera
    angle = np.arctan2(s, up[2])
    turn = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / s])
    return OrientationStream(camera.t, rotations.canonical(rotations.multiply(turn, camera.q)), camera.source, camera.note)


def _gps(by_key: dict[str, list[StreamChunk]], path: Path, warnings: Warnings) -> tuple[GnssTrack | None, np.ndarray | None, float | None, int]:
    key = "GPS9" if "GPS9" in by_key else "GPS5" if "GPS5" in by_key else None
    if key is None:
        warnings.add(f"{path.name}: no GPS stream (GPS5/GPS9): the camera's position is unknown")
        return None, None, None, 0
    ts, vals, dop, utc0, dropped = [], [], [], None, 0
    for c in by_key[key]:
        t = _times(c)
        fix = np.ravel(c.modifiers["GPSF"])[0] if isinstance(c.modifiers.get("GPSF"), np.ndarray) else 3.0
        ok = np.full(len(t), fix >= 2)
        if key == "GPS9" and c.samples.shape[1] >= 9:
            ok = c.samples[:, 8] >= 2
        dropped += int((~ok).sum())
        ts.append(t[ok])
        vals.append(c.samples[ok, :5])
        if isinstance(c.modifiers.get("GPSP"), np.ndarray):
            dop.append((c.t0, float(np.ravel(c.modifiers["GPSP"])[0]) / 100.0))
        if utc0 is None and isinstance(c.modifiers.get("GPSU"), str):
            try:
                when = datetime.strptime(c.modifiers["GPSU"][:16], "%y%m%d%H%M%S.%f").replace(tzinfo=timezone.utc)
                utc0 = when.timestamp() - c.t0
            except ValueError:
                warnings.add(f"{path.name}: unparsable GPSU {c.modifiers['GPSU']!r}")
    if dropped:
        warnings.add(f"{path.name}: {dropped} GPS samples without a fix dropped")
    t = np.concatenate(ts) if ts else np.zeros(0)
    v = np.concatenate(vals) if vals else np.zeros((0, 5))
    if len(t) < 2:
        warnings.add(f"{path.name}: fewer than two GPS samples with a fix")
        return None, np.array(dop) if dop else None, utc0, dropped
    # Average into GPS_BIN_S bins: 18 Hz fixes jitter by decimetres, which Hermite velocities amplify.
    bins = np.floor((t - t[0]) / GPS_BIN_S).astype(int)
    keep = np.unique(bins)
    mean = np.array([v[bins == b].mean(axis=0) for b in keep])
    tb = np.array([t[bins == b].mean() for b in keep])
    return GnssTrack(tb, mean[:, 0], mean[:, 1], mean[:, 2], None, None, str(path)), np.array(dop) if dop else None, utc0, dropped
