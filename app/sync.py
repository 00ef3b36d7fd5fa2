"""Automatic video <-> sensor time offset (`geofuse sync`): the camera's rotation rate seen in the
video against the gyroscope's.

1. Video: sparse optical flow (OpenCV's pyramidal Lucas-Kanade on corners) between consecutive
   frames of a reduced grey copy; each pair's feature bearings (through the session's lens or
   pinhole) give the frame-to-frame rotation by a least-squares fit (Kabsch) with outlier
   rejection; rotation / time step = the rate (rad/s, camera frame) at the pair's mid time.
2. Gyroscope: its rates turned from the device frame into the camera frame by the mount.
3. Coarse: the lag that maximises the cross-correlation of the two rate magnitudes over the
   whole clip (+-MAX_LAG_S); fine: the lag, in 1 ms steps within +-FINE_RANGE_S of it and refined
   by a parabola, that best fits the three rate components on the windows with the most
   rotation. The result is the offset to add to the video's times (seconds; video.time_offset_s).
4. Drift, on long clips: each strong window's own lag, regressed on time; kept when it moves the
   clip's ends by DRIFT_MIN_EFFECT_S or more.

Times: media seconds (the video's presentation times) and session seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import rotations
from app.errors import GeofuseError

FLOW_WIDTH_PX = 320  # the video is reduced to this width for the flow
MAX_FEATURES = 200
MIN_TRACKS = 12  # pairs with fewer tracked features give no rate
MAX_LAG_S = 2.0
FINE_RANGE_S = 0.25  # the fine fit searches this far either side of the coarse lag
GRID_HZ = 500.0  # both rate curves are resampled on this grid
WINDOW_S = 1.0
DRIFT_MIN_SPAN_S = 40.0  # a clock drift is fitted only over clips whose strong windows span this
DRIFT_LOCAL_S = 0.05  # each window's own offset is searched this far around the clip's
DRIFT_MIN_EFFECT_S = 0.005  # a fitted drift that moves the clip's ends by less than this is noise: 0
STRONG_FRACTION = 0.3  # the fine fit uses the windows whose rotation is in the top 30 %


@dataclass(frozen=True)
class RateCurve:
    """Rotation rates: t (N,) seconds; omega (N, 3) rad/s in the camera frame (OpenGL axes)."""

    t: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class SyncResult:
    """offset_s: add to the video's times; confidence: the mean correlation coefficient (0..1) of
    the three rate components at that offset, on the fitted windows; windows: (start, end) session seconds of the windows fitted;
    coarse_s: the magnitude correlation's lag."""

    offset_s: float
    confidence: float
    windows: tuple[tuple[float, float], ...]
    coarse_s: float
    drift_ppm: float = 0.0  # the video clock's rate error against the sensors' (parts per million)
    reference_s: float = 0.0  # session time at which offset_s holds exactly (the drift's pivot)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R (3x3) minimising sum |b - R a|^2 over unit vectors (N, 3)."""
    h = a.T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def frame_rotation(b1: np.ndarray, b2: np.ndarray) -> np.ndarray | None:
    """R with b2 ~ R b1 (bearings (N, 3)), refitted without the worst third of residuals."""
    if len(b1) < MIN_TRACKS:
        return None
    r = _kabsch(b1, b2)
    res = np.linalg.norm(b2 - b1 @ r.T, axis=1)
    keep = res <= np.percentile(res, 67)
    return _kabsch(b1[keep], b2[keep]) if keep.sum() >= MIN_TRACKS else r


