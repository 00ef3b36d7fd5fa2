"""The interactive viewer: a GLFW window with a ModernGL renderer and ImGui panels.

The frame loop pulls: each tick it advances the playback clock, takes the frame due from the
decoder's queue (stale serials dropped), looks up the pose for that frame's time, updates the
projector (the depth map is redrawn only when the pose changed), draws the scene and the panels,
and records each frame's playback latency (due time -> first display, as the paper defines it).
A bad file never crashes it: the error panel says what is wrong and the viewer keeps running.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from app.camera import Camera, Intrinsics
from app.config import OverlaySettings, ProjectionSettings
from app.errors import GeofuseError
from app.playback.clock import PlaybackClock
from app.playback.player import Player
from app.playback.tracks import TrackLibrary
from app.ui.navigation import Navigator
from app.ui.script import Action, parse_script

log = logging.getLogger("geofuse.viewer")
GL_VERSION = (4, 1)
TRAJECTORY_STEP = 5  # frames between trajectory polyline vertices


@dataclass
class Options:
    manifest: Path | None
    size: tuple[int, int] = (1280, 720)
    script: Path | None = None
    screenshot: Path | None = None
    play_seconds: float = 2.0  # with --screenshot alone: play this long, then save and exit
    visible: bool = True
    srt: Path | None = None


@dataclass
class Loaded:
    """One open session and everything made for it."""

    session: object
    renderer: object
    player: Player
    tracks: TrackLibrary
    source: str
    trajectory: np.ndarray | None = None

    @property
    def clock(self) -> PlaybackClock:
        return self.player.clock


@dataclass
class Stats:
    frame_times: list[float] = field(default_factory=list)
    depth_redraws: int = 0


def home_view(session, mesh) -> Navigator:
    """Where the window camera starts: for a real scene, south of it looking across it; on an
    assumed ground, behind and above the camera's track so that its frustum and footprint show."""
    if session.scene_path is None:
        g = session.gnss
        enu = session.frame.geodetic_to_enu(g.lat, g.lon, g.h)
        centre = (enu.min(axis=0) + enu.max(axis=0)) / 2
        size = float(max(np.ptp(enu[:, 0]), np.ptp(enu[:, 1]), 10.0))
        eye = centre + np.array([-0.4 * size - 12.0, -0.8 * size - 25.0, 0.5 * size + 18.0])
        d = centre - eye
        return Navigator(position=eye, yaw=float(np.degrees(np.arctan2(d[0], d[1]))), pitch=float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1])))))
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    return Navigator(position=np.array([centre[0] + 35.0, lo[1] - 20.0, 40.0]), yaw=-15.0, pitch=-15.0)


