"""The camera's rotation rate seen in the video (app.sync, step 1): sparse optical flow between
consecutive frames of a reduced grey copy, each pair's feature bearings fitted by a rotation
(Kabsch) with outlier rejection; rotation / time step = the rate at the pair's mid time.

OpenCV and PyAV are imported when the flow runs: opening a session needs neither.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from app.core.errors import GeofuseError
from app.geodesy import rotations
from app.io.video import decode, media_seconds, open_video
from app.sync.rates import RateCurve

FLOW_WIDTH_PX = 320  # the video is reduced to this width for the flow
MAX_FEATURES = 200
MIN_TRACKS = 12  # pairs with fewer tracked features give no rate


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


def tracked(
    prev: np.ndarray, grey: np.ndarray, scale: float, features: int = MAX_FEATURES
) -> tuple[np.ndarray, np.ndarray] | None:
    """(where (N, 2) display pixels, where in `grey` (N, 2)) of the corners of grey image `prev`
    tracked into `grey` by sparse optical flow (both reduced by `scale` from the display
    pixels); None when fewer than MIN_TRACKS are."""
    pts = cv2.goodFeaturesToTrack(prev, features, 0.01, 6)
    if pts is None or len(pts) < MIN_TRACKS:
        return None
    nxt, ok, _ = cv2.calcOpticalFlowPyrLK(prev, grey, pts, None, winSize=(15, 15), maxLevel=3)
    ok = ok.ravel() == 1
    if ok.sum() < MIN_TRACKS:
        return None
    return (pts[ok, 0, :] + 0.5) / scale, (nxt[ok, 0, :] + 0.5) / scale


def pair_rotation(
    prev: np.ndarray,
    grey: np.ndarray,
    scale: float,
    bearings: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray | None:
    """The camera's rotation (rotation vector, rad, camera frame in OpenGL axes) from grey image
    `prev` to `grey` (a copy reduced by `scale` from the display pixels `bearings` takes), by
    sparse optical flow; None when too few features are tracked. Divided by the frames' time
    step it is the rate at their mid time (video_rates, and the live feed's lag: app.live.lag)."""
    pairs = tracked(prev, grey, scale)
    if pairs is None:
        return None
    rot = frame_rotation(bearings(pairs[0]), bearings(pairs[1]))
    if rot is None:
        return None
    # b2 = D^T b1 for a body turn D: the camera's rotation is -rotvec(R).
    rv = -rotations.to_scipy(rotations.from_matrix(rot)).as_rotvec()
    return np.array([rv[0], -rv[1], -rv[2]])  # OpenCV camera axes -> OpenGL's


def video_rates(
    video,
    bearings: Callable[[np.ndarray], np.ndarray],
    rotation_cw: int,
    progress: Callable[[float], None] | None = None,
) -> RateCurve:
    """The camera's rotation rate between consecutive frames (see the module docstring).
    bearings: display pixels (N, 2) -> unit vectors (N, 3) in OpenCV's camera frame."""

    w, h = video.width, video.height
    scale = FLOW_WIDTH_PX / w
    size = (FLOW_WIDTH_PX, max(2, round(h * scale)))
    k = (rotation_cw // 90) % 4
    t_out, w_out = [], []
    prev = prev_t = None
    n = len(video.pts_s)
    with open_video(video.path) as c:
        stream = c.streams.video[0]
        stream.thread_type = "AUTO"
        for i, frame in enumerate(decode(c, stream)):
            if frame.pts is None:
                continue
            t = media_seconds(frame.pts, stream.time_base, video.origin_s)
            grey = np.ascontiguousarray(
                np.rot90(
                    frame.reformat(width=size[0], height=size[1], format="gray").to_ndarray(), k=-k
                )
            )
            if prev is not None and t > prev_t:
                rv = pair_rotation(prev, grey, scale, bearings)
                if rv is not None:
                    t_out.append((t + prev_t) / 2)
                    w_out.append(rv / (t - prev_t))
            prev, prev_t = grey, t
            if progress is not None and i % 50 == 0:
                progress(min(1.0, i / max(n, 1)))
    if progress is not None:
        progress(1.0)
    if len(t_out) < 10:
        raise GeofuseError(
            f"{video.path}: too few frames with trackable features to see the camera turn ({len(t_out)})"
        )
    return RateCurve(np.asarray(t_out), np.asarray(w_out))