def video_rates(video, bearings: Callable[[np.ndarray], np.ndarray], rotation_cw: int, progress: Callable[[float], None] | None = None) -> RateCurve:
    """The camera's rotation rate between consecutive frames (see the module docstring).
    bearings: display pixels (N, 2) -> unit vectors (N, 3) in OpenCV's camera frame."""
    import av
    import cv2

    from app.io.video import media_seconds

    w, h = video.width, video.height
    scale = FLOW_WIDTH_PX / w
    size = (FLOW_WIDTH_PX, max(2, round(h * scale)))
    k = (rotation_cw // 90) % 4
    t_out, w_out = [], []
    prev = prev_t = None
    n = len(video.pts_s)
    with av.open(str(video.path)) as c:
        stream = c.streams.video[0]
        stream.thread_type = "AUTO"
        for i, frame in enumerate(c.decode(stream)):
            if frame.pts is None:
                continue
            t = media_seconds(frame.pts, stream.time_base, video.origin_s)
            grey = np.ascontiguousarray(np.rot90(frame.reformat(width=size[0], height=size[1], format="gray").to_ndarray(), k=-k))
            if prev is not None and t > prev_t:
                pts = cv2.goodFeaturesToTrack(prev, MAX_FEATURES, 0.01, 6)
                if pts is not None and len(pts) >= MIN_TRACKS:
                    nxt, ok, _ = cv2.calcOpticalFlowPyrLK(prev, grey, pts, None, winSize=(15, 15), maxLevel=3)
                    ok = ok.ravel() == 1
                    if ok.sum() >= MIN_TRACKS:
                        p1 = (pts[ok, 0, :] + 0.5) / scale  # display pixels of the full video
                        p2 = (nxt[ok, 0, :] + 0.5) / scale
                        rot = frame_rotation(bearings(p1), bearings(p2))
                        if rot is not None:
                            # b2 = D^T b1 for a body turn D: the camera's rate is -rotvec(R) / dt.
                            rv = -rotations.to_scipy(rotations.from_matrix(rot)).as_rotvec() / (t - prev_t)
                            t_out.append((t + prev_t) / 2)
                            w_out.append([rv[0], -rv[1], -rv[2]])  # OpenCV camera axes -> OpenGL's
            prev, prev_t = grey, t
            if progress is not None and i % 50 == 0:
                progress(min(1.0, i / max(n, 1)))
    if progress is not None:
        progress(1.0)
    if len(t_out) < 10:
        raise GeofuseError(f"{video.path}: too few frames with trackable features to see the camera turn ({len(t_out)})")
    return RateCurve(np.asarray(t_out), np.asarray(w_out))


def _on_grid(curve: RateCurve, t: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t, curve.t, curve.omega[:, j], left=np.nan, right=np.nan) for j in range(3)])


