"""The interactive viewer: a window (app.render.window) with the fusion renderer and ImGui panels.

The frame loop pulls: each tick it reads its clock (injected: the wall clock, or a fixed-step
clock a script sets), advances playback to the frame due, asks the session's camera track for
that frame's camera (app.camera_track: the one place a pose for display is computed), updates
the projector (the depth map is redrawn only when the pose changed), draws the scene into the 3D
view's rectangle and the panels around it, and records each frame's playback latency (due time ->
first display, as the paper defines it). When drawing is slower than the video, frames are
dropped and counted (app.playback.player, app.playback.decoder), so the frame shown stays the one
due. A bad file never crashes it: the error panel says what is wrong and the viewer keeps running.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from app.camera import Camera, Intrinsics
from app.errors import GeofuseError
from app.messages import ERROR, WARNING
from app.playback.clock import SPEEDS, PlaybackClock
from app.playback.library import SolverLibrary
from app.playback.player import Player
from app.render.window import Window
from app.session.model import REGISTERED
from app.ui import panels
from app.ui.commands import run_command
from app.ui.gui import Gui
from app.ui.inputs import handle_input
from app.ui.jobs import ViewerJobs
from app.ui.navigation import Navigator
from app.ui.script import Action, parse_script
from app.ui.state import UiState

if TYPE_CHECKING:
    from app.render.renderer import FusionRenderer
    from app.session.model import Session

log = logging.getLogger("geofuse.viewer")
TRAJECTORY_STEP = 5  # frames between trajectory polyline vertices
VIEW_HFOV_DEG = 60.0  # the window camera's horizontal field of view
FIXED_CLOCK_WAIT_S = 30.0  # on a fixed-step clock, wait this long at most for a decoded frame
SOLVE_WAIT_S = 600.0  # `wait solved` gives up after this long (real seconds)
FRAME_HISTORY = 600  # frame times kept for the Stats panel


@dataclass
class Options:
    manifest: Path | None
    size: tuple[int, int] = (1280, 720)
    script: Path | None = None
    screenshot: Path | None = None
    play_seconds: float = 2.0  # with --screenshot alone: play this long, then save and exit
    visible: bool = True
    srt: Path | None = None
    lens: Path | None = None  # a lens profile for a clip opened from the command line
    layers: tuple = ()  # app.scene.layers.Layer: the scene of a clip opened from the command line


@dataclass
class Loaded:
    """One open session and everything made for it."""

    session: Session
    renderer: FusionRenderer
    player: Player
    library: SolverLibrary
    source: str
    trajectory_version: tuple[int, str] | None = None  # (library version, source) drawn

    @property
    def clock(self) -> PlaybackClock:
        return self.player.clock


@dataclass
class Stats:
    frames: int = 0  # frames drawn since the session opened
    frame_times: list[float] = field(default_factory=list)  # the last FRAME_HISTORY, seconds
    depth_redraws: int = 0


class FixedStepClock:
    """A clock a script controls: `now()` stays put within a frame; `advance()` moves it by step s."""

    def __init__(self, start: float, step: float) -> None:
        if not 0.0 < step <= 10.0:
            raise ValueError(f"clock step must be in (0, 10] seconds, got {step}")
        self.t, self.step = float(start), float(step)

    def __call__(self) -> float:
        return self.t

    def advance(self) -> None:
        self.t += self.step


def home_view(session, mesh) -> Navigator:
    """Where the window camera starts: for a model of a site, south of it looking across it; on an
    assumed ground, a tileset or terrain larger than a site, behind and above the camera's track
    so that its frustum and footprint show."""
    if (
        session.scene_path is None
        or mesh.tilesets
        or float(np.ptp(mesh.bounds()[:, :2], axis=0).max()) > 2000.0
    ):
        g = session.gnss
        enu = session.frame.geodetic_to_enu(g.lat, g.lon, g.h)
        centre = (enu.min(axis=0) + enu.max(axis=0)) / 2
        size = float(max(np.ptp(enu[:, 0]), np.ptp(enu[:, 1]), 10.0))
        eye = centre + np.array([-0.4 * size - 12.0, -0.8 * size - 25.0, 0.5 * size + 18.0])
        d = centre - eye
        return Navigator(
            position=eye,
            yaw=float(np.degrees(np.arctan2(d[0], d[1]))),
            pitch=float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1])))),
        )
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    return Navigator(
        position=np.array([centre[0] + 35.0, lo[1] - 20.0, 40.0]), yaw=-15.0, pitch=-15.0
    )


def _is_layer(path: Path) -> bool:
    """A tileset, a DEM or a model: added to the open clip's scene rather than opened."""
    from app.scene.layers import layer_kind

    try:
        return layer_kind(path) in ("tileset", "dem") or (
            layer_kind(path) == "mesh" and path.suffix.lower() != ".toml"
        )
    except GeofuseError:
        return False


