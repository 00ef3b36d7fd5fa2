"""The two passes of the method: the depth map from the video's camera (paper 2.2.1, shadow
mapping), then the scene seen from the window camera with the video projected (paper 2.2.2)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.core.settings import ProjectionSettings
from app.render.gpu_scene import GpuScene
from app.render.programs import Uniforms, load_program
from app.render.video_texture import ExtraVideo, VideoTexture, yuv_matrix

LIGHT_DIR = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])


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
        Uniforms(self.program).matrices("u_view_proj", [camera.view_projection])
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
    """Draws the scene from the window camera, projecting the video where the depth test allows.

    The scene shader is compiled in variants, one for each combination of what a frame draws
    (projection on, lens model, YUV planes, nine-case test, error overlay, the further
    projectors and which of them have lenses), each made when first needed and kept: a software
    rasteriser runs every branch a shader holds, so a switch left to a uniform costs as much
    switched off as on (docs/PERFORMANCE.md, "Shader variants")."""

    def __init__(self, ctx: moderngl.Context, scene: GpuScene) -> None:
        self.ctx = ctx
        self.scene = scene
        self.programs: dict[tuple[tuple[str, int], ...], moderngl.Program] = {}
        self.triangles = 0  # drawn in the last frame
        self.count_samples = False  # count the scene's fragments that pass (an occlusion query)
        self.samples: int | None = None  # of the last frame, when counted
        self.light = LIGHT_DIR
        # A 1x1 stand-in so that unused samplers are always complete.
        self._blank = ctx.texture((1, 1), 4, bytes([255, 255, 255, 255]))
        self.variant: dict[str, int] = {}  # the defines of the variant drawn last
        # How many textures the driver lets one fragment shader sample (32 on llvmpipe and
        # desktop GPUs; GL guarantees 16), and how many further projectors the last frame left
        # out for want of them.
        self.max_samplers = int(ctx.info["GL_MAX_TEXTURE_IMAGE_UNITS"])
        self.left_out = 0
        self.program = self._program({})  # the file's defaults, compiled now: errors show early

    @property
    def left_out_message(self) -> str | None:
        """What the last frame left out for want of texture units, in a sentence; None if
        nothing."""
        if not self.left_out:
            return None
        return (
            f"{self.left_out} further clip(s) not drawn: this OpenGL driver lets a shader sample"
            f" {self.max_samplers} textures at most"
        )

    def _program(self, defines: dict[str, int]) -> moderngl.Program:
        """The variant compiled with `defines` (made once)."""
        key = tuple(sorted(defines.items()))
        program = self.programs.get(key)
        if program is None:
            program = load_program(self.ctx, "scene.vert", "scene.frag", defines)
            u = Uniforms(program)
            for name, unit in SAMPLER_UNITS.items():
                u[name] = unit
            u["u_extra_depth"] = [EXTRA_DEPTH_UNIT + i for i in range(MAX_EXTRA)]
            u["u_extra_video"] = [EXTRA_VIDEO_UNIT + i for i in range(MAX_EXTRA)]
            u["u_extra_chroma"] = [EXTRA_CHROMA_UNIT + i for i in range(MAX_EXTRA)]
            self.programs[key] = program
        self.variant = dict(defines)
        return program

    def set_light(self, direction_enu: np.ndarray) -> None:
        """The direction toward the light (ENU, normalised here) for the model's shading; a
        simulated world may light the scene otherwise than the model's renderings."""
        d = np.asarray(direction_enu, np.float64)
        self.light = d / np.linalg.norm(d)

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
        age_s: float = 0.0,
        surface: bool = False,
    ) -> None:
        """Draw into the bound framebuffer. Projection needs projector, depth and video; the error
        overlay a position map from the true camera; extras: further projectors (other clips),
        at most MAX_EXTRA; priority and age_s: the first projector's (see ExtraProjector).
        surface: the model alone, with the surface each pixel sees written to a second colour
        attachment, for the deferred projectors (app.render.decals) to draw over."""
        if len(extras) > MAX_EXTRA:
            raise ValueError(f"at most {MAX_EXTRA + 1} projectors at once, got {len(extras) + 1}")
        on = (
            not surface
            and settings.enabled
            and projector is not None
            and depth is not None
            and video is not None
            and video.ready
        )
        extras = extras if settings.enabled and not surface else ()
        fitting = _fitting(extras, self.max_samplers)
        self.left_out = len(extras) - len(fitting)
        extras = fitting
        defines = {"PROJECTION": int(on), "EXTRA_COUNT": len(extras)}
        if surface:
            defines["GBUFFER"] = 1
        if on or extras:
            defines["NEIGHBOURHOOD"] = int(settings.neighbourhood)
        if on:
            defines["EXACT_VIDEO"] = int(
                projector.lens is not None or projector.rs_turn is not None
            )
            defines["VIDEO_YUV"] = int(video.yuv)
            defines["ERROR_OVERLAY"] = int(truth_positions is not None)
        if extras:
            defines["EXTRA_LENSES"] = sum(
                1 << i for i, e in enumerate(extras) if e.camera.lens is not None
            )
            defines["EXTRA_YUV"] = sum(
                1 << i for i, e in enumerate(extras) if e.video.chroma is not None
            )
        self.program = self._program(defines)
        p = Uniforms(self.program)
        p.matrices("u_view_proj", [view.view_projection])
        p["u_eye"] = tuple(view.position)
        p["u_light_dir"] = tuple(float(v) for v in self.light)
        if on:
            size = depth.size
            p.matrices("u_proj_view_proj", [projector.view_projection])
            p["u_proj_position"] = tuple(projector.position)
            p["u_proj_near"] = projector.near
            p["u_proj_far"] = projector.far
            scale = size[0] / projector.intrinsics.width
            p["u_proj_focal_texels"] = max(projector.intrinsics.fx, projector.intrinsics.fy) * scale
            p["u_alpha"] = settings.alpha
            set_lens(p, projector)
            depth.texture.use(1)
            video.bind(p)
        else:
            for unit in (1, 2, 3, 4):
                self._blank.use(unit)
        p["u_bias_constant"] = settings.bias_constant_m
        p["u_bias_slope"] = settings.bias_slope
        p["u_proj_priority"] = float(priority)
        p["u_proj_age"] = float(age_s)
        p["u_seam"] = SEAM
        _set_extras(p, extras)
        p["u_error_scale_m"] = error_scale_m
        (truth_positions or self._blank).use(5)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        prims = self.scene.drawables(view, None, "view")
        query = self.ctx.query(samples=True) if self.count_samples else None
        with query or contextlib.nullcontext():
            for prim in prims:
                p["u_has_texture"] = prim.texture is not None
                (prim.texture or self._blank).use(0)
                self.ctx.polygon_offset = OVERLAY_OFFSET if prim.overlay else (0.0, 0.0)
                prim.vao(self.ctx, self.program, ("in_position", "in_uv", "in_color")).render(
                    moderngl.TRIANGLES
                )
            self.ctx.polygon_offset = (0.0, 0.0)
        self.triangles = sum(q.count for q in prims) // 3
        self.samples = query.samples if query is not None else None

    def release(self) -> None:
        for program in self.programs.values():
            self.scene.forget(program)
            program.release()
        self.programs.clear()
        self._blank.release()


