"""FusionRenderer: the scene, a video frame and a projector (the video's camera), drawn into any framebuffer.

The same object draws into the viewer's window, an EGL off-screen framebuffer in tests, and the
CLI's still export. All GL calls happen on the thread that owns the context.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext

import moderngl
import numpy as np
import numpy.typing as npt

from app.camera.pinhole import Camera, depth_map_size
from app.core.settings import OverlaySettings, ProjectionSettings
from app.render.coverage import coverage, depth_long_side
from app.render.decals import Decal, DeferredProjectors, deferred_available
from app.render.gpu_scene import GpuScene
from app.render.overlays import (
    FIX_REJECTED_COLOR,
    FIX_USED_COLOR,
    FRUSTUM_COLOR,
    OUTLINE_COLOR,
    REFERENCE_COLOR,
    TRAJECTORY_COLOR,
    LineOverlay,
    frustum_segments,
)
from app.render.pass_timer import PassTimer
from app.render.passes import MAX_EXTRA, DepthPass, ExtraProjector, ScenePass
from app.render.positions import PositionPass
from app.render.video_texture import ExtraVideo, VideoTexture, YuvPlanes
from app.scene.mesh import MeshData

BACKGROUND = (0.62, 0.74, 0.86)
PICK_DOWNSCALE = 4  # picking renders positions at a quarter of the view's resolution


def nearest_in_time(
    ages_s: Sequence[float], priorities: Sequence[float], limit: int = MAX_EXTRA
) -> list[int]:
    """Indices (in the order given) of the further projectors drawn where more than `limit` are
    offered: those whose frames were taken nearest in time to the moment drawn (the smallest
    |age|, s), the higher priority first where they tie, then the one offered first."""
    nearest = sorted(range(len(ages_s)), key=lambda k: (abs(ages_s[k]), -priorities[k], k))
    return sorted(nearest[:limit])


def left_out_message(count: int) -> str:
    """What drawing at most MAX_EXTRA further projectors leaves out, in a sentence: `count`
    further clips not drawn at a moment."""
    return (
        f"{count} further clip(s) left out: at most {MAX_EXTRA + 1} projectors are drawn at once,"
        f" the first clip's and the {MAX_EXTRA} further ones nearest in time to the moment drawn"
    )


def beyond_message(count: int) -> str:
    """left_out_message of `count` further clips beyond MAX_EXTRA played over a span of frames:
    left out only at the moments where more than MAX_EXTRA have a frame."""
    return f"{left_out_message(count)} (where more than {MAX_EXTRA} further clips have a frame)"


class FusionRenderer:
    """Owns every GL object of one scene; call from the GL thread only."""

    def __init__(self, ctx: moderngl.Context, mesh: MeshData, deferred: bool | None = None) -> None:
        """deferred: draw the projectors as deferred decals (app.render.decals), each over what
        it covers; False: the forward scene pass, every projector in every fragment (the
        full-cost path, kept as the reference and where no blit is found); None: deferred
        where the context can. Measured on an H100 (docs/PERFORMANCE.md, "GPU"), forward draws
        the sample in about half the decals' time, but its full-size depth maps ask a streamed
        city for every tile the projector sees at full detail (52 s to the first full-detail
        frame against 0.6 s): deferred stays the default on GPUs too."""
        self.ctx = ctx
        self.scene = GpuScene(ctx, mesh)
        self.depth = DepthPass(ctx, self.scene)
        self.scene_pass = ScenePass(ctx, self.scene)
        self.lines = LineOverlay(ctx)
        self.video = VideoTexture(ctx)
        self.projector: Camera | None = None
        self.projector_priority = 0.0
        self.projector_age = 0.0
        self.reference: Camera | None = None
        self.truth: Camera | None = None
        self._positions = None  # PositionPass, made on first use of the error overlay
        self._truth_map = None
        self._truth_map_camera: Camera | None = None
        self.trajectory: np.ndarray | None = None
        self.fixes: tuple[np.ndarray, np.ndarray] | None = None  # GNSS segments: used, rejected
        self.outlines: np.ndarray | None = None
        self.extras: list[_Extra] = []  # further projectors (other clips), drawn with the first
        self.extras_offered = 0  # how many the last set_extra_projectors was given
        self.extras_kept: list[int] = []  # which of those are drawn (nearest_in_time)
        self.deferred_pass = DeferredProjectors(ctx) if deferred_available(ctx) else None
        self.timer: PassTimer | None = None  # set: each pass's CPU and GPU time (benchmarks)
        # Switchable between frames (benchmarks compare both in one run); never on without a pass.
        self.deferred = self.deferred_pass is not None and deferred is not False

    def set_video_frame(self, rgb: npt.NDArray[np.uint8]) -> None:
        """Upload one display-oriented video frame (H, W, 3) uint8 RGB, row 0 = the top row."""
        self.video.set_rgb(rgb)

    def set_video_yuv(
        self,
        y: np.ndarray,
        u: np.ndarray,
        v: np.ndarray,
        rotation_cw: int,
        bt709: bool,
        full_range: bool = False,
    ) -> None:
        """Upload one stored playback frame's planes; the shader turns it by rotation_cw."""
        self.video.set_yuv(y, u, v, rotation_cw, bt709, full_range)

    def set_projector(
        self, camera: Camera | None, priority: float = 0.0, age_s: float = 0.0
    ) -> None:
        """The projector (the video's camera) for the next draws; priority: where further
        projectors see the same surface, the higher priority wins (set_extra_projectors); age_s:
        how long before the drawn moment its frame was taken (where views tie, the younger
        wins)."""
        self.projector = camera
        self.projector_priority = float(priority)
        self.projector_age = float(age_s)

    def set_extra_projectors(
        self,
        views: list[tuple[Camera, np.ndarray | YuvPlanes, float]],
        alphas: list[float] | None = None,
        colours: list[tuple[float, float, float, float]] | None = None,
        ages_s: list[float] | None = None,
    ) -> None:
        """Further projectors drawn with the first (several clips at once): each (camera, frame,
        priority), the frame a display-oriented RGB image (H, W, 3) uint8 or a playback frame's
        stored planes (turned and converted to RGB in the shader), with its opacity (default the
        settings' alpha), frustum colour and frame age (s before the drawn moment; default 0).
        One depth map each, redrawn only when its own pose changes. Beyond MAX_EXTRA, those
        nearest in time are drawn (nearest_in_time; extras_left_out says how many are not)."""
        ages = [0.0] * len(views) if ages_s is None else [float(a) for a in ages_s]
        self.extras_offered = len(views)
        self.extras_kept = nearest_in_time(ages, [priority for _, _, priority in views])
        kept = self.extras_kept
        views = [views[k] for k in kept]
        ages = [ages[k] for k in kept]
        alphas = None if alphas is None else [alphas[k] for k in kept]
        colours = None if colours is None else [colours[k] for k in kept]
        while len(self.extras) > len(views):
            self.extras.pop().release()
        while len(self.extras) < len(views):
            key = f"projector{len(self.extras)}"
            depth = DepthPass(self.ctx, self.scene, key)
            self.extras.append(_Extra(depth, ExtraVideo(self.ctx)))
        for k, (extra, (camera, frame, priority)) in enumerate(
            zip(self.extras, views, strict=True)
        ):
            extra.set(camera, frame, priority)
            extra.alpha = None if alphas is None else float(alphas[k])
            extra.age_s = ages[k]
            extra.colour = FRUSTUM_COLOR if colours is None else colours[k]

    def set_ages(self, first_s: float, extras_s: list[float]) -> None:
        """How long before the drawn moment each projector's frame was taken (s): the first's and
        each further one's (as set_extra_projectors ordered them). Where views tie, the younger
        wins; set every frame by a player, without uploading the frames again. extras_s may
        also give one age for each projector offered, of which those drawn are taken."""
        self.projector_age = float(first_s)
        if len(extras_s) == self.extras_offered != len(self.extras):
            extras_s = [extras_s[k] for k in self.extras_kept]
        for extra, age in zip(self.extras, extras_s, strict=True):
            extra.age_s = float(age)

    @property
    def extras_left_out(self) -> int:
        """How many further projectors the last set_extra_projectors left out (MAX_EXTRA)."""
        return self.extras_offered - len(self.extras_kept)

    @property
    def extras_left_out_message(self) -> str | None:
        """left_out_message of the last set_extra_projectors; None where it drew them all."""
        return left_out_message(self.extras_left_out) if self.extras_left_out else None

    def set_reference(self, camera: Camera | None) -> None:
        """A second camera drawn as a frustum beside the projector's (e.g. the true pose)."""
        self.reference = camera

    def set_truth(self, camera: Camera | None) -> None:
        """The video's true camera, for the projection-error overlay (simulated sessions)."""
        self.truth = camera

    def _truth_positions(self, overlays: OverlaySettings):
        if not overlays.error_map or self.truth is None:
            return None
        w, h = self.truth.intrinsics.width, self.truth.intrinsics.height
        s = overlays.error_map_texels / max(w, h)
        cam = Camera.create(
            self.truth.intrinsics.scaled(max(1, round(w * s)), max(1, round(h * s))),
            self.truth.position,
            self.truth.orientation,
            self.truth.near,
            self.truth.far,
        )
        if cam != self._truth_map_camera:  # redrawn only when the true pose changes
            self._truth_map = self._position_pass().render_texture(cam)
            self._truth_map_camera = cam
        return self._truth_map

    def _position_pass(self):

        if self._positions is None:
            self._positions = PositionPass(self.ctx, self.scene)
        return self._positions

    def pick(
        self, view: Camera, x: float, y: float, downscale: int = PICK_DOWNSCALE
    ) -> np.ndarray | None:
        """The model point (ENU m) seen at window position (x, y) in [0, 1] from the left/top,
        through the GPU position pass at 1/downscale of the view's resolution; None where the
        view sees no model."""
        w = max(1, view.intrinsics.width // downscale)
        h = max(1, view.intrinsics.height // downscale)
        small = Camera.create(
            view.intrinsics.scaled(w, h), view.position, view.orientation, view.near, view.far
        )
        col = int(np.clip(x * w, 0, w - 1))
        row = int(np.clip(y * h, 0, h - 1))
        p = self._position_pass().render(small)[row, col]
        return p.astype(np.float64) if np.all(np.isfinite(p)) else None

    def pick_map(self, camera: Camera) -> np.ndarray:
        """(H, W, 3) ENU metres of the surface at each pixel centre of `camera` (row 0 = top),
        NaN where it sees none: the position pass at the camera's full resolution."""
        return self._position_pass().render(camera)

    def set_outlines(self, segments_enu: npt.ArrayLike | None) -> None:
        """Line segments (2N, 3) ENU metres, drawn in pairs over the scene (e.g. footprints)."""
        self.outlines = None if segments_enu is None else np.asarray(segments_enu, np.float64)

    def set_trajectory(self, points_enu: npt.ArrayLike | None) -> None:
        """A polyline (N, 3) ENU metres drawn by the trajectory overlay."""
        self.trajectory = None if points_enu is None else np.asarray(points_enu, np.float64)

    def set_fixes(self, used_enu: npt.ArrayLike | None, rejected_enu: npt.ArrayLike = ()) -> None:
        """The GNSS fixes drawn with the trajectory overlay: segments (2N, 3) ENU metres in pairs,
        those the track stands on and those rejected as lies (None: none drawn)."""
        if used_enu is None:
            self.fixes = None
            return
        used = np.asarray(used_enu, np.float64).reshape(-1, 3)
        self.fixes = (used, np.asarray(rejected_enu, np.float64).reshape(-1, 3))

    def settle(
        self,
        view: Camera,
        settings: ProjectionSettings = ProjectionSettings(),
        timeout_s: float = 300.0,
    ) -> bool:
        """Load every streamed tile that `view` and the projector's depth map need at full
        detail (off-screen renders and exports; the viewer never calls this). True when done
        within timeout_s."""
        cameras = [(view, None, "view")]
        if settings.enabled and self.projector is not None:
            size = depth_map_size(
                self.projector.intrinsics.width,
                self.projector.intrinsics.height,
                settings.depth_long_side,
            )
            focal = (
                max(self.projector.intrinsics.fx, self.projector.intrinsics.fy)
                * size[1]
                / self.projector.intrinsics.height
            )
            cameras.append((self.projector, focal, "projector"))
        if settings.enabled:
            for k, e in enumerate(self.extras):
                i = e.camera.intrinsics
                size = depth_map_size(i.width, i.height, settings.depth_long_side)
                cameras.append((e.camera, max(i.fx, i.fy) * size[1] / i.height, f"projector{k}"))
        return self.scene.settle(cameras, timeout_s)

    def draw(
        self,
        view: Camera,
        fbo: moderngl.Framebuffer,
        settings: ProjectionSettings = ProjectionSettings(),
        overlays: OverlaySettings = OverlaySettings(frustum=False, trajectory=False),
    ) -> None:
        """Draw one frame from the window camera `view` into `fbo` (its viewport is used whole).
        Streamed tiles that finished loading are uploaded first, within a small time budget."""
        section = self._section
        with section("tiles"):
            self.scene.update()
        truth_map = self._truth_positions(overlays)
        decals = None
        if (
            self.deferred
            and self.deferred_pass is not None
            and truth_map is None
            and not self.scene_pass.count_samples
        ):
            with section("depth"):  # each projector's reach, then its depth map
                decals = self._decals(view, settings)
        if decals is not None:
            with section("scene"):
                self.deferred_pass.begin(fbo, BACKGROUND)
                self.scene_pass.render(view, settings, None, None, None, surface=True)
            with section("projectors"):
                self.deferred_pass.project(view, settings, decals)
            with section("overlays"):
                self.deferred_pass.overlays()
                self._draw_overlays(view, overlays)
                self.deferred_pass.finish(fbo)
            return
        with section("depth"):
            views = self._views(settings)
            for v in views:
                i = v.camera.intrinsics
                size = depth_map_size(i.width, i.height, settings.depth_long_side)
                v.depth.update(v.camera, size)
        extras = [v for v in views if v.depth is not self.depth]  # the first goes on its own
        with section("scene"):  # forward: the projectors are shaded in the scene pass
            fbo.use()
            fbo.clear(*BACKGROUND, 1.0, depth=1.0)
            self.scene_pass.render(
                view,
                settings,
                self.projector,
                self.depth,
                self.video,
                truth_map,
                overlays.error_scale_m,
                tuple(extras),
                self.projector_priority,
                self.projector_age,
            )
        with section("overlays"):
            self._draw_overlays(view, overlays)

    def _section(self, name: str) -> AbstractContextManager[None]:
        """The pass timer's section `name`, or nothing where no timer is set."""
        return nullcontext() if self.timer is None else self.timer.section(name)

    def _views(self, settings: ProjectionSettings) -> list[ExtraProjector]:
        """The projectors this frame draws, the first (the session's video, once it has a frame)
        first, then the further ones in order; none with projection off. Their depth maps are
        not brought up to date here (each path sizes them its way)."""
        if not settings.enabled:
            return []
        views = []
        if self.projector is not None and self.video.ready:
            views.append(
                ExtraProjector(
                    self.projector,
                    self.depth,
                    self.video,
                    self.projector_priority,
                    settings.alpha,
                    self.projector_age,
                )
            )
        for e in self.extras:
            alpha = settings.alpha if e.alpha is None else e.alpha
            views.append(ExtraProjector(e.camera, e.depth, e.video, e.priority, alpha, e.age_s))
        return views

    def _decals(self, view: Camera, settings: ProjectionSettings) -> list[Decal] | None:
        """The projectors drawn as deferred decals this frame, each with its depth map brought
        up to date at the size its reach on screen needs; None when none is on (the scene is
        then drawn alone, forward)."""
        views = self._views(settings)
        if not views:
            return None
        bounds = self.scene.bounds()
        decals = []
        for v in views:
            reach = coverage(v.camera, view, bounds)
            if reach is None:
                continue  # nothing of the scene it lights is on the screen
            i = v.camera.intrinsics
            long_side = depth_long_side(v.camera, view, reach.ratio, settings.depth_long_side)
            v.depth.update(v.camera, depth_map_size(i.width, i.height, long_side))
            decals.append(Decal(v, reach.polygon))
        return decals

    def _draw_overlays(self, view: Camera, overlays: OverlaySettings) -> None:
        """Frustums, the trajectory and outlines over the bound framebuffer, depth-tested."""
        vp = view.view_projection
        if overlays.frustum:
            frustums = [(self.projector, FRUSTUM_COLOR)]
            frustums += [(e.camera, e.colour) for e in self.extras]
            frustums.append((self.reference, REFERENCE_COLOR))
            for camera, colour in frustums:
                if camera is not None:
                    segments = frustum_segments(camera, overlays.frustum_length_m)
                    self.lines.draw(vp, segments, colour, moderngl.LINES)
        if overlays.trajectory and self.trajectory is not None:
            self.lines.draw(vp, self.trajectory, TRAJECTORY_COLOR, moderngl.LINE_STRIP)
        if overlays.trajectory and self.fixes is not None:
            for segments, colour in zip(
                self.fixes, (FIX_USED_COLOR, FIX_REJECTED_COLOR), strict=True
            ):
                if len(segments) >= 2:
                    self.lines.draw(vp, segments, colour, moderngl.LINES)
        if self.outlines is not None and len(self.outlines) >= 2:
            self.lines.draw(vp, self.outlines, OUTLINE_COLOR, moderngl.LINES)

    def release(self) -> None:
        if self._positions is not None:
            self._positions.release()
        self.lines.release()
        for e in self.extras:
            e.release()
        self.extras = []
        self.scene_pass.release()
        if self.deferred_pass is not None:
            self.deferred_pass.release()
        self.depth.release()
        self.scene.release()
        self.video.release()


class _Extra:
    """A further projector's GL objects: its depth pass and its video."""

    def __init__(self, depth: DepthPass, video: ExtraVideo) -> None:
        self.depth, self.video = depth, video
        self.camera: Camera | None = None
        self.priority = 0.0
        self.alpha: float | None = None  # None: the settings' alpha
        self.colour = FRUSTUM_COLOR
        self.age_s = 0.0

    def set(self, camera: Camera, frame: np.ndarray | YuvPlanes, priority: float) -> None:
        self.video.set(frame)
        self.camera, self.priority = camera, float(priority)

    def release(self) -> None:
        self.depth.release()
        self.video.release()
