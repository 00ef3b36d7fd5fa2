"""The video frame on the GPU: an RGB still, or a playback frame's Y, U, V planes (converted to RGB
in the shader, shaders/include/video.glsl), with the display rotation applied there."""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from app.render.programs import Uniforms

# Studio-swing (limited range) Y'CbCr -> R'G'B', per ITU-R BT.601 and BT.709, as column-major
# mat3 rows: R = 1.164 (Y-16) + ... (values from the standards' inverse matrices, scaled by 255/219
# for luma and 255/224 for chroma).
_BT601 = np.array([[1.164, 0.0, 1.596], [1.164, -0.392, -0.813], [1.164, 2.017, 0.0]])
_BT709 = np.array([[1.164, 0.0, 1.793], [1.164, -0.213, -0.533], [1.164, 2.112, 0.0]])
_FULL601 = np.array([[1.0, 0.0, 1.402], [1.0, -0.344, -0.714], [1.0, 1.772, 0.0]])
_LIMITED_OFFSET = np.array([16.0, 128.0, 128.0]) / 255.0
_FULL_OFFSET = np.array([0.0, 128.0, 128.0]) / 255.0


def yuv_matrix(bt709: bool, full_range: bool) -> tuple[np.ndarray, np.ndarray]:
    """The (matrix, offset) that take (Y, Cb, Cr) in [0, 1] to R'G'B': RGB = M (YUV - offset)."""
    m = _FULL601 if full_range else (_BT709 if bt709 else _BT601)
    return m, (_FULL_OFFSET if full_range else _LIMITED_OFFSET)


def yuv_to_rgb(
    y: np.ndarray, u: np.ndarray, v: np.ndarray, bt709: bool = False, full_range: bool = False
) -> np.ndarray:
    """CPU reference of the shader's conversion: planes (chroma upsampled by repetition) -> RGB uint8."""
    m, off = yuv_matrix(bt709, full_range)
    uu = np.repeat(np.repeat(u, 2, axis=0), 2, axis=1)[: y.shape[0], : y.shape[1]]
    vv = np.repeat(np.repeat(v, 2, axis=0), 2, axis=1)[: y.shape[0], : y.shape[1]]
    yuv = np.stack([y, uu, vv], -1) / 255.0 - off
    return np.clip(np.rint(yuv @ m.T * 255.0), 0, 255).astype(np.uint8)


def _textures(
    ctx: moderngl.Context, old: list[moderngl.Texture], shapes: list[tuple[int, int, int]]
) -> list[moderngl.Texture]:
    """Video textures of `shapes` (width, height, components), filtered linearly and clamped at
    the edges: `old` itself where it has those shapes already, else released and made anew."""
    if [(t.width, t.height, t.components) for t in old] == list(shapes):
        return old
    for t in old:
        t.release()
    made = []
    for w, h, c in shapes:
        t = ctx.texture((w, h), c)
        t.filter = (moderngl.LINEAR, moderngl.LINEAR)
        t.repeat_x = t.repeat_y = False
        made.append(t)
    return made


class VideoTexture:
    """Owns the video textures; `bind(program)` sets the sampler units 2, 3, 4 and the uniforms."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.planes: list[moderngl.Texture] = []
        self.yuv = False
        self.rotation = 0
        self.bt709 = False
        self.full_range = False
        self.size = (0, 0)  # displayed size (w, h)

    def set_rgb(self, rgb: np.ndarray) -> None:
        """A display-oriented (H, W, 3|4) uint8 frame, row 0 = top."""
        img = np.ascontiguousarray(rgb, dtype=np.uint8)
        if img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValueError(f"video frame must be (H, W, 3|4) uint8, got {img.shape}")
        self.planes = _textures(self.ctx, self.planes, [(img.shape[1], img.shape[0], img.shape[2])])
        self.planes[0].write(img.tobytes())
        self.yuv, self.rotation, self.size = False, 0, (img.shape[1], img.shape[0])

    def set_yuv(
        self,
        y: np.ndarray,
        u: np.ndarray,
        v: np.ndarray,
        rotation_cw: int,
        bt709: bool,
        full_range: bool = False,
    ) -> None:
        """Stored planes: Y (H, W), U and V (H/2, W/2) uint8; rotation_cw turns them for display."""
        h, w = y.shape
        shapes = [(w, h, 1), (u.shape[1], u.shape[0], 1), (v.shape[1], v.shape[0], 1)]
        self.planes = _textures(self.ctx, self.planes, shapes)
        for tex, plane in zip(self.planes, (y, u, v), strict=True):
            tex.write(np.ascontiguousarray(plane).tobytes())
        self.yuv, self.rotation, self.bt709, self.full_range = (
            True,
            int(rotation_cw) % 360,
            bt709,
            full_range,
        )
        self.size = (h, w) if self.rotation % 180 else (w, h)

    @property
    def ready(self) -> bool:
        return bool(self.planes)

    def bind(self, uniforms: Uniforms) -> None:
        """Its planes on texture units 2-4 and video.glsl's uniforms (a shader compiled with
        VIDEO_YUV = self.yuv)."""
        uniforms["u_video_rotation"] = self.rotation
        m, offset = yuv_matrix(self.bt709, self.full_range)
        uniforms.matrices("u_yuv_matrix", [m])
        uniforms["u_yuv_offset"] = tuple(offset)
        for unit, tex in zip(
            (2, 3, 4), self.planes + [self.planes[0]] * (3 - len(self.planes)), strict=True
        ):
            tex.use(unit)

    @property
    def variant(self) -> int:
        """video.glsl's VIDEO_YUV for this frame: 0 an RGB still, 1 three planes."""
        return int(self.yuv)

    def release(self) -> None:
        for t in self.planes:
            t.release()
        self.planes = []