MAX_EXTRA = 7  # further projectors beside the first (shaders/scene.frag)
# glPolygonOffset (factor, units) of an overlay primitive in the view pass: pulled toward the
# camera, so that it wins the depth test over the surface it lies on
OVERLAY_OFFSET = (-1.0, -4.0)
SEAM = 0.02  # score difference over which two views blend (shaders/scene.frag, view_score)
AGE_SCORE_PER_S = 0.6  # score lost per second of a frame's age: ties go to the most recent frame
# Texture units of the further projectors' depth maps, videos (RGB or Y) and chroma (U, V)
EXTRA_DEPTH_UNIT, EXTRA_VIDEO_UNIT, EXTRA_CHROMA_UNIT = 6, 6 + MAX_EXTRA, 6 + 2 * MAX_EXTRA
SAMPLER_UNITS = {  # the scene shader's other samplers and their texture units
    "u_base_texture": 0,
    "u_depth_map": 1,
    "u_video": 2,
    "u_video_u": 3,
    "u_video_v": 4,
    "u_truth_positions": 5,
}


@dataclass(frozen=True)
class ExtraProjector:
    """A projector for one draw: its camera, depth pass (drawn), video (an RGB still or a
    playback frame's planes) and priority (higher wins where several see a surface). The scene
    pass takes the further ones (ExtraVideo); the deferred decals take the first too."""

    camera: Camera
    depth: DepthPass
    video: VideoTexture | ExtraVideo
    priority: float = 0.0
    alpha: float = 1.0  # its opacity over the model (the first projector's: the settings' alpha)
    age_s: float = 0.0  # how long before the drawn moment its frame was taken (ties: the younger)