def config_dir() -> Path:
    """Where the viewer remembers its panel layout: $XDG_CONFIG_HOME/geofuse (~/.config/geofuse)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "geofuse"


class Viewer(ViewerJobs):
    def __init__(self, options: Options, clock: Callable[[], float] = time.perf_counter) -> None:
        self.options = options
        self.clock = clock
        self.loaded: Loaded | None = None
        self.ui = UiState()
        self.nav = Navigator()
        self.stats = Stats()
        self.script: list[Action] = []
        self.window = None
        self.window_camera: Camera | None = None
        self._messages_seen = 0  # of the open session's messages, shown so far
        self.view_rect: tuple[int, int, int, int] | None = (
            None  # x, y (from the top), w, h in framebuffer pixels
        )

    # --- clocks ---------------------------------------------------------------------------------

    def use_fixed_clock(self, step_s: float) -> None:
        """From now on every frame advances the clock by step_s, whatever the machine's speed."""
        self.clock = FixedStepClock(self.clock(), step_s)

    def use_wall_clock(self) -> None:
        self.clock = time.perf_counter

    @property
    def fixed_clock(self) -> bool:
        return isinstance(self.clock, FixedStepClock)

    def use_lens(self, profile: Path | None) -> None:
        """Reopen the clip through another lens profile (None: the one chosen from the file)."""
        s = self.loaded.session
        if s.path.suffix.lower() == ".toml":
            raise ValueError("a manifest names its lens as camera.lens; edit it and reopen")
        previous = self.options.lens
        self.options.lens = profile
        self.options.manifest = s.path
        if not self.open(s.path):
            self.options.lens = previous

    def add_layer(self, location: str) -> None:
        """Reopen the clip with one more scene layer (a tileset, a DEM, a model in ECEF), as a
        dropped or opened tileset.json or .tif does."""
        from app.scene.layers import Layer

        s = self.loaded.session if self.loaded is not None else None
        if s is None or s.path.suffix.lower() == ".toml":
            raise ValueError(
                f"{location}: a manifest names its scene ([scene], [[layers]], [dem]); edit it and reopen, or open a clip first"
            )
        previous = self.options.layers
        self.options.layers = (*previous, Layer.of(location))
        self.options.manifest = s.path
        if not self.open(s.path):
            self.options.layers = previous

    def set_tile_detail(self, max_sse_px: float) -> None:
        """3D Tiles refine where their screen-space error exceeds max_sse_px (1..256 px)."""
        if not 1.0 <= max_sse_px <= 256.0:
            raise ValueError(f"expected 1..256 pixels, got {max_sse_px:g}")
        self.ui.max_sse_px = float(max_sse_px)

    def wait_until_tiles_loaded(self) -> None:
        """Load the tiles the current view and the projector need (scripts, screenshots)."""
        L = self.loaded
        if L is None or not L.renderer.scene.tilesets or self.window_camera is None:
            return
        for layer in L.renderer.scene.tilesets:
            layer.max_sse_px = self.ui.max_sse_px
        if not L.renderer.settle(self.window_camera, self.ui.settings, SOLVE_WAIT_S):
            raise GeofuseError(f"the 3D Tiles did not load within {SOLVE_WAIT_S:g} s")

    def _tile_notices(self) -> None:
        """Tile load failures and skipped content, said once each as notices."""
        errors = [e for layer in self.loaded.renderer.scene.tilesets for e in layer.stream.errors]
        for e in errors[self.ui.tile_errors_said :]:
            self.ui.notices.append(f"3D Tiles: {e}")
        self.ui.tile_errors_said = len(errors)
        for layer in self.loaded.renderer.scene.tilesets:
            for kind in layer.stream.skipped.snapshot():
                note = f"3D Tiles: skipped {kind} (the Stats panel counts them)"
                if note not in self.ui.notices:
                    self.ui.notices.append(note)

    def wait_until_solved(self, registered: bool = False) -> None:
        """Hold everything until every source is solved: all but `registered` (a script's `wait
        solved`: registration takes about as long as the clip), or it too (`wait registered`)."""
        but = () if registered else (REGISTERED,)
        if self.loaded is not None and not self.loaded.library.wait(SOLVE_WAIT_S, but):
            raise GeofuseError(f"the pose sources were not solved within {SOLVE_WAIT_S:g} s")

    # --- sessions -------------------------------------------------------------------------------

    def open(self, manifest: Path | None) -> bool:
        """Open a session or clip (the bundled sample when None); on failure keep the current one."""
        from app.clips import open_any
        from app.demo import SAMPLE_DIR
        from app.render.renderer import FusionRenderer

        path = Path(manifest) if manifest is not None else SAMPLE_DIR / "session.toml"
        if manifest is not None and _is_layer(path):
            try:
                self.add_layer(str(path))
            except (ValueError, GeofuseError) as exc:
                self.ui.error(str(exc))
                return False
            return True
        try:
            own = path == self.options.manifest
            session = open_any(
                path,
                self.options.srt if own else None,
                lens=self.options.lens if own else None,
                layers=self.options.layers if own else (),
            )
            mesh = session.scene()
        except GeofuseError as exc:
            self.ui.error(str(exc))
            log.error("%s", exc)
            return False
        except Exception as exc:  # an unexpected reader failure is still only an error panel entry
            self.ui.error(f"{path}: {type(exc).__name__}: {exc}")
            log.exception("opening %s", path)
            return False
        self.close_session()
        first = session.sources[0]
        self.loaded = Loaded(
            session,
            FusionRenderer(self.window.ctx, mesh),
            Player(session.video),
            SolverLibrary(session, first=first),
            first,
        )
        self.ui.notices, self.ui.warnings, self._messages_seen = [], [], 0
        self._show_messages()
        self.ui.time_offset_s = 0.0
        if session.course_pitch_deg is not None:
            self.ui.course_pitch_deg = session.course_pitch_deg
        self.stats = Stats()
        self.nav = home_view(session, mesh)
        log.info(
            "opened %s: %d frames, sources %s", path, len(session.video.pts_s), session.sources
        )
        return True

    def close_session(self) -> None:
        if self.loaded is not None:
            self.loaded.player.close()
            self.loaded.library.close()
            self.loaded.renderer.release()
            self.loaded = None

    # --- actions (app.ui.commands calls these) -------------------------------------------------

    def apply(self, name: str, arg: str | None, now: float) -> None:
        """One action by name (the script's vocabulary; keys and panels call the same table)."""
        run_command(self, name, arg, now)

    @property
    def current_index(self) -> int:
        return self.loaded.player.index if self.loaded is not None else -1

    def set_source(self, name: str) -> None:
        self.loaded.session.check_source(name)
        self.loaded.source = name

    def toggle_ahrs(self, on: bool | None = None) -> None:
        """Switch between the AHRS and IMU forms of the current filter."""
        src = self.loaded.source
        pairs = {"gd-ahrs": "gd-imu", "cf-ahrs": "cf-imu"}
        inverse = {v: k for k, v in pairs.items()}
        if src in pairs and on is not True and pairs[src] in self.loaded.session.sources:
            self.set_source(pairs[src])
        elif src in inverse and on is not False and inverse[src] in self.loaded.session.sources:
            self.set_source(inverse[src])

    def change_speed(self, direction: int, now: float) -> None:
        clock = self.loaded.clock
        i = min(range(len(SPEEDS)), key=lambda k: abs(SPEEDS[k] - clock.speed))
        clock.set_speed(SPEEDS[int(np.clip(i + direction, 0, len(SPEEDS) - 1))], now)

    def set_time_offset(
        self, offset_s: float, drift_ppm: float = 0.0, pivot_s: float = 0.0
    ) -> None:
        """The session's time offset (s) and clock drift (ppm about session time pivot_s),
        applied by the solver library to every track."""
        self.ui.time_offset_s = offset_s
        self.loaded.library.set_time_offset(offset_s, drift_ppm, pivot_s)

    def set_course_pitch(self, pitch_deg: float) -> None:
        """A drone clip without gimbal attitude: ask the library to re-solve at this pitch."""
        if not -90.0 <= pitch_deg <= 90.0:
            raise ValueError(f"pitch must be in [-90, 90] degrees, got {pitch_deg}")
        self.ui.course_pitch_deg = pitch_deg
        self.loaded.library.set_course_pitch(pitch_deg)

    def cursor_in_view(self) -> tuple[float, float] | None:
        """The mouse cursor in [0, 1] of the 3D view (from its top-left corner), None outside."""
        if self.view_rect is None:
            return None
        x, y = self.window.cursor()
        sw, sh = self.window.size()
        fw, fh = self.window.framebuffer_size()
        vx, vy, vw, vh = self.view_rect
        fx, fy = (x * fw / max(sw, 1) - vx) / max(vw, 1), (y * fh / max(sh, 1) - vy) / max(vh, 1)
        return (fx, fy) if 0 <= fx <= 1 and 0 <= fy <= 1 else None

    def orbit_pick(self) -> None:
        """Orbit around the model point under the mouse cursor, or a point 50 m ahead when the
        cursor sees no model."""
        from app import rotations

        cam = self.window_camera
        if self.loaded is None or cam is None or self.view_rect is None:
            return
        x, y = self.window.cursor()
        sw, sh = self.window.size()
        fw, fh = self.window.framebuffer_size()
        vx, vy, vw, vh = self.view_rect
        px, py = x * fw / max(sw, 1), y * fh / max(sh, 1)
        p = self.loaded.renderer.pick(cam, (px - vx) / max(vw, 1), (py - vy) / max(vh, 1))
        if p is None:
            p = np.asarray(cam.position) + 50.0 * rotations.rotate(cam.orientation, [0, 0, -1])
        self.nav.orbit_around(p)

    # --- one frame ------------------------------------------------------------------------------

    def _show_messages(self) -> None:
        """The session's messages not shown yet, by level: information among the notices,
        warnings apart (the Session panel shows them first), errors as errors. What the solver
        thread finds arrives here too."""
        new = self.loaded.session.messages.since(self._messages_seen)
        self._messages_seen += len(new)
        for m in new:
            if m.level == ERROR:
                self.ui.error(m.text)
            elif m.level == WARNING:
                self.ui.warnings.append(m.text)
            else:
                self.ui.notices.append(m.text)

    def _update(self, now: float) -> None:
        L = self.loaded
        if L is None:
            return
        self._show_messages()
        if L.player.decoder.error:
            self.ui.error(L.player.decoder.error)
        self._apply_sync()
        wait = FIXED_CLOCK_WAIT_S if self.fixed_clock else 0.0
        if L.player.tick(now, wait_s=wait):
            f = L.player.current
            L.renderer.set_video_yuv(f.y, f.u, f.v, L.session.rotation_cw, f.bt709, f.full_range)
        lib = L.library
        k = self.current_index
        track = lib.track(L.source)
        reference = lib.reference()
        L.renderer.set_projector(track.frame_camera(k) if track is not None and k >= 0 else None)
        ref_track = lib.track(reference) if reference != L.source else None
        L.renderer.set_reference(
            ref_track.frame_camera(k) if ref_track is not None and k >= 0 else None
        )
        truth = lib.truth_track() if self.ui.overlays.error_map else None
        L.renderer.set_truth(truth.frame_camera(k) if truth is not None and k >= 0 else None)
        if track is not None and L.trajectory_version != (lib.version, L.source):
            L.renderer.set_trajectory(track.frame_poses(TRAJECTORY_STEP).enu)
            L.trajectory_version = (lib.version, L.source)

    def _draw(self) -> None:
        from app.render.renderer import BACKGROUND

        ctx = self.window.ctx
        fb_w, fb_h = self.window.framebuffer_size()
        if fb_w <= 0 or fb_h <= 0:
            return
        ctx.screen.use()
        ctx.viewport = (0, 0, fb_w, fb_h)
        ctx.clear(*BACKGROUND)
        if self.loaded is None:
            return
        x, y, w, h = self.view_rect or (0, 0, fb_w, fb_h)
        ctx.screen.viewport = (x, fb_h - y - h, w, h)  # GL counts rows from the bottom
        L = self.loaded
        self.window_camera = self.nav.camera(
            Intrinsics.from_fov(w, h, VIEW_HFOV_DEG), L.renderer.projector
        )
        for layer in L.renderer.scene.tilesets:
            layer.max_sse_px = self.ui.max_sse_px
        before = L.renderer.depth.renders
        L.renderer.draw(self.window_camera, ctx.screen, self.ui.settings, self.ui.overlays)
        self.stats.depth_redraws += L.renderer.depth.renders - before
        if L.renderer.scene.tilesets:
            self._tile_notices()
        ctx.screen.viewport = (0, 0, fb_w, fb_h)

    def screenshot(self, path: Path) -> Path:
        """The window's current back buffer (scene and panels) as PNG."""
        from app.imageio import write_rgb

        out = write_rgb(path, self.window.read_back_buffer())
        log.info("screenshot %s", out)
        return out

    def write_state(self, path: Path, now: float) -> None:
        """The state a test needs to reproduce this frame off-screen, as JSON."""
        import json

        ui = self.ui
        fb = self.window.framebuffer_size()
        state: dict = {
            "errors": ui.errors,
            "notices": ui.notices,
            "warnings": ui.warnings,
            "frames_drawn": self.stats.frames,
            "window": list(fb),
            "view_rect": list(self.view_rect or (0, 0, *fb)),
            "clock": self.clock(),
        }
        L = self.loaded
        if L is not None:
            cam = self.window_camera
            i = cam.intrinsics
            proj = L.renderer.projector
            s = L.player.stats
            state.update(
                manifest=str(L.session.path), source=L.source, lens=None if L.session.lens is None else L.session.lens.name, layers=[f"{layer.kind}:{layer.name}" for layer in L.session.layers], frame=self.current_index, due_frame=L.player.due_index(now),
                frames_shown=len(s.latencies), dropped=s.dropped, latency_ms=list(s.summary()), skipped_by_decoder=L.player.decoder.skipped,
                solved=L.library.solved(), alpha=ui.settings.alpha, time_offset_s=L.library.time_offset_s,
                registration=_registration_state(L.library.track(REGISTERED)),
                control=_control_state(ui.control),
                sync=None if ui.sync_job is None or ui.sync_job.result is None else {"offset_s": ui.sync_job.result.offset_s, "confidence": ui.sync_job.result.confidence},
                window_camera={"size": [i.width, i.height], "fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "position": list(cam.position), "orientation": list(cam.orientation), "near": cam.near, "far": cam.far},
                projector=None if proj is None else {"position": list(proj.position), "orientation": list(proj.orientation)},
                frame_ms=float(np.median(self.stats.frame_times) * 1000) if self.stats.frame_times else None,
            )  # fmt: skip
        Path(path).write_text(json.dumps(state, indent=1))

    def _run_script(self, elapsed: float, now: float) -> None:
        while self.script and self.script[0].at_s <= elapsed + 1e-9:
            a = self.script.pop(0)
            try:
                self.apply(a.name, a.arg, now)
            except (ValueError, GeofuseError) as exc:
                self.ui.error(f"script line {a.line}: {a.name}: {exc}")
            if a.name == "wait":  # on the wall clock the wait took time: later actions see it
                now = self.clock()

    def _end_of_frame(self, now: float) -> None:
        ui = self.ui
        if ui.screenshot_request is not None:
            self.screenshot(ui.screenshot_request)
            ui.screenshot_request = None
        if ui.state_request is not None:
            self.write_state(ui.state_request, now)
            ui.state_request = None
        if ui.open_request is not None:
            path, ui.open_request = ui.open_request, None
            self.open(path)

    # --- the loop -------------------------------------------------------------------------------

    def run(self) -> int:
        self.window = Window(self.options.size, self.options.visible)
        gui = Gui(self.window, config_dir() / "imgui.ini")
        self.window.on_scroll(lambda dx, dy: None if gui.wants_mouse() else self.nav.wheel(dy))
        self.window.on_drop(
            lambda paths: setattr(self.ui, "open_request", Path(paths[0])) if paths else None
        )
        if self.options.script is not None:
            try:
                self.script = parse_script(self.options.script)
            except GeofuseError as exc:
                self.ui.error(str(exc))
        opened = self.open(self.options.manifest)
        start = self.clock()
        self._run_script(0.0, start)  # clock and wait directives at 0 apply before the first frame
        start = self.clock()
        if self.loaded is not None and self.options.script is None:
            self.loaded.clock.set_paused(False, start)
        last = start
        try:
            while not self.window.should_close and not self.ui.quit:
                frame_start = (
                    time.perf_counter()
                )  # for the Stats panel only; playback uses self.clock
                now = self.clock()
                dt, last = now - last, now
                self.window.poll()
                gui.begin_frame()
                handle_input(self, gui, dt, now)
                self._run_script(now - start, now)
                self._update(now)
                self.view_rect = gui.layout(self) if self.ui.show_panels else None
                self._draw()
                panels.draw(self, gui, now)
                gui.render()
                if (
                    self.options.screenshot is not None
                    and self.options.script is None
                    and now - start >= self.options.play_seconds
                ):
                    self.ui.screenshot_request, self.ui.quit = self.options.screenshot, True
                self._end_of_frame(now)
                if self.ui.recorder is not None:
                    self.ui.recorder.add(self.window.read_back_buffer(), now)
                self.window.swap()
                shown = self.clock()
                if self.loaded is not None:
                    self.loaded.player.shown(shown, shown - now)
                self.stats.frames += 1
                self.stats.frame_times.append(time.perf_counter() - frame_start)
                del self.stats.frame_times[:-FRAME_HISTORY]
                if self.fixed_clock:
                    self.clock.advance()
        finally:
            if self.ui.recorder is not None:
                self.stop_recording()
            if self.loaded is not None:
                _, mean, p95 = self.loaded.player.stats.summary()
                log.info(
                    "latency mean %.1f ms, p95 %.1f ms, dropped %d",
                    mean,
                    p95,
                    self.loaded.player.stats.dropped,
                )
            self.close_session()
            gui.shutdown()
            self.window.close()
        if not opened and self.options.screenshot is not None and self.options.script is None:
            log.error("the session did not open: the screenshot shows the error, not a session")
            return 1
        return 0


def _registration_state(track) -> dict | None:
    """The registered source's outcome for a script's `state`: its summary and keyframe counts."""
    if track is None or track.registration is None:
        return None
    reg = track.registration
    return {
        "summary": reg.summary(),
        "keyframes": len(reg.keyframes),
        "used": reg.used,
        "prior": reg.prior,
    }


def _control_state(picks) -> dict:
    """Control points picked by hand, for a script's `state`."""
    sol = picks.solution
    return {
        "pairs": [{"frame": f, "pixel": list(uv), "enu": [float(c) for c in p]} for f, uv, p in picks.pairs],
        "pending": picks.pending is not None, "saved": picks.saved,
        "residual_px": None if sol is None else [float(r) for r in sol.residual_px],
        "boresight_deg": None if sol is None else sol.boresight_deg,
        "offset_m": None if sol is None else [float(c) for c in sol.offset_m],
    }  # fmt: skip
