"""Painting clips' frames into a surface memory (app.export.memory): which frames, in what
order, and each frame's distance map for the occlusion test and its agreement with the model
(the quality). Shared by the orthophoto, the painted model and the viewer's memory.

Several clips paint one memory on one timeline (app.session.timeline), their frames taken in
time order, the further clips' cameras moved onto the first one's scene. Frames are taken every
`every_s` seconds of each clip's video; each is decoded at most DECODE_LONG_SIDE pixels on its
long side and its camera's distances are rendered off-screen (app.render.views) at most
DISTANCE_LONG_SIDE. Exports give each frame its UTC time where the clips have a clock, else
seconds on the timeline (from the first frame); the viewer, timeline seconds.
"""

from __future__ import annotations

import heapq
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from app.camera.pinhole import Camera
from app.export.memory import SurfaceMemory, agreement
from app.footage.clips import onto
from app.io.video import frames_at
from app.render.views import ModelViews
from app.scene.mesh import MeshData
from app.scene.tiles.freeze import frozen_tiles
from app.session.camera_track import CameraTrack
from app.session.model import Session
from app.session.timeline import Timeline
from app.solve.uncertainty import frame_sigmas

log = logging.getLogger("geofuse.export")
DECODE_LONG_SIDE = 960
DISTANCE_LONG_SIDE = 480
DEFAULT_EVERY_S = 0.2


@dataclass(frozen=True)
class ClipToPaint:
    """One clip's frames for a memory: its session, its camera track, its frames' times on the
    timeline (s, one per video frame) and what takes its cameras onto the scene painted (None:
    they are on it)."""

    session: Session
    track: CameraTrack
    times: np.ndarray
    move: Callable[[Camera], Camera] | None = None

    def camera(self, k: int) -> Camera:
        cam = self.track.frame_camera(int(k))
        return cam if self.move is None else self.move(cam)


def clips_on_a_timeline(
    solved: list[tuple[Session, CameraTrack]],
) -> tuple[list[ClipToPaint], float | None]:
    """The clips (session, solved track; the first's scene is painted) on one timeline, and its
    UTC (Unix s) at time 0, None where no clip has a clock."""
    timeline = Timeline.of([s for s, _ in solved])
    first = solved[0][0]
    clips = [
        ClipToPaint(s, t, span.times, None if k == 0 else onto(s, first))
        for k, ((s, t), span) in enumerate(zip(solved, timeline.clips, strict=True))
    ]
    return clips, timeline.utc0


def planned_cameras(clips: list[ClipToPaint], plans: list[np.ndarray]) -> list[Camera]:
    """The cameras of every clip's planned frames (paint_frame_indices), clip by clip."""
    return [c.camera(int(k)) for c, frames in zip(clips, plans, strict=True) for k in frames]


def scene_to_paint(mesh: MeshData, cameras: list[Camera]) -> MeshData:
    """The scene a memory paints: `mesh`, its 3D Tiles layers frozen to the tiles the painted
    frames' cameras (planned_cameras) need (app.scene.tiles.freeze; the count and bytes logged).
    A tileset none of whose tiles loads raises FreezeError."""
    if not mesh.tilesets:
        return mesh
    frozen, tiles, nbytes = frozen_tiles(mesh, cameras)
    log.info("3D Tiles painted: %d tiles the frames need, %.0f MB", tiles, nbytes / 1e6)
    return frozen


def frames_in_time_order(
    clips: list[ClipToPaint], plans: list[np.ndarray]
) -> Iterator[tuple[float, int, int, np.ndarray]]:
    """(timeline s, clip index, frame, RGB) of every clip's planned frames, in time order."""

    def one(index: int) -> Iterator[tuple[float, int, int, np.ndarray]]:
        clip = clips[index]
        for k, rgb in frames_at(clip.session.video, plans[index], DECODE_LONG_SIDE):
            yield float(clip.times[k]), index, int(k), rgb

    return heapq.merge(*(one(i) for i in range(len(clips))), key=lambda item: item[:3])


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
    memory: SurfaceMemory,
    views: ModelViews,
    rgb: np.ndarray,
    camera: Camera,
    time_s: float,
    sigmas: tuple[float, float] = (0.0, 0.0),
) -> int:
    """One frame painted with its occlusion test, its pose's uncertainty (position m, attitude
    deg) and, for a camera without a lens (whose image is its pinhole's), its agreement with
    the model (app.export.memory.agreement)."""
    d, model = model_view(views, camera)
    agree = agreement(rgb, model) if camera.lens is None else None
    return memory.paint(rgb, camera, d, time_s, agree, sigmas)


def paint_frames(
    memory: SurfaceMemory,
    views: ModelViews,
    clips: list[ClipToPaint],
    plans: list[np.ndarray],
    utc0: float | None = None,
    progress: Callable[[float], None] | None = None,
) -> int:
    """Paint the clips' planned frames (paint_frame_indices) into a memory in time order, each
    with its camera's occlusion test, agreement and pose uncertainty (its source's:
    app.solve.uncertainty.frame_sigmas), its time utc0 + its timeline time (utc0 None:
    timeline s). Returns the frames painted."""
    total = sum(len(p) for p in plans)
    sigmas = []
    for clip, plan in zip(clips, plans, strict=True):
        pos, att = frame_sigmas(clip.session, clip.track, plan)
        sigmas.append(
            dict(zip(plan.tolist(), zip(pos.tolist(), att.tolist(), strict=True), strict=True))
        )
    n = 0
    for t, ci, k, rgb in frames_in_time_order(clips, plans):
        time_s = t if utc0 is None else utc0 + t
        paint_one(memory, views, rgb, clips[ci].camera(k), time_s, sigmas[ci][k])
        n += 1
        if progress is not None:
            progress(n / total)
    return n
