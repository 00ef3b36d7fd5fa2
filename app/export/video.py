"""The fused view as a video: every frame of the clip (no drops) draped on the scene and rendered
off-screen from a chosen view, encoded as H.264 with the clip's own presentation times (variable
frame rate kept).

Views (window cameras, ENU): `ride` through the video's own camera (its pose, a wider field of
view); `follow` behind and above it (app.render.still.ThirdPerson); `orbit` circling the scene
once over the export; `top` straight down over the camera.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from app.camera.frame_time import frame_of
from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.constants import VIEW_FAR_M, VIEW_NEAR_M
from app.core.errors import GeofuseError
from app.core.settings import OverlaySettings, ProjectionSettings
from app.io.video import VideoInfo, decode, media_seconds, open_video, rotate_for_display
from app.render.context import create_offscreen_context, keep_current
from app.render.offscreen import OffscreenTarget, render_to_array
from app.render.renderer import FusionRenderer
from app.render.still import ThirdPerson
from app.scene.mesh import MeshData
from app.session.camera_track import CameraTrack

VIEWS = ("ride", "follow", "orbit", "top")
RIDE_HFOV_DEG = 80.0  # the ride view sees a little around the video
VIEW_HFOV_DEG = 60.0
TOP_HEIGHT_M = 60.0  # the top view's height above the camera
EXPORT_ALPHA = 0.9


def view_camera(
    view: str, projector: Camera, size: tuple[int, int], scene_bounds: np.ndarray, phase: float
) -> Camera:
    """The window camera of one exported frame; phase in [0, 1) along the export (orbit)."""
    w, h = size
    if view == "ride":
        return Camera.create(
            Intrinsics.from_fov(w, h, RIDE_HFOV_DEG),
            projector.position,
            projector.orientation,
            VIEW_NEAR_M,
            VIEW_FAR_M,
        )
    intr = Intrinsics.from_fov(w, h, VIEW_HFOV_DEG)
    if view == "follow":
        eye, target = ThirdPerson().eye_and_target(projector)
    elif view == "top":
        target = np.asarray(projector.position)
        eye = target + [0.0, -0.01, TOP_HEIGHT_M]
    elif view == "orbit":
        lo, hi = scene_bounds
        target = (lo + hi) / 2
        radius = float(max(hi[:2] - lo[:2])) * 0.8 + 30.0
        a = 2 * np.pi * phase
        eye = target + [radius * np.sin(a), -radius * np.cos(a), 0.5 * radius]
    else:
        raise ValueError(f"view must be one of {VIEWS}, got {view!r}")
    return Camera.create(intr, eye, look_at_quat(eye, target), VIEW_NEAR_M, VIEW_FAR_M)


@dataclass
class FurtherClip:
    """A further clip drawn in an exported video: its video, display rotation, camera track
    (cameras already in its own frame), its frame at each of the first clip's frames (None:
    nothing then) and how long before that moment it was taken (s), and the move of its cameras
    into the first clip's frame."""

    video: VideoInfo
    rotation_cw: int
    track: CameraTrack
    frames: list[int | None]
    ages_s: list[float]
    move: Callable[[Camera], Camera]
    priority: float = 0.0


class _Frames:
    """A further clip's frames decoded forward, each once (restarting when asked for an earlier
    one): `get(k)` is frame k as display-oriented RGB."""

    def __init__(self, clip: FurtherClip) -> None:
        self.clip = clip
        self._open()

    def _open(self) -> None:
        self.container = open_video(self.clip.video.path)
        self.stream = self.container.streams.video[0]
        self.frames = decode(self.container, self.stream)
        self.k, self.rgb = -1, None

    def get(self, k: int) -> np.ndarray | None:
        if k < self.k:
            self.close()
            self._open()
        for frame in self.frames if self.k < k else ():
            if frame.pts is None:
                continue
            j = frame_of(
                self.clip.video.pts_s,
                media_seconds(frame.pts, self.stream.time_base, self.clip.video.origin_s),
            )
            if j is None:
                continue
            self.k = j
            if j >= k:
                self.rgb = rotate_for_display(
                    frame.to_ndarray(format="rgb24"), self.clip.rotation_cw
                )
                break
        return self.rgb if self.k == k else None

    def close(self) -> None:
        self.container.close()