class Viewer:
    def __init__(self, options: Options) -> None:
        self.options = options
        self.loaded: Loaded | None = None
        self.errors: list[str] = []
        self.notices: list[str] = []
        self.settings = ProjectionSettings(alpha=0.85)
        self.overlays = OverlaySettings()
        self.time_offset_s = 0.0
        self.nav = Navigator()
        self.stats = Stats()
        self.quit = False
        self.script: list[Action] = []
        self.show_help = False
        self.open_path = ""
        self.screenshot_request: Path | None = None
        self.state_request: Path | None = None
        self.show_panels = True
        self.window_camera: Camera | None = None

    # --- setup ----------------------------------------------------------------------------------

    def _window(self) -> None:
        import glfw
        import moderngl

        if not glfw.init():
            raise GeofuseError("cannot initialise GLFW: no display? (set DISPLAY, or run under Xvfb)")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, GL_VERSION[0])
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, GL_VERSION[1])
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, self.options.visible)
        w, h = self.options.size
        self.window = glfw.create_window(w, h, "geofuse", None, None)
        if not self.window:
            glfw.terminate()
            raise GeofuseError(f"cannot open an OpenGL {GL_VERSION[0]}.{GL_VERSION[1]} core window")
        glfw.make_context_current(self.window)
        glfw.swap_interval(0)  # the clock paces playback; never block on vsync
        self.ctx = moderngl.create_context(require=400)
        from imgui_bundle import imgui, implot
        from imgui_bundle.python_backends.glfw_backend import GlfwRenderer

        imgui.create_context()
        implot.create_context()
        imgui.get_io().set_ini_filename("")  # never write imgui.ini into the user's folder
        self.imgui_renderer = GlfwRenderer(self.window)
        glfw.set_scroll_callback(self.window, self._on_scroll)

    def _on_scroll(self, window, dx: float, dy: float) -> None:
        from imgui_bundle import imgui

        self.imgui_renderer.scroll_callback(window, dx, dy)
        if not imgui.get_io().want_capture_mouse:
            self.nav.wheel(dy)

    # --- sessions -------------------------------------------------------------------------------

    def open(self, manifest: Path | None) -> bool:
        """Open a session (the bundled sample when None); on failure keep the current one."""
        from app.clips import open_any
        from app.demo import SAMPLE_DIR
        from app.render.renderer import FusionRenderer

        path = Path(manifest) if manifest is not None else SAMPLE_DIR / "session.toml"
        try:
            session = open_any(path, self.options.srt if path == self.options.manifest else None)
            mesh = session.scene()
        except GeofuseError as exc:
            self.errors.append(str(exc))
            log.error("%s", exc)
            return False
        except Exception as exc:  # an unexpected reader failure is still only an error panel entry
            self.errors.append(f"{path}: {type(exc).__name__}: {exc}")
            log.exception("opening %s", path)
            return False
        self.close_session()
        renderer = FusionRenderer(self.ctx, mesh)
        pts = session.video.pts_s
        first = session.filters[0]
        self.loaded = Loaded(session, renderer, Player(session.video.path, pts), TrackLibrary(session, first=first), first)
        self.notices = list(session.warnings.items)
        self.stats = Stats()
        self.nav = home_view(session, mesh)
        log.info("opened %s: %d frames, sources %s", path, len(pts), session.filters)
        return True

    def close_session(self) -> None:
        if self.loaded is not None:
            self.loaded.player.close()
            self.loaded.renderer.release()
            self.loaded = None

    # --- playback -------------------------------------------------------------------------------

    @property
    def current_index(self) -> int:
        return self.loaded.player.index if self.loaded is not None else -1

    def seek(self, media_time: float, now: float) -> None:
        self.loaded.player.seek(media_time, now)

    def step(self, frames: int, now: float) -> None:
        self.loaded.player.step(frames, now)

    def set_source(self, name: str) -> None:
        if self.loaded is not None and name in self.loaded.session.filters:
            self.loaded.source = name

    def set_course_pitch(self, pitch_deg: float) -> None:
        """A drone clip without gimbal attitude: change the assumed camera pitch and re-solve
        that one source (a fraction of a second)."""
        from app.clips import set_course_pitch
        from app.session import pose_track

        L = self.loaded
        if L is None or "course" not in L.session.references:
            return
        set_course_pitch(L.session, pitch_deg)
        L.tracks.tracks["course"] = pose_track(L.session, "course")
        L.tracks.curves.pop("course", None)
        L.trajectory = None

    def toggle_ahrs(self, on: bool | None = None) -> None:
        """Switch between the AHRS and IMU forms of the current filter."""
        if self.loaded is None:
            return
        src = self.loaded.source
        pairs = {"gd-ahrs": "gd-imu", "cf-ahrs": "cf-imu"}
        inverse = {v: k for k, v in pairs.items()}
        if src in pairs and on is not True:
            self.set_source(pairs[src])
        elif src in inverse and on is not False:
            self.set_source(inverse[src])

    def _camera_of(self, source: str | None, times: np.ndarray | None = None) -> Camera | None:
        """The video's camera for the current frame under `source`, at the pipeline's frame time
        plus the live time offset, or at `times` (one per frame) when given."""
        L = self.loaded
        track = L.tracks.tracks.get(source) if source else None
        if track is None or self.current_index < 0:
            return None
        t = L.session.frame_times[self.current_index] + self.time_offset_s if times is None else times[self.current_index]
        enu, _, q = track.at(np.array([t]))
        return Camera.create(L.session.intrinsics, enu[0], q[0], near=0.5, far=2000.0)

    def _reference_camera(self) -> Camera | None:
        """The reference (truth or the phone's own) beside the chosen source's frustum."""
        ref = self.loaded.tracks.reference()
        return self._camera_of(ref) if ref != self.loaded.source else None

    def _truth_camera(self) -> Camera | None:
        """The video's true camera, at the frame's true time (for the error overlay)."""
        if not self.overlays.error_map:
            return None
        s = self.loaded.session
        return self._camera_of("truth", s.truth_frame_times if s.truth_frame_times is not None else s.frame_times)

    def _update(self, now: float) -> None:
        L = self.loaded
        if L is None:
            return
        error = L.player.decoder.error
        if error and error not in self.errors:
            self.errors.append(error)
        if L.player.tick(now):
            f = L.player.current
            L.renderer.set_video_yuv(f.y, f.u, f.v, L.session.rotation_cw, f.bt709, f.full_range)
        projector = self._camera_of(L.source)
        L.renderer.set_projector(projector)
        L.renderer.set_reference(self._reference_camera())
        L.renderer.set_truth(self._truth_camera())
        if L.trajectory is None and L.source in L.tracks.tracks:
            enu, _, _ = L.tracks.tracks[L.source].at(L.session.frame_times[::TRAJECTORY_STEP])
            L.trajectory = enu
            L.renderer.set_trajectory(enu)

    # --- drawing --------------------------------------------------------------------------------

    def _draw(self) -> None:
        import glfw

        fb_w, fb_h = glfw.get_framebuffer_size(self.window)
        if fb_w <= 0 or fb_h <= 0:
            return
        self.ctx.screen.use()
        self.ctx.viewport = (0, 0, fb_w, fb_h)
        if self.loaded is None:
            self.ctx.clear(0.62, 0.74, 0.86)
            return
        L = self.loaded
        self.window_camera = self.nav.camera(Intrinsics.from_fov(fb_w, fb_h, 60.0), L.renderer.projector)
        before = L.renderer.depth.renders
        L.renderer.draw(self.window_camera, self.ctx.screen, self.settings, self.overlays)
        self.stats.depth_redraws += L.renderer.depth.renders - before

    def screenshot(self, path: Path) -> Path:
        """The window's current back buffer (scene and panels) as PNG."""
        import glfw

        from app.imageio import write_rgb

        import OpenGL.GL as gl

        w, h = glfw.get_framebuffer_size(self.window)
        # moderngl's read of the default framebuffer selects GL_COLOR_ATTACHMENT0, which is invalid
        # there (GL_INVALID_OPERATION, then PyOpenGL raises at ImGui's next call): read GL_BACK.
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, 0)
        gl.glReadBuffer(gl.GL_BACK)
        gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
        data = np.frombuffer(gl.glReadPixels(0, 0, w, h, gl.GL_RGB, gl.GL_UNSIGNED_BYTE), np.uint8)
        out = write_rgb(path, data.reshape(h, w, 3)[::-1])
        log.info("screenshot %s", out)
        return out

    def write_state(self, path: Path) -> None:
        """The state a test needs to reproduce this frame off-screen, as JSON."""
        import json

        state: dict = {"errors": self.errors, "notices": self.notices, "frames_drawn": len(self.stats.frame_times)}
        L = self.loaded
        if L is not None:
            cam = self.window_camera
            i = cam.intrinsics
            proj = L.renderer.projector
            state.update(
                manifest=str(L.session.manifest.path), source=L.source, frame=self.current_index,
                frames_shown=len(L.player.stats.latencies), dropped=L.player.stats.dropped,
                alpha=self.settings.alpha, time_offset_s=self.time_offset_s,
                window_camera={"size": [i.width, i.height], "fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "position": list(cam.position), "orientation": list(cam.orientation), "near": cam.near, "far": cam.far},
                projector=None if proj is None else {"position": list(proj.position), "orientation": list(proj.orientation)},
            )
        Path(path).write_text(json.dumps(state, indent=1))

    # --- script ---------------------------------------------------------------------------------

    def _run_script(self, elapsed: float, now: float) -> None:
        while self.script and self.script[0].at_s <= elapsed:
            a = self.script.pop(0)
            try:
                self.apply(a.name, a.arg, now)
            except (ValueError, GeofuseError) as exc:
                self.errors.append(f"script line {a.line}: {a.name}: {exc}")

    def apply(self, name: str, arg: str | None, now: float) -> None:
        """One UI action by name (the script's vocabulary; the panels call the same methods)."""
        L = self.loaded
        if name == "quit":
            self.quit = True
        elif name == "open":
            self.open(Path(arg))
        elif name == "screenshot":
            self.screenshot_request = Path(arg)  # taken after this frame's panels are drawn
        elif name == "state":
            self.state_request = Path(arg)
        elif name == "panels":
            self.show_panels = arg == "on"
        elif name == "lines":
            self.overlays = replace(self.overlays, frustum=arg == "on", trajectory=arg == "on")
        elif L is None:
            raise ValueError("no session is open")
        elif name == "play":
            L.clock.set_paused(False, now)
        elif name == "pause":
            L.clock.set_paused(True, now)
        elif name == "seek":
            self.seek(float(arg), now)
        elif name == "step":
            self.step(int(arg), now)
        elif name == "speed":
            L.clock.set_speed(float(arg), now)
        elif name == "source":
            if arg not in L.session.filters:
                raise ValueError(f"unknown source {arg!r}; the session offers {L.session.filters}")
            self.set_source(arg)
        elif name == "ahrs":
            self.toggle_ahrs(arg == "on")
        elif name == "alpha":
            self.settings = replace(self.settings, alpha=float(arg))
        elif name == "offset":
            self.time_offset_s = float(arg)
        elif name == "pitch":
            self.set_course_pitch(float(arg))
        elif name == "overlay":
            self.overlays = replace(self.overlays, error_map=arg == "on")
        elif name == "view":
            if arg == "reset":
                self.nav.reset()
            elif arg == "orbit":
                from app.ui import panels

                panels.orbit_pick(self)  # as the O key: around the point under the cursor
            else:
                self.nav.mode = arg

    # --- the loop -------------------------------------------------------------------------------

    def run(self) -> int:
        import glfw
        from imgui_bundle import imgui

        from app.ui import panels

        self._window()
        if self.options.script is not None:
            try:
                self.script = parse_script(self.options.script)
            except GeofuseError as exc:
                self.errors.append(str(exc))
        self.open(self.options.manifest)
        if self.loaded is not None and self.options.script is None:
            self.loaded.clock.set_paused(False, time.perf_counter())
        start = time.perf_counter()
        last = start
        try:
            while not glfw.window_should_close(self.window) and not self.quit:
                now = time.perf_counter()
                dt, last = now - last, now
                glfw.poll_events()
                self.imgui_renderer.process_inputs()
                panels.handle_keys(self, dt, now)
                self._run_script(now - start, now)
                self._update(now)
                self._draw()
                panels.draw(self, now)
                self.imgui_renderer.render(imgui.get_draw_data())
                if self.options.screenshot is not None and self.options.script is None and now - start >= self.options.play_seconds:
                    self.screenshot_request, self.quit = self.options.screenshot, True
                if self.screenshot_request is not None:
                    self.screenshot(self.screenshot_request)
                    self.screenshot_request = None
                if self.state_request is not None:
                    self.write_state(self.state_request)
                    self.state_request = None
                glfw.swap_buffers(self.window)
                shown = time.perf_counter()
                if self.loaded is not None:
                    self.loaded.player.shown(shown, shown - now)
                self.stats.frame_times.append(shown - now)
                del self.stats.frame_times[:-600]
        finally:
            if self.loaded is not None:
                _, mean, p95 = self.loaded.player.stats.summary()
                log.info("latency mean %.1f ms, p95 %.1f ms, dropped %d", mean, p95, self.loaded.player.stats.dropped)
            self.close_session()
            try:
                self.imgui_renderer.shutdown()
            except Exception:  # PyOpenGL may already have lost the context at exit: nothing to free
                log.debug("imgui renderer shutdown failed", exc_info=True)
            glfw.terminate()
        return 0
