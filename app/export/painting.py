"""Painting a clip's frames into a surface memory (app.export.memory): which frames, and each
frame's distance map for the occlusion test and its agreement with the model (the quality). Shared by the orthophoto and the painted model.

Frames are taken every `every_s` seconds of video; each is decoded at most DECODE_LONG_SIDE
pixels on its long side and its camera's distances are rendered off-screen (app.render.views)
at most DISTANCE_LONG_SIDE; its time is UTC s where the clip has a clock, else session s.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.camera.pinhole import Camera
from app.export.memory import SurfaceMemory, agreement
from app.export.ortho import OrthoMemory
from app.io.video import frames_at
from app.render.views import ModelViews
from app.session.camera_track import CameraTrack
from app.session.model import Session

DECODE_LONG_SIDE = 960
DISTANCE_LONG_SIDE = 480
DEFAULT_EVERY_S = 0.2


def paint_frame_indices(track: CameraTrack, every_s: float) -> np.ndarray:
    """The frames painted: one every `every_s` seconds of video (0: all)."""
    media = np.asarray(track.clock.media_s, np.float64)
    picked, last = [], -np.inf
    for k, t in enumerate(media):
        if t - last >= every_s - 1e-9:
            picked.append(k)
            last = t
    return np.asarray(picked, np.int64)


def model_view(views: ModelViews, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The model through the camera's pinhole, at most DISTANCE_LONG_SIDE px: (h, w) metres
    from the camera through each pixel (inf where the scene is not) and (h, w, 3) uint8 its
    colours (the model's own, no video)."""
    i = camera.intrinsics
    small = camera.pinhole(min(1.0, DISTANCE_LONG_SIDE / max(i.width, i.height)))
    rgb, positions = views.render(small)
    d = np.linalg.norm(positions - np.asarray(camera.position), axis=2)
    return np.where(np.isfinite(d), d, np.inf), rgb


def distances(views: ModelViews, camera: Camera) -> np.ndarray:
    """(h, w) metres from the camera through each pixel of its pinhole (model_view)."""
    return model_view(views, camera)[0]


def paint_one(
    memory: OrthoMemory | SurfaceMemory,
    views: ModelViews,
    rgb: np.ndarray,
    camera: Camera,
    time_s: float,
) -> int:
    """One frame painted with its occlusion test and, for a camera without a lens (whose
    image is its pinhole's), its agreement with the model (app.export.memory.agreement)."""
    d, model = model_view(views, camera)
    agree = agreement(rgb, model) if camera.lens is None else None
    return memory.paint(rgb, camera, d, time_s, agree)


def paint_frames(
    session: Session,
    track: CameraTrack,
    memory: OrthoMemory | SurfaceMemory,
    views: ModelViews,
    frames: np.ndarray,
    progress: Callable[[float], None] | None = None,
) -> None:
    """Paint the video's frames (indices) into a memory, each with its camera's distances
    (the occlusion test) and its time (UTC s where the clip has a clock, else session s)."""
    for n, (k, rgb) in enumerate(frames_at(session.video, frames, DECODE_LONG_SIDE)):
        cam = track.frame_camera(int(k))
        t = float(track.clock.session_time(float(track.clock.media_s[k])))
        utc = session.utc_of(t)
        paint_one(memory, views, rgb, cam, utc if utc is not None else t)
        if progress is not None:
            progress((n + 1) / len(frames))