@keep_current()  # its own context, made and released here: the caller's stays current
def export_video(
    video: VideoInfo,
    rotation_cw: int,
    track: CameraTrack,
    mesh: MeshData,
    out: Path,
    size: tuple[int, int],
    view: str = "follow",
    first: int = 0,
    last: int | None = None,
    progress: Callable[[float], None] | None = None,
    further: tuple[FurtherClip, ...] = (),
    credit: str = "",
) -> int:
    """Render frames first..last (inclusive) of `video` into `out` (H.264 MP4 at the clip's
    presentation times), with the further clips' frames of the same moments projected too;
    credit: what the scene's imagery must be credited with (app.scene.layers.scene_credit),
    in the file's copyright metadata ('' none). Returns the number of frames written."""

    last = len(video.pts_s) - 1 if last is None else last
    wanted = set(range(first, last + 1))
    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, mesh)
    target = OffscreenTarget(ctx, *size)
    settings = ProjectionSettings(alpha=EXPORT_ALPHA)
    bounds = mesh.bounds()
    written = 0
    fps = Fraction(video.nominal_fps or video.average_fps or 30).limit_denominator(1001)
    readers = [_Frames(c) for c in further]
    try:
        with open_video(video.path) as src, av.open(str(out), "w") as dst:
            vin = src.streams.video[0]
            vin.thread_type = "AUTO"
            if credit:
                dst.metadata["copyright"] = credit
            enc = dst.add_stream("libx264", rate=fps)
            enc.width, enc.height, enc.pix_fmt = size[0], size[1], "yuv420p"
            enc.time_base = Fraction(1, 90000)
            enc.codec_context.time_base = enc.time_base
            enc.codec_context.options = {"preset": "veryfast", "crf": "20", "bf": "0"}
            for frame in decode(src, vin):
                if frame.pts is None:
                    continue
                k = frame_of(video.pts_s, media_seconds(frame.pts, vin.time_base, video.origin_s))
                if k is None or k not in wanted:
                    if k is not None and k > last:
                        break
                    continue
                projector = track.frame_camera(k)
                renderer.set_video_frame(
                    rotate_for_display(frame.to_ndarray(format="rgb24"), rotation_cw)
                )
                renderer.set_projector(projector)
                views, ages = [], []
                for clip, reader in zip(further, readers, strict=True):
                    j = clip.frames[k]
                    rgb_j = None if j is None else reader.get(j)
                    if rgb_j is not None:
                        views.append((clip.move(clip.track.frame_camera(j)), rgb_j, clip.priority))
                        ages.append(clip.ages_s[k])
                renderer.set_extra_projectors(views, ages_s=ages)
                phase = (k - first) / max(1, last - first + 1)
                rgb = render_to_array(
                    renderer,
                    view_camera(view, projector, size, bounds, phase),
                    settings,
                    OverlaySettings(frustum=view != "ride", trajectory=False),
                    target,
                )
                if renderer.scene_pass.left_out_message:
                    raise GeofuseError(f"{out}: {renderer.scene_pass.left_out_message}")
                out_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
                out_frame.pts = int(round((video.pts_s[k] - video.pts_s[first]) * 90000))
                out_frame.time_base = enc.time_base
                for packet in enc.encode(out_frame):
                    dst.mux(packet)
                written += 1
                if progress is not None:
                    progress(written / len(wanted))
            for packet in enc.encode(None):
                dst.mux(packet)
    finally:
        for reader in readers:
            reader.close()
        target.release()
        renderer.release()
        ctx.release()
    return written
