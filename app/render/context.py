"""OpenGL contexts: a standalone EGL one for tests, CLI export and benchmarks."""

from __future__ import annotations

import ctypes
import ctypes.util

import moderngl

from app.core.errors import GeofuseError

GL_REQUIRE = 400  # textureGather (nine-case rule) needs GLSL 4.00


class RenderUnavailable(GeofuseError):
    """No OpenGL 3.3 context could be made (no EGL / Mesa on this machine)."""


def create_offscreen_context() -> moderngl.Context:
    """A headless OpenGL >= 3.3 core context through EGL (Mesa llvmpipe without a GPU)."""
    try:
        return moderngl.create_context(standalone=True, backend="egl", require=GL_REQUIRE)
    except Exception as exc:
        raise RenderUnavailable(
            f"cannot create an EGL OpenGL {GL_REQUIRE // 100}.{GL_REQUIRE % 100 // 10} core context ({exc}); "
            "install Mesa: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1"
        ) from exc


def describe(ctx: moderngl.Context) -> str:
    """'renderer, GL version' of a context, for logs and benchmark reports."""
    return f"{ctx.info['GL_RENDERER']}, {ctx.info['GL_VERSION']}"


def _libgl_finish():

    for name in ("libGL.so.1", ctypes.util.find_library("GL") or ""):
        try:
            return ctypes.CDLL(name).glFinish
        except OSError:
            continue
    return None


_GL_FINISH = _libgl_finish()


def wait_for_gpu(ctx: moderngl.Context) -> None:
    """Block until the GPU has finished, with Python's GIL released.

    moderngl's `finish()` holds the GIL while it waits, which starves the decoder thread for the
    whole render time on a software rasteriser (measured: another thread ran ~6x slower); a
    ctypes call to libGL's glFinish releases it. Falls back to moderngl without libGL."""
    if _GL_FINISH is not None:
        _GL_FINISH()
    else:
        ctx.finish()
