"""Projectors as deferred decals: the scene is drawn once, then each projector shades only the
pixels its frustum can reach (issue 31).

The forward scene pass (passes.ScenePass with projectors) runs every projector's depth test and
video lookup in every fragment of the scene, overdrawn ones included; on a software rasteriser,
which runs both sides of every branch, a projector costs the whole screen whatever it covers. Here
the scene pass writes, beside its colour, the surface each window pixel sees (its distance from
the eye and its normal: shaders/include/surface.glsl); then each projector is drawn as the
polygon of its reach on the screen (app.render.coverage), and shaders/decal.frag reconstructs
the pixel's world point and applies the same depth test and video lookup as the forward pass.

Overlaps: projectors are drawn best first (higher priority, then the younger frame, then the
order given), and the first that sees a pixel claims it: its fragment writes a claim depth that
the later projectors' early depth test rejects before their shader runs, so a pixel seen by
several costs one projector's shading. Where the forward pass blends views of equal standing
by their incidence and range (a soft seam), the decals give the pixel to the first in order.
The frame is then copied into the caller's framebuffer (its viewport).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from app.camera.pinhole import Camera
from app.core.settings import ProjectionSettings
from app.render.context import GL_REQUIRE, blit_colour, can_blit
from app.render.coverage import polygon_pixels
from app.render.passes import ExtraProjector, set_lens
from app.render.programs import Uniforms, load_program

MAX_POLYGON = math.comb(13, 3)  # coverage()'s 13 planes, three at a time
DEPTH_UNIT, SURFACE_UNIT = 1, 5  # texture units; the video takes 2-4 (VideoTexture.bind)


@dataclass(frozen=True)
class Decal:
    """One projector for one frame (its depth map drawn) and the polygon of its reach on the
    screen (window NDC, (K, 2): app.render.coverage)."""

    view: ExtraProjector
    polygon: np.ndarray


def deferred_available(ctx: moderngl.Context) -> bool:
    """Whether this context can draw deferred projectors (the scene shader's OpenGL, and a blit
    to copy the frame into the caller's framebuffer)."""
    return ctx.version_code >= GL_REQUIRE and can_blit()


def drawing_order(decals: list[Decal]) -> list[Decal]:
    """Best first: higher priority, then the younger frame, then the order given (stable)."""
    return sorted(decals, key=lambda d: (-d.view.priority, d.view.age_s))


class DeferredProjectors:
    """The frame's buffers (colour, surface, scene depth, claims) at the size of the caller's
    framebuffer, and the decal programs; call from the GL thread only."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.programs: dict[tuple[tuple[str, int], ...], moderngl.Program] = {}
        # A reach polygon has at most as many vertices as its polytope: C(13, 3) plane triples.
        self.vbo = ctx.buffer(reserve=MAX_POLYGON * 8, dynamic=True)
        self.vao: dict[int, moderngl.VertexArray] = {}
        self.size = (0, 0)
        self._objects: list = []
        self.scene_fbo: moderngl.Framebuffer | None = None  # colour + surface + scene depth
        self.frame_fbo: moderngl.Framebuffer | None = None  # colour + scene depth (overlays)
        self.decal_fbo: moderngl.Framebuffer | None = None  # colour + claims
        self.claims_fbo: moderngl.Framebuffer | None = None  # claims alone (cleared each frame)
        self.drawn = 0  # projectors drawn in the last frame
        self._reach: list[np.ndarray] = []  # their polygons (window NDC), for `pixels`

    def _ensure(self, size: tuple[int, int]) -> None:
        if self.size == size:
            return
        self._release_targets()
        ctx = self.ctx
        self.colour = ctx.texture(size, 4)
        self.surface = ctx.texture(size, 2, dtype="u4")
        self.surface.filter = (moderngl.NEAREST, moderngl.NEAREST)
        depth = ctx.depth_renderbuffer(size)
        claims = ctx.depth_renderbuffer(size)
        self.scene_fbo = ctx.framebuffer([self.colour, self.surface], depth)
        self.frame_fbo = ctx.framebuffer([self.colour], depth)
        self.decal_fbo = ctx.framebuffer([self.colour], claims)
        self.claims_fbo = ctx.framebuffer(depth_attachment=claims)
        self._objects = [
            self.scene_fbo,
            self.frame_fbo,
            self.decal_fbo,
            self.claims_fbo,
            self.colour,
            self.surface,
            depth,
            claims,
        ]
        self.size = size

    def begin(self, fbo: moderngl.Framebuffer, background: tuple[float, float, float]) -> None:
        """Bind the scene's buffers (the size of `fbo`, drawing into its viewport), cleared to the
        background: the scene pass (with its surface) draws into them next."""
        self._ensure(fbo.size)
        for target in (self.scene_fbo, self.frame_fbo, self.decal_fbo, self.claims_fbo):
            target.viewport = fbo.viewport
        self.scene_fbo.use()
        self.scene_fbo.clear(*background, 1.0, depth=1.0)

    def _program(self, defines: dict[str, int]) -> moderngl.Program:
        key = tuple(sorted(defines.items()))
        program = self.programs.get(key)
        if program is None:
            program = load_program(self.ctx, "decal.vert", "decal.frag", defines)
            u = Uniforms(program)
            u["u_depth_map"] = DEPTH_UNIT
            u["u_surface"] = SURFACE_UNIT
            u["u_video"], u["u_video_u"], u["u_video_v"] = 2, 3, 4
            self.programs[key] = program
            self.vao[program.glo] = self.ctx.vertex_array(program, [(self.vbo, "2f", "in_ndc")])
        return program

    def project(self, view: Camera, settings: ProjectionSettings, decals: list[Decal]) -> None:
        """Draw the projectors over their reach, best first (drawing_order), after the scene."""
        self.drawn, self._reach = 0, []
        if not decals:
            return
        ctx = self.ctx
        vx, vy, _, vh = self.scene_fbo.viewport
        i = view.intrinsics
        self.claims_fbo.use()
        self.claims_fbo.clear(depth=1.0)
        self.decal_fbo.use()
        ctx.enable(moderngl.DEPTH_TEST | moderngl.BLEND)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<"
        # The video over the model by its opacity; the frame's alpha stays 1.
        ctx.blend_func = (
            moderngl.SRC_ALPHA,
            moderngl.ONE_MINUS_SRC_ALPHA,
            moderngl.ZERO,
            moderngl.ONE,
        )
        self.surface.use(SURFACE_UNIT)
        view_inverse = np.linalg.inv(view.view)
        for decal in drawing_order(decals):
            d = decal.view
            exact = d.camera.lens is not None or d.camera.rs_turn is not None
            program = self._program(
                {
                    "EXACT_VIDEO": int(exact),
                    "VIDEO_YUV": d.video.variant,
                    "NEIGHBOURHOOD": int(settings.neighbourhood),
                }
            )
            p = Uniforms(program)
            p.matrices("u_proj_view_proj", [d.camera.view_projection])
            p.matrices("u_view_inverse", [view_inverse])
            p["u_eye"] = tuple(view.position)
            p["u_pixel_ray"] = (vx + i.cx, i.fx, vy + vh - i.cy, i.fy)
            p["u_proj_position"] = tuple(d.camera.position)
            p["u_proj_near"] = d.camera.near
            p["u_proj_far"] = d.camera.far
            scale = d.depth.size[0] / d.camera.intrinsics.width
            p["u_proj_focal_texels"] = max(d.camera.intrinsics.fx, d.camera.intrinsics.fy) * scale
            p["u_alpha"] = d.alpha
            p["u_bias_constant"] = settings.bias_constant_m
            p["u_bias_slope"] = settings.bias_slope
            set_lens(p, d.camera)
            d.depth.texture.use(DEPTH_UNIT)
            d.video.bind(p)
            fan = np.ascontiguousarray(decal.polygon, np.float32)
            self.vbo.write(fan.tobytes())
            self.vao[program.glo].render(moderngl.TRIANGLE_FAN, vertices=len(fan))
            self.drawn += 1
            self._reach.append(decal.polygon)
        ctx.disable(moderngl.BLEND)

    @property
    def pixels(self) -> int:
        """Screen pixels the last frame's reach polygons covered, summed (worked out when asked:
        a statistic, not a cost every frame pays)."""
        if not self._reach:
            return 0
        _, _, w, h = self.scene_fbo.viewport  # the last frame's (begin sets it)
        return sum(polygon_pixels(p, w, h) for p in self._reach)

    def overlays(self) -> moderngl.Framebuffer:
        """The frame's colour and scene depth, bound, for what is drawn over the scene (lines)."""
        self.frame_fbo.use()
        return self.frame_fbo

    def finish(self, fbo: moderngl.Framebuffer) -> None:
        """Copy the frame into `fbo`'s viewport (and bind it)."""
        blit_colour(self.frame_fbo, self.frame_fbo.viewport, fbo, fbo.viewport)

    def _release_targets(self) -> None:
        for obj in self._objects:
            obj.release()
        self._objects = []
        self.size = (0, 0)

    def release(self) -> None:
        self._release_targets()
        for vao in self.vao.values():
            vao.release()
        self.vao.clear()
        for program in self.programs.values():
            program.release()
        self.programs.clear()
        self.vbo.release()