def _score(video: RateCurve, gyro: RateCurve, lag: float, t: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared difference of the three components, video at t against gyro at t + lag."""
    a, b = _on_grid(video, t), _on_grid(gyro, t + lag)
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    if mask is not None:
        ok &= mask
    return float(np.mean(np.sum((a[ok] - b[ok]) ** 2, axis=1))) if ok.sum() > 10 else np.inf


def estimate_offset(video: RateCurve, gyro: RateCurve, clip_start_s: float) -> SyncResult:
    """The offset (s) that aligns the video's rates (media time + clip_start_s) with the
    gyroscope's (session time); see the module docstring."""
    v = RateCurve(video.t + clip_start_s, video.omega)
    t = np.arange(v.t[0], v.t[-1], 1.0 / GRID_HZ)
    mag_v = np.nan_to_num(np.linalg.norm(_on_grid(v, t), axis=1))
    lags = np.arange(-MAX_LAG_S, MAX_LAG_S + 1e-9, 1.0 / GRID_HZ)
    mag_g_full = np.linalg.norm(_on_grid(gyro, np.arange(t[0] - MAX_LAG_S, t[-1] + MAX_LAG_S + 1e-9, 1.0 / GRID_HZ)), axis=1)
    mag_g_full = np.nan_to_num(mag_g_full)
    mv = mag_v - mag_v.mean()
    corr = np.array([np.dot(mv, mag_g_full[i : i + len(mv)] - mag_g_full[i : i + len(mv)].mean()) for i in range(len(lags))])
    coarse = float(lags[int(np.argmax(corr))])
    # Windows with the most rotation (where timing errors show most).
    edges = np.arange(t[0], t[-1], WINDOW_S)
    energy = np.array([np.mean(mag_v[(t >= e) & (t < e + WINDOW_S)] ** 2) for e in edges])
    strong_edges = edges[energy >= np.quantile(energy, 1.0 - STRONG_FRACTION)]
    mask = np.zeros(len(t), bool)
    for e in strong_edges:
        mask |= (t >= e) & (t < e + WINDOW_S)
    fine_lags = np.arange(coarse - FINE_RANGE_S, coarse + FINE_RANGE_S + 1e-9, 0.001)
    tm = t[mask]  # the strong windows' grid only
    scores = np.array([_score(v, gyro, lag, tm) for lag in fine_lags])
    best = _parabolic_min(fine_lags, scores)
    a, b = _on_grid(v, t), _on_grid(gyro, t + best)
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & mask
    confidence = float(np.mean([np.corrcoef(a[ok, j], b[ok, j])[0, 1] for j in range(3)])) if ok.sum() > 10 else 0.0
    drift, pivot = _drift(v, gyro, best, strong_edges, t)
    return SyncResult(best, max(0.0, confidence), tuple((float(e), float(e + WINDOW_S)) for e in strong_edges), coarse, drift, pivot)


def _parabolic_min(lags: np.ndarray, scores: np.ndarray) -> float:
    """The lag of the lowest score, refined by the parabola through it and its neighbours."""
    k = int(np.argmin(scores))
    best = float(lags[k])
    if 0 < k < len(scores) - 1 and np.isfinite(scores[k - 1 : k + 2]).all():
        s0, s1, s2 = scores[k - 1 : k + 2]
        denom = s0 - 2 * s1 + s2
        if denom > 0:
            best += float(lags[1] - lags[0]) * 0.5 * (s0 - s2) / denom
    return best


def _drift(v: RateCurve, gyro: RateCurve, offset: float, edges: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """(drift ppm, pivot time): each strong window's own best lag near the clip's, regressed on
    time; 0 when the windows span less than DRIFT_MIN_SPAN_S (too short a clip to see it)."""
    pivot = float(np.mean(edges + WINDOW_S / 2)) if len(edges) else float(t[0])
    if len(edges) < 6 or np.ptp(edges) < DRIFT_MIN_SPAN_S:
        return 0.0, pivot
    lags = np.arange(offset - DRIFT_LOCAL_S, offset + DRIFT_LOCAL_S + 1e-9, 0.001)
    local = []
    for e in edges:
        tw = t[(t >= e) & (t < e + WINDOW_S)]  # this window's grid only
        local.append(_parabolic_min(lags, np.array([_score(v, gyro, lag, tw) for lag in lags])))
    slope, _ = np.polyfit(edges + WINDOW_S / 2 - pivot, np.asarray(local), 1)
    if abs(slope) * np.ptp(edges) < DRIFT_MIN_EFFECT_S:
        return 0.0, pivot
    return float(slope * 1e6), pivot


ATTITUDE_SMOOTH_S = 0.15  # moving average of rates differentiated from recorded attitudes
RECORDED_FOR_RATES = ("telemetry", "camera", "phone")  # recorded attitudes, best first, when no gyroscope


def attitude_rates(t: np.ndarray, q: np.ndarray) -> RateCurve:
    """Body rates (rad/s, the device frame) between successive attitudes q (N, 4) device -> world
    at times t (N,) s, at the midpoints: the rotation vector of q_i* q_(i+1) over the interval.
    (`omega` is then in the device frame; gyro_rates turns it into the camera frame.)"""
    t = np.asarray(t, np.float64)
    dt = np.diff(t)
    keep = dt > 1e-6
    step = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])[keep]
    rates = rotations.to_scipy(step).as_rotvec() / dt[keep, None]
    mid = (t[:-1] + t[1:])[keep] / 2.0
    # attitudes carry sample-to-sample noise that differentiation amplifies: a centred moving
    # average over ATTITUDE_SMOOTH_S (symmetric, so it moves no time) keeps the turns
    n = max(1, int(round(ATTITUDE_SMOOTH_S / max(float(np.median(dt[keep])), 1e-6))) | 1)
    if n > 1 and len(rates) > n:
        from scipy.ndimage import uniform_filter1d

        rates = uniform_filter1d(rates, n, axis=0, mode="nearest")
    return RateCurve(mid, rates)