@dataclass(frozen=True)
class YuvPlanes:
    """A stored playback frame as the decoder gives it: Y (H, W), U and V (H/2, W/2) uint8, shown
    turned clockwise by rotation_cw degrees; bt709 and full_range: its colour matrix and range."""

    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    rotation_cw: int = 0
    bt709: bool = False
    full_range: bool = False


class ExtraVideo:
    """A further projector's video as the scene pass samples it: an RGB still (display-oriented)
    as one texture, or a playback frame as stored: Y in `texture` (R8) and U, V in `chroma` (one
    RG8 texture at half size), turned for display and converted to RGB in the shader like the
    first projector's frames (no conversion on the CPU, where numpy took 82 ms a 1080p frame:
    docs/PERFORMANCE.md)."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.planes: list[moderngl.Texture] = []  # [RGB] or [Y, UV]
        self.rotation = 0  # clockwise degrees from stored to displayed (planes only)
        self.bt709 = False
        self.full_range = False

    @property
    def texture(self) -> moderngl.Texture | None:
        """The RGB still, or the Y plane."""
        return self.planes[0] if self.planes else None

    @property
    def chroma(self) -> moderngl.Texture | None:
        """U and V in one texture; None for an RGB still."""
        return self.planes[1] if len(self.planes) == 2 else None

    @property
    def ready(self) -> bool:
        return bool(self.planes)

    @property
    def variant(self) -> int:
        """video.glsl's VIDEO_YUV for this frame: 0 an RGB still, 2 Y and a two-channel U, V."""
        return 2 if self.chroma is not None else 0

    def bind(self, uniforms: Uniforms) -> None:
        """Its planes on texture units 2 and 3 and video.glsl's uniforms (a shader compiled with
        VIDEO_YUV = self.variant): as VideoTexture.bind, for the deferred projectors."""
        uniforms["u_video_rotation"] = self.rotation
        m, offset = yuv_matrix(self.bt709, self.full_range)
        uniforms.matrices("u_yuv_matrix", [m])
        uniforms["u_yuv_offset"] = tuple(offset)
        self.texture.use(2)
        (self.chroma or self.texture).use(3)

    def set(self, frame: np.ndarray | YuvPlanes) -> None:
        """An RGB frame (H, W, 3) uint8, row 0 the displayed top, or a stored frame's planes."""
        if isinstance(frame, YuvPlanes):
            h, w = frame.y.shape
            ch, cw = frame.u.shape
            if frame.v.shape != (ch, cw) or not (0 < ch <= h and 0 < cw <= w):
                raise ValueError(
                    f"YUV planes must be Y (H, W), U and V alike and no larger, got {frame.y.shape}, "
                    f"{frame.u.shape}, {frame.v.shape}"
                )
            self.planes = _textures(self.ctx, self.planes, [(w, h, 1), (cw, ch, 2)])
            self.planes[0].write(np.ascontiguousarray(frame.y, np.uint8).tobytes())
            self.planes[1].write(np.stack([frame.u, frame.v], -1).astype(np.uint8).tobytes())
            self.rotation = int(frame.rotation_cw) % 360
            self.bt709, self.full_range = bool(frame.bt709), bool(frame.full_range)
            return
        img = np.ascontiguousarray(frame, dtype=np.uint8)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"a video frame must be (H, W, 3) uint8, got {img.shape}")
        self.planes = _textures(self.ctx, self.planes, [(img.shape[1], img.shape[0], 3)])
        self.planes[0].write(img.tobytes())
        self.rotation = 0

    def release(self) -> None:
        for t in self.planes:
            t.release()
        self.planes = []
