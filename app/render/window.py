"""The on-screen platform: a GLFW window with its OpenGL core context, beside the off-screen EGL
one (app.render.context). The viewer asks for one or the other; everything else draws through
moderngl the same way. Only app.ui uses this module."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

import glfw
import moderngl
import numpy as np
import OpenGL.GL as gl

from app.core.errors import GeofuseError
from app.render.context import GL_REQUIRE

GL_VERSION = (4, 1)  # core profile; 4.1 is the highest macOS offers, 4.0 is what the shaders need


class Window:
    """A GLFW window and its moderngl context (`ctx`); the GL calls stay on this thread."""

    def __init__(self, size: tuple[int, int], visible: bool = True, title: str = "geofuse") -> None:

        if not glfw.init():
            raise GeofuseError(
                "cannot initialise GLFW: no display? (set DISPLAY, or run under Xvfb)"
            )
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, GL_VERSION[0])
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, GL_VERSION[1])
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, visible)
        self.handle = glfw.create_window(size[0], size[1], title, None, None)
        if not self.handle:
            glfw.terminate()
            raise GeofuseError(f"cannot open an OpenGL {GL_VERSION[0]}.{GL_VERSION[1]} core window")
        glfw.make_context_current(self.handle)
        glfw.swap_interval(0)  # the playback clock paces the loop; never block on vsync
        self.ctx = moderngl.create_context(require=GL_REQUIRE)
        self._glfw = glfw

    @property
    def should_close(self) -> bool:
        return bool(self._glfw.window_should_close(self.handle))

    def poll(self) -> None:
        self._glfw.poll_events()

    def swap(self) -> None:
        self._glfw.swap_buffers(self.handle)

    def framebuffer_size(self) -> tuple[int, int]:
        return tuple(self._glfw.get_framebuffer_size(self.handle))

    def size(self) -> tuple[int, int]:
        """The window's size in screen coordinates (mouse positions use these)."""
        return tuple(self._glfw.get_window_size(self.handle))

    def cursor(self) -> tuple[float, float]:
        return tuple(self._glfw.get_cursor_pos(self.handle))

    def key_down(self, key: int) -> bool:
        return self._glfw.get_key(self.handle, key) == self._glfw.PRESS

    def mouse_down(self, button: int) -> bool:
        return self._glfw.get_mouse_button(self.handle, button) == self._glfw.PRESS

    def on_scroll(self, callback: Callable[[float, float], None]) -> None:
        """callback(dx, dy) on wheel motion (chained after any callback set before, e.g. ImGui's)."""
        previous = self._glfw.set_scroll_callback(self.handle, None)

        def both(win, dx: float, dy: float) -> None:
            if previous is not None:
                previous(win, dx, dy)
            callback(dx, dy)

        self._glfw.set_scroll_callback(self.handle, both)

    def on_drop(self, callback: Callable[[list[str]], None]) -> None:
        """callback(paths) when files are dropped on the window."""
        self._glfw.set_drop_callback(self.handle, lambda win, paths: callback(list(paths)))

    def clear(self, rgb: tuple[float, float, float]) -> tuple[int, int]:
        """Clear the whole framebuffer to rgb (0..1); returns its size (w, h) px."""
        w, h = self.framebuffer_size()
        self.ctx.screen.use()
        self.ctx.viewport = (0, 0, max(w, 0), max(h, 0))
        if w > 0 and h > 0:
            self.ctx.clear(*rgb)
        return w, h

    @contextmanager
    def region(self, rect: tuple[int, int, int, int]) -> Iterator[moderngl.Framebuffer]:
        """The screen framebuffer drawing into rect (x, y from the top, w, h; framebuffer px)
        only, for the `with` block; the whole framebuffer again after it."""
        x, y, w, h = rect
        fb_w, fb_h = self.framebuffer_size()
        self.ctx.screen.viewport = (x, fb_h - y - h, w, h)  # GL counts rows from the bottom
        try:
            yield self.ctx.screen
        finally:
            self.ctx.screen.viewport = (0, 0, fb_w, fb_h)

    def read_back_buffer(self) -> np.ndarray:
        """The back buffer (what the next swap shows) as (H, W, 3) uint8 RGB, row 0 at the top."""

        w, h = self.framebuffer_size()
        # moderngl's read of the default framebuffer selects GL_COLOR_ATTACHMENT0, which is invalid
        # there (GL_INVALID_OPERATION, then PyOpenGL raises at ImGui's next call): read GL_BACK.
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, 0)
        gl.glReadBuffer(gl.GL_BACK)
        gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
        data = np.frombuffer(gl.glReadPixels(0, 0, w, h, gl.GL_RGB, gl.GL_UNSIGNED_BYTE), np.uint8)
        return data.reshape(h, w, 3)[::-1]

    def close(self) -> None:
        self._glfw.terminate()
