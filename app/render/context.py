"""OpenGL contexts: a standalone EGL one for tests, CLI export and benchmarks."""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

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


class CurrentContext(NamedTuple):
    """The GL context current on a thread: which API made it current, and its handles."""

    api: str  # "egl", "glx" or "" (none)
    handles: tuple[int, ...]  # display, draw surface, read surface, context


_EGL_DRAW, _EGL_READ = 0x3059, 0x305A


def current_context() -> CurrentContext:
    """The context current on this thread, EGL's (the off-screen ones) or GLX's (a GLFW
    window on X11), to compare or make current again."""
    if _EGL is not None:
        ctx = _EGL.eglGetCurrentContext()
        if ctx:
            draw, read = (_EGL.eglGetCurrentSurface(which) or 0 for which in (_EGL_DRAW, _EGL_READ))
            return CurrentContext("egl", (_EGL.eglGetCurrentDisplay() or 0, draw, read, ctx))
    if _GLX is not None:
        ctx = _GLX.glXGetCurrentContext()
        if ctx:
            g = _GLX
            drawables = (g.glXGetCurrentDrawable() or 0, g.glXGetCurrentReadDrawable() or 0)
            return CurrentContext("glx", (g.glXGetCurrentDisplay() or 0, *drawables, ctx))
    return CurrentContext("", ())


def make_current(saved: CurrentContext) -> None:
    """Make `saved` current again on this thread (nothing to do where none was)."""
    if saved.api == "egl":
        _EGL.eglMakeCurrent(*saved.handles)
    elif saved.api == "glx":
        _GLX.glXMakeContextCurrent(*saved.handles)


@contextmanager
def keep_current() -> Iterator[None]:
    """Whatever GL context was current on this thread before the block is current again after
    it. Making a context (create_offscreen_context) makes it current; without this, a caller's
    own context (a test's shared one, a window's) stops being current, and its later GL calls
    land nowhere or on the wrong objects: clears skipped, reads of uninitialised memory."""
    saved = current_context()
    try:
        yield
    finally:
        make_current(saved)


@contextmanager
def made_current(ctx: moderngl.Context) -> Iterator[moderngl.Context]:
    """`ctx` current inside the block, and what was current before current again after it
    (moderngl's own `with ctx` leaves no context current when it ends)."""
    with keep_current(), ctx:
        yield ctx


SOFTWARE_RASTERISERS = ("llvmpipe", "softpipe", "swrast", "software rasterizer")


def software_rasteriser(renderer: str) -> bool:
    """Whether a GL_RENDERER string names a rasteriser that runs on the CPU (Mesa's llvmpipe,
    softpipe, swrast), where fill rate, not the per-projector setup, bounds a frame."""
    text = renderer.lower()
    return any(name in text for name in SOFTWARE_RASTERISERS)


def describe(ctx: moderngl.Context) -> str:
    """'renderer, GL version' of a context, for logs and benchmark reports."""
    return f"{ctx.info['GL_RENDERER']}, {ctx.info['GL_VERSION']}"


def _library(soname: str, short: str) -> ctypes.CDLL | None:
    """A shared library by its soname, else by what find_library finds for its short name;
    None if neither loads."""
    for name in (soname, ctypes.util.find_library(short) or ""):
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None


_LIBGL = _library("libGL.so.1", "GL")
_GL_FINISH = getattr(_LIBGL, "glFinish", None)


def _typed(lib: ctypes.CDLL | None, names: dict[str, tuple]) -> ctypes.CDLL | None:
    """`lib` with each named function's (result, *arguments) ctypes declared; None if it lacks
    one of them."""
    if lib is None or not all(hasattr(lib, n) for n in names):
        return None
    for name, (result, *args) in names.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = result, args
    return lib


_P, _XID = ctypes.c_void_p, ctypes.c_ulong
_EGL = _typed(
    _library("libEGL.so.1", "EGL"),
    {
        "eglGetCurrentContext": (_P,),
        "eglGetCurrentDisplay": (_P,),
        "eglGetCurrentSurface": (_P, ctypes.c_int),
        "eglMakeCurrent": (ctypes.c_uint, _P, _P, _P, _P),
    },
)
_GLX = _typed(
    _LIBGL,
    {
        "glXGetCurrentContext": (_P,),
        "glXGetCurrentDisplay": (_P,),
        "glXGetCurrentDrawable": (_XID,),
        "glXGetCurrentReadDrawable": (_XID,),
        "glXMakeContextCurrent": (ctypes.c_int, _P, _XID, _XID, _P),
    },
)

GL_READ_FRAMEBUFFER, GL_DRAW_FRAMEBUFFER = 0x8CA8, 0x8CA9
GL_COLOR_BUFFER_BIT, GL_NEAREST = 0x4000, 0x2600


def _gl_blit():
    """glBlitFramebuffer of the current context (moderngl's copy_framebuffer copies from the
    origin only, and with the depth buffer, which a window's may not match): from libGL, else
    through EGL's eglGetProcAddress (glvnd's dispatch serves EGL and GLX contexts alike)."""
    args = [ctypes.c_int] * 8 + [ctypes.c_uint, ctypes.c_uint]
    if _LIBGL is not None and hasattr(_LIBGL, "glBlitFramebuffer"):
        _LIBGL.glBlitFramebuffer.argtypes = args
        _LIBGL.glBindFramebuffer.argtypes = [ctypes.c_uint, ctypes.c_uint]
        return _LIBGL.glBindFramebuffer, _LIBGL.glBlitFramebuffer
    egl = _library("libEGL.so.1", "EGL")
    if egl is None:
        return None
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    bind = egl.eglGetProcAddress(b"glBindFramebuffer")
    blit = egl.eglGetProcAddress(b"glBlitFramebuffer")
    if not (bind and blit):
        return None
    return (
        ctypes.CFUNCTYPE(None, ctypes.c_uint, ctypes.c_uint)(bind),
        ctypes.CFUNCTYPE(None, *args)(blit),
    )


_GL_BLIT = _gl_blit()


def can_blit() -> bool:
    """Whether blit_colour can copy between framebuffers on this machine."""
    return _GL_BLIT is not None


def blit_colour(
    src: moderngl.Framebuffer,
    src_rect: tuple[int, int, int, int],
    dst: moderngl.Framebuffer,
    dst_rect: tuple[int, int, int, int],
) -> None:
    """Copy the colour of rectangle src_rect (x, y, w, h; GL rows from the bottom) of `src` into
    dst_rect of `dst`, texel for texel where the sizes agree; `dst` is bound afterwards."""
    bind, blit = _GL_BLIT
    sx, sy, sw, sh = src_rect
    dx, dy, dw, dh = dst_rect
    bind(GL_READ_FRAMEBUFFER, src.glo)
    bind(GL_DRAW_FRAMEBUFFER, dst.glo)
    blit(sx, sy, sx + sw, sy + sh, dx, dy, dx + dw, dy + dh, GL_COLOR_BUFFER_BIT, GL_NEAREST)
    dst.use()


def wait_for_gpu(ctx: moderngl.Context) -> None:
    """Block until the GPU has finished, with Python's GIL released.

    moderngl's `finish()` holds the GIL while it waits, which starves the decoder thread for the
    whole render time on a software rasteriser (measured: another thread ran ~6x slower); a
    ctypes call to libGL's glFinish releases it. Falls back to moderngl without libGL."""
    if _GL_FINISH is not None:
        _GL_FINISH()
    else:
        ctx.finish()