def _fitting(extras: tuple[ExtraProjector, ...], max_samplers: int) -> tuple[ExtraProjector, ...]:
    """The further projectors, first ones first, whose textures fit beside the first projector's
    in a fragment shader that may sample `max_samplers` (the driver's limit): a depth map and an
    RGB still each, or a depth map and a playback frame's two planes."""
    used, out = len(SAMPLER_UNITS), []
    for e in extras:
        used += 3 if e.video.chroma is not None else 2
        if used > max_samplers:
            break
        out.append(e)
    return tuple(out)


def _set_extras(p: Uniforms, extras: tuple[ExtraProjector, ...]) -> None:
    """The further projectors' uniforms and texture units (the variant has EXTRA_COUNT of them;
    the lens uniforms only where EXTRA_LENSES says)."""
    if not extras:
        return
    cams = [e.camera for e in extras]
    p.matrices("u_extra_view_proj", [c.view_projection for c in cams])
    p.matrices("u_extra_view", [c.view for c in cams])
    p["u_extra_position"] = [tuple(c.position) for c in cams]
    p["u_extra_near"] = [c.near for c in cams]
    p["u_extra_far"] = [c.far for c in cams]
    p["u_extra_focal_texels"] = [
        max(c.intrinsics.fx, c.intrinsics.fy) * e.depth.size[0] / c.intrinsics.width
        for c, e in zip(cams, extras, strict=True)
    ]
    p["u_extra_priority"] = [float(e.priority) for e in extras]
    p["u_extra_age"] = [float(e.age_s) for e in extras]
    p["u_extra_alpha"] = [float(e.alpha) for e in extras]
    # Pinhole extras (no lens uniforms read) stand in with a pinhole's values.
    lenses = [_lens_uniforms(c) for c in cams]
    for name in ("kind", "k", "p", "k3", "f", "c", "size", "stretch"):
        p[f"u_extra_lens_{name}"] = [lens[name] for lens in lenses]
    # Playback frames (EXTRA_YUV): stored planes turned and converted as video.glsl does.
    p["u_extra_rotation"] = [e.video.rotation for e in extras]
    colour = [yuv_matrix(e.video.bt709, e.video.full_range) for e in extras]
    p.matrices("u_extra_yuv_matrix", [m for m, _ in colour])
    p["u_extra_yuv_offset"] = [tuple(offset) for _, offset in colour]
    for i, e in enumerate(extras):
        e.depth.texture.use(EXTRA_DEPTH_UNIT + i)
        e.video.texture.use(EXTRA_VIDEO_UNIT + i)
        (e.video.chroma or e.video.texture).use(EXTRA_CHROMA_UNIT + i)


LENS_KIND = {None: 0, "fisheye": 1, "brown": 2}  # shaders/include/lens.glsl's constants


def _lens_uniforms(camera: Camera) -> dict[str, object]:
    """The lens uniforms' values (lens.glsl's lens_distort arguments) of a camera; without a lens
    model, its pinhole intrinsics."""
    lens = camera.lens
    if lens is None:
        i = camera.intrinsics
        return {
            "kind": LENS_KIND[None],
            "k": (0.0, 0.0, 0.0, 0.0),
            "p": (0.0, 0.0),
            "k3": 0.0,
            "f": (i.fx, i.fy),
            "c": (i.cx, i.cy),
            "size": (float(i.width), float(i.height)),
            "stretch": 1.0,
        }
    k = tuple(lens.coeffs)
    fisheye = lens.kind == "fisheye"
    return {
        "kind": LENS_KIND[lens.kind],
        "k": k[:4] if fisheye else (k[0], k[1], 0.0, 0.0),
        "p": (0.0, 0.0) if fisheye else (k[2], k[3]),
        "k3": 0.0 if fisheye else k[4],
        "f": (lens.fx, lens.fy),
        "c": (lens.cx, lens.cy),
        "size": (float(lens.width), float(lens.height)),
        "stretch": lens.stretch,
    }


def set_lens(p: Uniforms, projector: Camera) -> None:
    """The projector's lens and rolling-shutter uniforms (read by the EXACT_VIDEO variant)."""
    p.matrices("u_proj_view", [projector.view])
    p["u_rs_turn"] = projector.rs_turn or (0.0, 0.0, 0.0)
    p["u_rs_axis"] = projector.rs_axis
    for name, value in _lens_uniforms(projector).items():
        p[f"u_lens_{name}"] = value
