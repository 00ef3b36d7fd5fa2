"""The interactive viewer: a window (app.render.window) with the fusion renderer and ImGui panels.

The frame loop pulls: each tick it reads its clock (injected: the wall clock, or a fixed-step
clock a script sets), advances playback to the frame due, asks the session's camera track for
that frame's camera (app.session.camera_track: the one place a pose for display is computed), updates
the projector (the depth map is redrawn only when the pose changed), draws the scene into the 3D
view's rectangle and the panels around it, and records each frame's playback latency (due time ->
first display, as the paper defines it). When drawing is slower than the video, frames are
dropped and counted (app.playback.player, app.playback.decoder), so the frame shown stays the one
due. A bad file never crashes it: the error panel says what is wrong and the viewer keeps running.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.errors import GeofuseError
from app.core.imageio import write_rgb
from app.core.paths import config_dir
from app.geodesy import rotations
from app.live.feed import LiveOptions
from app.locate.marks import measure as measure_points
from app.playback.clock import SPEEDS
from app.render.context import describe
from app.render.renderer import BACKGROUND
from app.render.window import Window
from app.session.model import REGISTERED
from app.session.start import StartArea
from app.ui import clips, credit, gnss, live, measure, memory, panels, share, world
from app.ui.commands import run_command
from app.ui.gui import Gui
from app.ui.inputs import handle_input
from app.ui.jobs import ViewerJobs
from app.ui.navigation import Navigator
from app.ui.script import Action, parse_script
from app.ui.sessions import Loaded, Stats, ViewerSessions
from app.ui.state import UiState

log = logging.getLogger("geofuse.viewer")
TRAJECTORY_STEP = 5  # frames between trajectory polyline vertices
VIEW_HFOV_DEG = 60.0  # the window camera's horizontal field of view
FIXED_CLOCK_WAIT_S = 30.0  # on a fixed-step clock, wait this long at most for a decoded frame
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
    more: tuple = ()  # further clips (paths) played with the first on one timeline
    stream: str | None = None  # a stream URL to receive instead of a file (app.ui.live)
    live: LiveOptions | None = None  # its options (MAVLink, field of view, buffer, origin)
    sinks: tuple = ()  # where the shown frames are shared (app.ui.share: makers of sinks)
    start: StartArea | None = None  # where the clip begins without any GNSS fix (--near)

    @property
    def gnss_accuracy_m(self) -> float | None:
        """--gnss-accuracy (m): the accuracy of the fixes that state none, for every clip."""
        return None if self.live is None else self.live.gnss_accuracy_m


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


class Viewer(ViewerJobs, ViewerSessions):
    def __init__(self, options: Options, clock: Callable[[], float] = time.perf_counter) -> None:
        self.options = options
        self.clock = clock
        self.loaded: Loaded | None = None
        self.live: live.LiveView | None = None  # an open stream instead of a session
        self.ui = UiState()
        self.share = share.ViewerShare(list(options.sinks))
        self.nav = Navigator()
        self.stats = Stats()
        self.script: list[Action] = []
        self._hold: tuple | None = None  # a script action waiting for a condition the loop meets
        self._script_shift = 0.0  # seconds the script was held for
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

    def set_tile_detail(self, max_sse_px: float) -> None:
        """3D Tiles refine where their screen-space error exceeds max_sse_px (1..256 px)."""
        if not 1.0 <= max_sse_px <= 256.0:
            raise ValueError(f"expected 1..256 pixels, got {max_sse_px:g}")
        self.ui.max_sse_px = float(max_sse_px)

    # --- actions (app.ui.commands calls these) -------------------------------------------------

    def apply(self, name: str, arg: str | None, now: float) -> None:
        """One action by name (the script's vocabulary; keys and panels call the same table)."""
        run_command(self, name, arg, now)

    @property
    def current_index(self) -> int:
        return self.loaded.player.index if self.loaded is not None else -1

    def set_source(self, name: str) -> None:
        """Show the pose source `name`: the user's choice, kept from then on (the viewer no
        longer switches to `registered` by itself once it is solved)."""
        self.loaded.session.check_source(name)
        self.loaded.source = name
        self.loaded.source_chosen = True

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

    def open_input(self, text: str) -> bool:
        """Open what was typed or given: a stream URL (received live), else a file or folder."""
        if live.is_stream(text):
            live.open_stream(self, text, self.options.live)
            return True
        return self.open(Path(text), background=True)

    def _update(self, now: float) -> None:
        self.poll_open()
        if self.live is not None:
            live.update(self)
            share.update(self)
            return
        L = self.loaded
        if L is None:
            return
        world.update(self)
        self._show_messages()
        self._prefer_registered()
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
        clips.update(self, now, wait)
        memory.update(self)
        ref_track = lib.track(reference) if reference != L.source else None
        L.renderer.set_reference(
            ref_track.frame_camera(k) if ref_track is not None and k >= 0 else None
        )
        truth = lib.truth_track() if self.ui.overlays.error_map else None
        L.renderer.set_truth(truth.frame_camera(k) if truth is not None and k >= 0 else None)
        if track is not None and L.trajectory_version != (lib.version, L.source):
            L.renderer.set_trajectory(track.frame_poses(TRAJECTORY_STEP).enu)
            fixes = gnss.fix_lines(L.session, track)
            L.renderer.set_fixes(*((None,) if fixes is None else (fixes.used, fixes.rejected)))
            L.trajectory_version = (lib.version, L.source)
        share.update(self)

    def _draw(self) -> None:
        fb_w, fb_h = self.window.clear(BACKGROUND)
        if fb_w <= 0 or fb_h <= 0:
            return
        rect = self.view_rect or (0, 0, fb_w, fb_h)
        if self.live is not None and self.live.renderer is not None:
            r = self.live.renderer
            self.window_camera = self.nav.camera(
                Intrinsics.from_fov(rect[2], rect[3], VIEW_HFOV_DEG), r.projector
            )
            with self.window.region(rect) as screen:
                r.draw(self.window_camera, screen, self.ui.settings, self.ui.overlays)
            return
        if self.loaded is None:
            return
        L = self.loaded
        self.window_camera = self.nav.camera(
            Intrinsics.from_fov(rect[2], rect[3], VIEW_HFOV_DEG), L.renderer.projector
        )
        for layer in L.renderer.scene.tilesets:
            layer.max_sse_px = self.ui.max_sse_px
        before = L.renderer.depth.renders
        with self.window.region(rect) as screen:
            L.renderer.draw(self.window_camera, screen, self.ui.settings, self.ui.overlays)
        if L.renderer.scene_pass.left_out_message:
            self.ui.error(L.renderer.scene_pass.left_out_message + " (hide a clip to choose which)")
        self.stats.depth_redraws += L.renderer.depth.renders - before
        if L.renderer.scene.tilesets:
            self._tile_messages()

    def screenshot(self, path: Path) -> Path:
        """The window's current back buffer (scene and panels) as PNG."""

        out = write_rgb(path, self.window.read_back_buffer())
        log.info("screenshot %s", out)
        return out

    def write_state(self, path: Path, now: float) -> None:
        """The state a test needs to reproduce this frame off-screen, as JSON."""

        ui = self.ui
        fb = self.window.framebuffer_size()
        state: dict = {
            "live": None if self.live is None else live.state(self),
            "window_camera": _camera_state(self.window_camera),
            "errors": ui.errors,
            "info": ui.info,
            "warnings": ui.warnings,
            "frames_drawn": self.stats.frames,
            "window": list(fb),
            "view_rect": list(self.view_rect or (0, 0, *fb)),
            "clock": self.clock(),
            "opening": None if ui.opening is None else str(ui.opening.path),
        }
        L = self.loaded
        if L is not None:
            cam = self.window_camera
            proj = L.renderer.projector
            s = L.player.stats
            state.update(
                manifest=str(L.session.path), source=L.source, lens=None if L.session.lens is None else L.session.lens.name, layers=[f"{layer.kind}:{layer.name}" for layer in L.session.layers], frame=self.current_index, due_frame=L.player.due_index(now),
                frames_shown=len(s.latencies), dropped=s.dropped, latency_ms=list(s.summary()), skipped_by_decoder=L.player.decoder.skipped,
                solved=L.library.solved(), failed=L.library.errors(), alpha=ui.settings.alpha, time_offset_s=L.library.time_offset_s,
                registration=_registration_state(L.library.track(REGISTERED)), gnss=gnss.state(L, self.current_index, ui.gnss_band),
                control=_control_state(ui.control), measure=_measure_state(ui.measure),
                clips=[{"name": Path(c.session.video.path).name, "visible": c.visible, "frame": c.frame, "decoder": c.player is not None, "offset_s": c.offset_s, "start_s": s.start_s, "source": c.source, "alpha": c.alpha, "frames_shown": 0 if c.player is None else len(c.player.stats.latencies), "dropped": 0 if c.player is None else c.player.stats.dropped, "latency_ms": None if c.player is None else list(c.player.stats.summary())} for c, s in zip(L.others, L.timeline.clips[1:], strict=True)],
                extra_projectors=len(L.renderer.extras), frame_ages_s=[L.renderer.projector_age, *(e.age_s for e in L.renderer.extras)], timeline_s=None if self.current_index < 0 else float(L.timeline.clips[0].times[self.current_index]),
                archive=None if ui.archive is None else {"path": str(ui.archive.path), "footprints": ui.archive.footprints, "clips": ui.archive.clips, "picked": ui.archive.picked, "opened": ui.archive.opened, "opened_s": ui.archive.opened_s},
                memory=memory.state(L), memory_view=ui.memory_view, world=world.state(L), credit=credit.text(L),
                sync=None if ui.sync_job is None or ui.sync_job.result is None else {"offset_s": ui.sync_job.result.offset_s, "confidence": ui.sync_job.result.confidence},
                window_camera=_camera_state(cam),
                projector=None if proj is None else {"position": list(proj.position), "orientation": list(proj.orientation)},
                frame_ms=float(np.median(self.stats.frame_times) * 1000) if self.stats.frame_times else None,
                frame_p95_ms=float(np.percentile(self.stats.frame_times, 95) * 1000) if self.stats.frame_times else None,
                gl=describe(self.window.ctx),
            )  # fmt: skip
        Path(path).write_text(json.dumps(state, indent=1))

    def hold_script(self, until: Callable[[], bool], what: str, limit_s: float) -> None:
        """Hold the script (not the frame loop: what it waits for is drawn by the loop) until
        `until()` holds, or limit_s real seconds have gone (said as an error); the actions after
        it keep their spacing from the moment it is released."""
        self._hold = (until, what, time.perf_counter() + limit_s, None)

    def _held(self, elapsed: float) -> bool:
        until, what, deadline, since = self._hold
        if since is None:
            self._hold = (until, what, deadline, elapsed)
            since = elapsed
        done = until()
        if not done and time.perf_counter() < deadline:
            return True
        if not done:
            self.ui.error(f"script: gave up waiting for {what}")
        self._script_shift += elapsed - since
        self._hold = None
        return False

    def _run_script(self, elapsed: float, now: float) -> None:
        while self.script or self._hold is not None:
            if self._hold is not None and self._held(elapsed):
                return
            if not self.script or self.script[0].at_s > elapsed - self._script_shift + 1e-9:
                return
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
            self.open_input(str(path))

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
        if self.options.stream is not None:
            live.open_stream(self, self.options.stream, self.options.live)
            opened = True
        else:
            opened = self.open(self.options.manifest)
        for path in self.options.more if opened and self.live is None else ():
            try:
                clips.add(self, Path(path))
            except GeofuseError as exc:
                self.ui.error(str(exc))
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
                measure.hover(self, now, gui.wants_mouse())
                panels.draw(self, gui, now)
                credit.draw(self)  # the providers' credit over the 3D view, panels or not
                gui.render()
                if (
                    self.options.screenshot is not None
                    and self.options.script is None
                    and now - start >= self.options.play_seconds
                    and world.drawn(self.loaded)  # a world being built: once drawn in full
                ):
                    self.ui.screenshot_request, self.ui.quit = self.options.screenshot, True
                self._end_of_frame(now)
                if self.ui.recorder is not None:
                    self.ui.recorder.add(self.window.read_back_buffer(), now)
                self.window.swap()
                shown = self.clock()
                live.swapped(self)
                if self.loaded is not None:
                    self.loaded.player.shown(shown, shown - now)
                    for clip in self.loaded.others:
                        if clip.player is not None and clip.frame is not None:
                            clip.player.shown(shown, shown - now)
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
            share.close(self.share)
            share.stop_web(self)
            live.close(self)
            self.close_session()
            gui.shutdown()
            self.window.close()
        if not opened and self.options.screenshot is not None and self.options.script is None:
            log.error("the session did not open: the screenshot shows the error, not a session")
            return 1
        return 0


def _camera_state(cam: Camera | None) -> dict | None:
    """The window camera for a script's `state`: intrinsics and pose (ENU m, camera -> ENU)."""
    if cam is None:
        return None
    i = cam.intrinsics
    return {
        "size": [i.width, i.height], "fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy,
        "position": list(map(float, cam.position)), "orientation": list(map(float, cam.orientation)),
        "near": cam.near, "far": cam.far,
    }  # fmt: skip


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


def _measure_state(state) -> dict:
    """Point, measure and mark for a script's `state`: the picks (ENU m, and as the video sees
    them), the summary's figures, the marks and where they are kept."""
    m = measure_points(state.points())
    return {
        "kind": state.kind,
        "picks": [
            {"enu": list(map(float, p.enu)), "frame": p.frame, "location": None if p.location is None else p.location.as_dict()}
            for p in state.picks
        ],
        "straight_m": m.straight_m, "ground_m": m.ground_m, "height_m": m.height_m, "area_m2": m.area_m2,
        "marks": [{"label": k.label, "kind": k.kind, "frame": k.frame, "media_s": k.media_s, "points": np.asarray(k.points).tolist()} for k in state.marks],
        "saved": state.saved,
    }  # fmt: skip