def rate_source(session) -> str | None:
    """What times the video: 'gyroscope', a recorded attitude's name, or None (nothing turns)."""
    if session.gyr is not None:
        return "gyroscope"
    return next((n for n in RECORDED_FOR_RATES if n in session.recorded), None)


def gyro_rates(session) -> RateCurve:
    """The session's rotation rates in the camera frame of the displayed video: its gyroscope's,
    or, without one, those of a recorded attitude (a DJI gimbal's, a camera's or a phone's own),
    differentiated; raises when it has neither."""
    mount = rotations.conjugate(session.camera_mount())
    name = rate_source(session)
    if name == "gyroscope":
        t, body = session.gyr.t, session.gyr.values
    else:
        if name is None:
            raise GeofuseError(
                f"{session.path}: no gyroscope and no recorded attitude: the offset cannot be found from rotation "
                "(a GNSS course is too slow to time a video by; set video.time_offset_s by hand)"
            )
        stream = session.recorded[name]
        curve = attitude_rates(stream.t, stream.q)
        t, body = curve.t, curve.omega
    return RateCurve(t, rotations.rotate(np.tile(mount, (len(t), 1)), body))


def bearings_of(session) -> Callable[[np.ndarray], np.ndarray]:
    """Display pixels -> unit bearings (OpenCV camera frame) through the session's lens or pinhole."""
    lens, intr = session.lens, session.intrinsics

    def bearings(uv: np.ndarray) -> np.ndarray:
        if lens is not None:
            ab = lens.undistort(uv)
        else:
            ab = np.column_stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy])
        b = np.column_stack([ab, np.ones(len(ab))])
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    return bearings


def settings_path(source: Path) -> Path:
    """The session's own file of settings beside its manifest or clip (never an input):
    `NAME.geofuse.toml`, holding what `geofuse sync --write` found."""
    return source.with_name(source.stem + ".geofuse.toml")


def read_settings(source: Path) -> dict:
    """The settings file's tables ({} when there is none); a broken one is an error naming it."""
    import tomllib

    path = settings_path(source)
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GeofuseError(f"{path}: not valid TOML ({exc}); delete it or run geofuse sync --write again") from exc


def synced_offset(source: Path) -> float | None:
    """The offset stored by `geofuse sync --write` for this manifest or clip, or None."""
    value = read_settings(source).get("sync", {}).get("time_offset_s")
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None


def synced_drift(source: Path) -> tuple[float, float]:
    """(drift ppm, pivot session time) stored beside the offset, or (0, 0)."""
    sync = read_settings(source).get("sync", {})
    drift, pivot = sync.get("drift_ppm", 0.0), sync.get("drift_pivot_s", 0.0)
    ok = all(isinstance(x, (int, float)) and np.isfinite(x) for x in (drift, pivot))
    return (float(drift), float(pivot)) if ok else (0.0, 0.0)


def corrected_times(frame_times: np.ndarray, offset_s: float, drift_ppm: float, pivot_s: float) -> np.ndarray:
    """Frame times (session s) with an offset, and a drift about a pivot time, applied."""
    return frame_times + offset_s + drift_ppm * 1e-6 * (frame_times - pivot_s)


def settings_text(result: SyncResult, total_offset_s: float) -> str:
    return (
        "# written by `geofuse sync --write`: the session's own settings (its inputs are never written)\n"
        f"[sync]\ntime_offset_s = {total_offset_s:.6f}   # seconds added to the video's times\n"
        f"drift_ppm = {result.drift_ppm:.2f}   # the video clock's rate error (fitted on long clips; 0 otherwise)\n"
        f"drift_pivot_s = {result.reference_s:.6f}   # session time at which the offset holds exactly\n"
        f"confidence = {result.confidence:.4f}\nwindows = {len(result.windows)}\n"
    )


def sync_session(session, progress: Callable[[float], None] | None = None) -> SyncResult:
    """The offset to add to the session's video times so that they agree with its gyroscope (or,
    without one, with a recorded attitude's rates)."""
    gyro = gyro_rates(session)
    rates = video_rates(session.video, bearings_of(session), session.rotation_cw, progress)
    clip_start = float(session.frame_times[0] - session.video.pts_s[0])
    return estimate_offset(rates, gyro, clip_start)
