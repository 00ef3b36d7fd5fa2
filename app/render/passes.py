"""The two passes of the method: the depth map from the video's camera (paper 2.2.1, shadow
mapping), then the scene seen from the window camera with the video projected (paper 2.2.2)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import moderngl
import numpy as np

from app.camera import Camera
from app.config import ProjectionSettings
from app.render.gpu_scene import GpuScene
from app.render.programs import load_program
from app.render.video_texture import VideoTexture

LIGHT_DIR = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


def _mat(m: np.ndarray) -> bytes:
    """A 4x4 row-major numpy matrix as the column-major float32 bytes GLSL expects."""
    return np.asarray(m, np.float32).T.tobytes()


class DepthPass:
    """Renders the scene's depth from the projector into a depth texture of a given size."""

    def __init__(self, ctx: moderngl.Context, scene: GpuScene, key: str = "projector") -> None:
        self.ctx = ctx
        self.scene = scene
        self.key = key  # its tile selection's name (one per projector)
        self.program = load_program(ctx, "depth.vert", "depth.frag")
        self.texture: moderngl.Texture | None = None
        self.fbo: moderngl.Framebuffer | None = None
        self.camera: Camera | None = None
        self._drawn: tuple[int, ...] = ()  # the primitives the map was drawn with
        self.renders = 0  # how many times the depth map was actually redrawn
        self.triangles = 0  # in the last redraw

    @property
    def size(self) -> tuple[int, int]:
        return (0, 0) if self.texture is None else self.texture.size

    def _ensure_size(self, size: tuple[int, int]) -> None:
        if self.texture is not None and self.texture.size == size:
            return
        if self.fbo is not None:
            self.fbo.release()
            self.texture.release()
        self.texture = self.ctx.depth_texture(size)
        self.texture.compare_func = ""  # sample raw depth values, not a comparison
        # clamp-to-edge: the nine-case gathers rely on it at the image border (projective.glsl)
        self.texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.texture.repeat_x = self.texture.repeat_y = False
        self.fbo = self.ctx.framebuffer(depth_attachment=self.texture)
        self.camera = None

    def update(self, camera: Camera, size: tuple[int, int], force: bool = False) -> bool:
        """Redraw the depth map for `camera` at `size` (w, h) texels, only if either changed or
        the geometry it sees did (streamed tiles chosen for the projector at the depth map's
        resolution), or when forced (a redraw every frame, for benchmarks).

        Returns True when it redrew. Leaves the depth framebuffer bound: callers bind theirs.
        """
        self._ensure_size(size)
        focal = max(camera.intrinsics.fx, camera.intrinsics.fy) * size[1] / camera.intrinsics.height
        prims = self.scene.drawables(camera, focal, self.key)
        drawn = tuple(id(p) for p in prims)
        if camera == self.camera and drawn == self._drawn and not force:
            return False
        self.fbo.use()
        self.fbo.clear(depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        self.program["u_view_proj"].write(_mat(camera.view_projection))
        for prim in prims:
            prim.vao(self.ctx, self.program, ("in_position",)).render(moderngl.TRIANGLES)
        self.camera, self._drawn = camera, drawn
        self.triangles = sum(p.count for p in prims) // 3
        self.renders += 1
        return True

    def read(self) -> np.ndarray:
        """The depth map as (h, w) float32 window depth in [0, 1], row 0 at the image bottom."""
        w, h = self.size
        return np.frombuffer(self.texture.read(), np.float32).reshape(h, w)

    def release(self) -> None:
        self.scene.forget(self.program)
        if self.fbo is not None:
            self.fbo.release()
            self.texture.release()
        self.program.release()


class ScenePass:
    """Draws the scene from the window camera, projecting the video where the depth test allows."""

    def __init__(self, ctx: moderngl.Context, scene: GpuScene) -> None:
        self.ctx = ctx
        self.scene = scene
        self.program = load_program(ctx, "scene.vert", "scene.frag")
        self.triangles = 0  # drawn in the last frame
        self.count_samples = False  # count the scene's fragments that pass (an occlusion query)
        self.samples: int | None = None  # of the last frame, when counted
        self.program["u_base_texture"].value = 0
        self.program["u_depth_map"].value = 1
        self.program["u_video"].value = 2
        self.program["u_video_u"].value = 3
        self.program["u_video_v"].value = 4
        self.program["u_truth_positions"].value = 5
        self.set_light(LIGHT_DIR)
        # A 1x1 stand-in so that unused samplers are always complete.
        self._blank = ctx.texture((1, 1), 4, bytes([255, 255, 255, 255]))

    def set_light(self, direction_enu: np.ndarray) -> None:
        """The direction toward the light (ENU, normalised here) for the model's shading; a
        simulated world may light the scene otherwise than the model's renderings."""
        d = np.asarray(direction_enu, np.float64)
        self.program["u_light_dir"].value = tuple(float(v) for v in d / np.linalg.norm(d))

    def render(
        self,
        view: Camera,
        settings: ProjectionSettings,
        projector: Camera | None,
        depth: DepthPass | None,
        video: VideoTexture | None,
        truth_positions: moderngl.Texture | None = None,
        error_scale_m: float = 4.0,
        extras: tuple[ExtraProjector, ...] = (),
        priority: float = 0.0,
    ) -> None:
        """Draw into the bound framebuffer. Projection needs projector, depth and video; the error
        overlay a position map from the true camera; extras: further projectors (other clips),
        at most MAX_EXTRA; priority: the first projector's (see ExtraProjector)."""
        p = self.program
        p["u_view_proj"].write(_mat(view.view_projection))
        p["u_eye"].value = view.position
        on = (
            settings.enabled
            and projector is not None
            and depth is not None
            and video is not None
            and video.ready
        )
        p["u_projection_on"].value = on
        if on:
            size = depth.size
            p["u_proj_view_proj"].write(_mat(projector.view_projection))
            p["u_proj_position"].value = projector.position
            p["u_proj_near"].value = projector.near
            p["u_proj_far"].value = projector.far
            scale = size[0] / projector.intrinsics.width
            p["u_proj_focal_texels"].value = (
                max(projector.intrinsics.fx, projector.intrinsics.fy) * scale
            )
            p["u_alpha"].value = settings.alpha
            p["u_bias_constant"].value = settings.bias_constant_m
            p["u_bias_slope"].value = settings.bias_slope
            p["u_neighbourhood"].value = settings.neighbourhood
            _set_lens(p, projector)
            depth.texture.use(1)
            video.bind(p)
        else:
            for unit in (1, 2, 3, 4):
                self._blank.use(unit)
        p["u_proj_priority"].value = float(priority)
        p["u_seam"].value = SEAM
        _set_extras(p, extras if settings.enabled else ())
        p["u_error_overlay"].value = on and truth_positions is not None
        p["u_error_scale_m"].value = error_scale_m
        (truth_positions or self._blank).use(5)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        prims = self.scene.drawables(view, None, "view")
        query = self.ctx.query(samples=True) if self.count_samples else None
        with query or contextlib.nullcontext():
            for prim in prims:
                p["u_has_texture"].value = prim.texture is not None
                (prim.texture or self._blank).use(0)
                prim.vao(self.ctx, p, ("in_position", "in_uv", "in_color")).render(
                    moderngl.TRIANGLES
                )
        self.triangles = sum(q.count for q in prims) // 3
        self.samples = query.samples if query is not None else None

    def release(self) -> None:
        self.scene.forget(self.program)
        self._blank.release()
        self.program.release()


MAX_EXTRA = 7  # further projectors beside the first (shaders/scene.frag)
SEAM = 0.02  # score difference over which two views blend (shaders/scene.frag, view_score)
EXTRA_DEPTH_UNIT, EXTRA_VIDEO_UNIT = 6, 6 + MAX_EXTRA  # texture units of their maps and videos


@dataclass(frozen=True)
class ExtraProjector:
    """A further projector for one draw: its camera, depth pass (drawn), RGB video texture
    (display-oriented) and priority (higher wins where several see a surface)."""

    camera: Camera
    depth: DepthPass
    video: moderngl.Texture
    priority: float = 0.0
    alpha: float = 1.0  # its opacity over the model (the first projector's: the settings' alpha)


def _set_extras(p: moderngl.Program, extras: tuple[ExtraProjector, ...]) -> None:
    """The further projectors' uniforms and texture units."""
    if len(extras) > MAX_EXTRA:
        raise ValueError(f"at most {MAX_EXTRA + 1} projectors at once, got {len(extras) + 1}")
    p["u_extra_count"].value = len(extras)
    if not extras:
        return
    n = MAX_EXTRA

    def arr(values: list, fill) -> list:
        return list(values) + [fill] * (n - len(values))

    cams = [e.camera for e in extras]
    eye = np.eye(4, dtype=np.float32)
    p["u_extra_view_proj"].write(
        np.stack(arr([np.asarray(c.view_projection, np.float32).T for c in cams], eye)).tobytes()
    )
    p["u_extra_view"].write(
        np.stack(arr([np.asarray(c.view, np.float32).T for c in cams], eye)).tobytes()
    )
    p["u_extra_position"].value = arr([tuple(c.position) for c in cams], (0.0, 0.0, 0.0))
    p["u_extra_near"].value = arr([c.near for c in cams], 0.1)
    p["u_extra_far"].value = arr([c.far for c in cams], 1.0)
    p["u_extra_focal_texels"].value = arr(
        [
            max(c.intrinsics.fx, c.intrinsics.fy) * e.depth.size[0] / c.intrinsics.width
            for c, e in zip(cams, extras)
        ],
        1.0,
    )
    p["u_extra_priority"].value = arr([float(e.priority) for e in extras], 0.0)
    p["u_extra_alpha"].value = arr([float(e.alpha) for e in extras], 1.0)
    lenses = [c.lens for c in cams]
    p["u_extra_lens_kind"].value = arr(
        [LENS_KIND[None if L is None else L.kind] for L in lenses], 0
    )
    coeffs = [
        (0.0,) * 5 if L is None else tuple(L.coeffs) + (0.0,) * (5 - len(L.coeffs)) for L in lenses
    ]
    fisheye = [L is not None and L.kind == "fisheye" for L in lenses]
    p["u_extra_lens_k"].value = arr(
        [tuple(k[:4]) if f else (k[0], k[1], 0.0, 0.0) for k, f in zip(coeffs, fisheye)],
        (0.0, 0.0, 0.0, 0.0),
    )
    p["u_extra_lens_p"].value = arr(
        [(0.0, 0.0) if f else (k[2], k[3]) for k, f in zip(coeffs, fisheye)], (0.0, 0.0)
    )
    p["u_extra_lens_k3"].value = arr([0.0 if f else k[4] for k, f in zip(coeffs, fisheye)], 0.0)
    p["u_extra_lens_f"].value = arr(
        [(1.0, 1.0) if L is None else (L.fx, L.fy) for L in lenses], (1.0, 1.0)
    )
    p["u_extra_lens_c"].value = arr(
        [(0.0, 0.0) if L is None else (L.cx, L.cy) for L in lenses], (0.0, 0.0)
    )
    p["u_extra_lens_size"].value = arr(
        [(1.0, 1.0) if L is None else (float(L.width), float(L.height)) for L in lenses],
        (1.0, 1.0),
    )
    p["u_extra_lens_stretch"].value = arr([1.0 if L is None else L.stretch for L in lenses], 1.0)
    units_depth = [EXTRA_DEPTH_UNIT + i for i in range(n)]
    units_video = [EXTRA_VIDEO_UNIT + i for i in range(n)]
    p["u_extra_depth"].value = units_depth
    p["u_extra_video"].value = units_video
    for i, e in enumerate(extras):
        e.depth.texture.use(units_depth[i])
        e.video.use(units_video[i])


LENS_KIND = {None: 0, "fisheye": 1, "brown": 2}  # shaders/include/lens.glsl's constants


def _set_lens(p: moderngl.Program, projector: Camera) -> None:
    """The projector's lens and rolling-shutter uniforms: the exact path when it has either,
    else the pinhole's texture coordinates from its projection matrix."""
    lens = projector.lens
    exact = lens is not None or projector.rs_turn is not None
    p["u_exact_video"].value = exact
    if not exact:
        return
    p["u_proj_view"].write(_mat(projector.view))
    p["u_rs_turn"].value = projector.rs_turn or (0.0, 0.0, 0.0)
    p["u_rs_axis"].value = projector.rs_axis
    p["u_lens_kind"].value = LENS_KIND[None if lens is None else lens.kind]
    if lens is None:
        i = projector.intrinsics
        p["u_lens_f"].value, p["u_lens_c"].value = (i.fx, i.fy), (i.cx, i.cy)
        p["u_lens_size"].value, p["u_lens_stretch"].value = (float(i.width), float(i.height)), 1.0
        return
    k = lens.coeffs
    p["u_lens_k"].value = tuple(k) if lens.kind == "fisheye" else (k[0], k[1], 0.0, 0.0)
    p["u_lens_p"].value = (0.0, 0.0) if lens.kind == "fisheye" else (k[2], k[3])
    p["u_lens_k3"].value = 0.0 if lens.kind == "fisheye" else k[4]
    p["u_lens_f"].value = (lens.fx, lens.fy)
    p["u_lens_c"].value = (lens.cx, lens.cy)
    p["u_lens_size"].value = (float(lens.width), float(lens.height))
    p["u_lens_stretch"].value = lens.stretch
