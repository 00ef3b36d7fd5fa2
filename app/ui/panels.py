"""ImGui panels and keyboard/mouse handling of the viewer. Each control calls the same Viewer
methods that the script actions call (app/ui/viewer.py: Viewer.apply)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

SHORTCUTS = (
    ("Space", "play / pause"),
    ("Left / Right", "step one frame back / forward"),
    ("[ / ]", "slower / faster (0.25x-4x)"),
    ("W A S D, Q E", "move (free roam) / move the orbit target"),
    ("right mouse drag", "look around / orbit"),
    ("mouse wheel", "roam speed / orbit distance"),
    ("O", "orbit around the point under the mouse cursor"),
    ("F", "free roam"),
    ("P", "through the phone: ride the video's camera"),
    ("R", "reset the view"),
    ("I", "AHRS / IMU toggle"),
    ("H or F1", "this help"),
)
SPEEDS = (0.25, 0.5, 1.0, 1.5, 2.0, 4.0)
DEPTH_SIZES = (1024, 2048, 4096)
RED = (1.0, 0.35, 0.3, 1.0)
AMBER = (1.0, 0.8, 0.3, 1.0)


def _vec4(c):
    from imgui_bundle import imgui

    return imgui.ImVec4(*c)


# --- input ---------------------------------------------------------------------------------------

def handle_keys(v, dt: float, now: float) -> None:
    import glfw
    from imgui_bundle import imgui

    io = imgui.get_io()
    w = v.window
    if not io.want_capture_keyboard:
        def pressed(key: int) -> bool:
            state = glfw.get_key(w, key) == glfw.PRESS
            was = v.__dict__.setdefault("_keys", {}).get(key, False)
            v._keys[key] = state
            return state and not was

        if v.loaded is not None:
            clock = v.loaded.clock
            if pressed(glfw.KEY_SPACE):
                clock.set_paused(not clock.paused, now)
            if pressed(glfw.KEY_RIGHT):
                v.step(1, now)
            if pressed(glfw.KEY_LEFT):
                v.step(-1, now)
            if pressed(glfw.KEY_RIGHT_BRACKET):
                clock.set_speed(min(4.0, clock.speed * 2), now)
            if pressed(glfw.KEY_LEFT_BRACKET):
                clock.set_speed(max(0.25, clock.speed / 2), now)
            if pressed(glfw.KEY_I):
                v.toggle_ahrs()
        if pressed(glfw.KEY_O):
            orbit_pick(v)
        if pressed(glfw.KEY_F):
            v.nav.mode = "free"
        if pressed(glfw.KEY_P):
            v.nav.mode = "phone"
        if pressed(glfw.KEY_R):
            v.nav.reset()
        if pressed(glfw.KEY_H) or pressed(glfw.KEY_F1):
            v.show_help = not v.show_help
        axis = lambda plus, minus: float(glfw.get_key(w, plus) == glfw.PRESS) - float(glfw.get_key(w, minus) == glfw.PRESS)  # noqa: E731
        v.nav.move(dt, axis(glfw.KEY_W, glfw.KEY_S), axis(glfw.KEY_D, glfw.KEY_A), axis(glfw.KEY_E, glfw.KEY_Q))
    x, y = glfw.get_cursor_pos(w)
    last = v.__dict__.get("_cursor")
    v._cursor = (x, y)
    if last is not None and not io.want_capture_mouse and glfw.get_mouse_button(w, glfw.MOUSE_BUTTON_RIGHT) == glfw.PRESS:
        v.nav.look(x - last[0], y - last[1])


def orbit_pick(v) -> None:
    """Orbit around the model point under the mouse cursor (GPU position pass at a quarter of the
    window's resolution), or a point 50 m ahead when the cursor sees no model."""
    import glfw

    from app import rotations
    from app.render.positions import PositionPass

    if v.loaded is None or v.window_camera is None:
        return
    r = v.loaded.renderer
    if getattr(r, "_picker", None) is None:
        r._picker = PositionPass(v.ctx, r.scene)
    cam = v.window_camera
    w, h = max(1, cam.intrinsics.width // 4), max(1, cam.intrinsics.height // 4)
    small = type(cam).create(cam.intrinsics.scaled(w, h), cam.position, cam.orientation, cam.near, cam.far)
    win_w, win_h = glfw.get_window_size(v.window)
    x, y = glfw.get_cursor_pos(v.window)
    col = int(np.clip(x / max(win_w, 1) * w, 0, w - 1))
    row = int(np.clip(y / max(win_h, 1) * h, 0, h - 1))
    p = r._picker.render(small)[row, col]
    if not np.all(np.isfinite(p)):
        p = np.asarray(cam.position) + 50.0 * rotations.rotate(cam.orientation, [0, 0, -1])
    v.nav.orbit_around(p)


# --- panels --------------------------------------------------------------------------------------

def draw(v, now: float) -> None:
    from imgui_bundle import imgui

    imgui.new_frame()
    if not v.show_panels:
        imgui.render()
        return
    _session(v)
    if v.loaded is not None:
        _playback(v, now)
        _attitude(v)
        _projection(v)
        _error_inspection(v)
        _stats(v)
    if v.show_help:
        _help(v)
    imgui.render()


def _window(title: str, x: float, y: float, w: float = 0.0, h: float = 0.0) -> bool:
    from imgui_bundle import imgui

    imgui.set_next_window_pos(imgui.ImVec2(x, y), imgui.Cond_.first_use_ever)
    if w:
        imgui.set_next_window_size(imgui.ImVec2(w, h), imgui.Cond_.first_use_ever)
    expanded, _ = imgui.begin(title)
    return expanded


def _session(v) -> None:
    from imgui_bundle import imgui

    if _window("Session", 10, 10, 330, 165):
        if v.loaded is not None:
            s = v.loaded.session
            imgui.text(Path(s.manifest.path).name)
            imgui.text(f"{len(s.frame_times)} frames, {s.video.display_size[0]}x{s.video.display_size[1]}, rotate {s.rotation_cw}")
            imgui.text(f"declination {s.declination_deg:+.2f} deg")
            if s.scene_path is None:
                imgui.text_colored(_vec4(AMBER), "no scene: the ground is assumed (flat, 1 m grid)")
        _, v.open_path = imgui.input_text("manifest", v.open_path)
        imgui.same_line()
        if imgui.button("Open") and v.open_path.strip():
            v.open(Path(v.open_path.strip()))
        for note in v.notices[-4:]:
            imgui.text_wrapped(f"note: {note}")
        if v.errors:
            imgui.separator()
            imgui.text_colored(_vec4(RED), f"{len(v.errors)} error(s):")
            for e in v.errors[-5:]:
                imgui.push_text_wrap_pos(320)
                imgui.text_colored(_vec4(RED), e)
                imgui.pop_text_wrap_pos()
            if imgui.button("Clear errors"):
                v.errors.clear()
        imgui.text_disabled("H: help and shortcuts")
    imgui.end()


def _playback(v, now: float) -> None:
    import glfw
    from imgui_bundle import imgui

    L = v.loaded
    _, fb_h = glfw.get_window_size(v.window)
    fb_w, _ = glfw.get_window_size(v.window)
    if _window("Timeline", 350, max(10, fb_h - 110), max(400, fb_w - 360), 95):
        clock = L.clock
        if imgui.button("Pause" if not clock.paused else "Play"):
            clock.set_paused(not clock.paused, now)
        imgui.same_line()
        if imgui.button("<"):
            v.step(-1, now)
        imgui.same_line()
        if imgui.button(">"):
            v.step(1, now)
        imgui.same_line()
        imgui.set_next_item_width(80)
        idx = SPEEDS.index(clock.speed) if clock.speed in SPEEDS else 2
        changed, idx = imgui.combo("speed", idx, [f"{s:g}x" for s in SPEEDS])
        if changed:
            clock.set_speed(SPEEDS[idx], now)
        imgui.same_line()
        _, clock.loop = imgui.checkbox("loop", clock.loop)
        imgui.same_line()
        media = clock.time(now)
        imgui.text(f"{media:7.2f} / {clock.duration:.2f} s   frame {max(v.current_index, 0)}")
        imgui.set_next_item_width(-1)
        changed, t = imgui.slider_float("##scrub", media, 0.0, clock.duration, "%.2f s")
        if changed:
            v.seek(t, now)  # dragging scrubs
        if imgui.is_item_deactivated_after_edit():
            v.seek(t, now)  # release: show the exact frame
    imgui.end()


def _attitude(v) -> None:
    from imgui_bundle import imgui

    L = v.loaded
    if _window("Attitude", 10, 180, 330, 215):
        lib = L.tracks
        if not lib.done:
            imgui.progress_bar(lib.progress, imgui.ImVec2(-1, 0), f"solving {len(lib.tracks)}/{len(lib.order)}")
        for name in L.session.filters:
            label = name + ("" if name in lib.tracks else " (solving)" if name not in lib.errors else " (failed)")
            if imgui.radio_button(label, L.source == name) and name in lib.tracks:
                v.set_source(name)
        for name, err in lib.errors.items():
            imgui.text_colored(_vec4(RED), f"{name}: {err}")
        ahrs = L.source.endswith("-ahrs")
        if L.source[:3] in ("gd-", "cf-"):
            changed, ahrs = imgui.checkbox("AHRS (with magnetometer)", ahrs)
            if changed:
                v.toggle_ahrs(ahrs)
        if L.session.heading_note:
            imgui.text_colored(_vec4(AMBER), L.session.heading_note)
        if "course" in L.session.references:
            current = float(v.__dict__.setdefault("_course_pitch", -30.0))
            _, pitch = imgui.slider_float("camera pitch (deg)", current, -90.0, 30.0, "%.0f")
            v._course_pitch = pitch
            if imgui.is_item_deactivated_after_edit():
                v.set_course_pitch(pitch)
        elif L.session.mag is None:
            imgui.text_colored(_vec4(AMBER), "no magnetometer: IMU filters only")
        elif not L.source.endswith("-ahrs") and L.source[:3] in ("gd-", "cf-"):
            imgui.text_wrapped("IMU heading anchored to the compass's mean over the clip")
    imgui.end()


def _projection(v) -> None:
    from imgui_bundle import imgui

    if _window("Projection", 10, 400, 330, 310):
        s = v.settings
        _, enabled = imgui.checkbox("project the video", s.enabled)
        _, alpha = imgui.slider_float("transparency", s.alpha, 0.0, 1.0, "%.2f")
        _, bias = imgui.slider_float("depth bias (m)", s.bias_constant_m, 0.0, 1.0, "%.2f")
        _, slope = imgui.slider_float("slope bias (texels)", s.bias_slope, 0.0, 8.0, "%.1f")
        _, rule = imgui.checkbox("nine-case neighbourhood rule", s.neighbourhood)
        idx = DEPTH_SIZES.index(s.depth_long_side) if s.depth_long_side in DEPTH_SIZES else 1
        _, idx = imgui.combo("depth map", idx, [str(d) for d in DEPTH_SIZES])
        v.settings = replace(s, enabled=enabled, alpha=alpha, bias_constant_m=bias, bias_slope=slope, neighbourhood=rule, depth_long_side=DEPTH_SIZES[idx])
        o = v.overlays
        _, fr = imgui.checkbox("frustum", o.frustum)
        imgui.same_line()
        _, tr = imgui.checkbox("trajectory", o.trajectory)
        v.overlays = replace(o, frustum=fr, trajectory=tr)
        if v.loaded is not None and "truth" in v.loaded.session.filters:
            _, em = imgui.checkbox("projection error on the model (m)", v.overlays.error_map)
            _, scale = imgui.slider_float("error scale (m)", v.overlays.error_scale_m, 0.5, 20.0, "%.1f")
            v.overlays = replace(v.overlays, error_map=em, error_scale_m=scale)
            if em:
                for frac, colour in ((0.0, (0.10, 0.80, 0.25, 1.0)), (0.5, (1.00, 0.85, 0.10, 1.0)), (1.0, (0.90, 0.10, 0.10, 1.0))):
                    imgui.color_button(f"##legend{frac}", imgui.ImVec4(*colour), 0, imgui.ImVec2(14, 14))
                    imgui.same_line()
                    imgui.text(f"{frac * scale:.1f} m" + (" and more" if frac == 1.0 else ""))
                    if frac < 1.0:
                        imgui.same_line()
        else:
            imgui.text_disabled("projection error: needs a session with ground truth")
        _, v.time_offset_s = imgui.slider_float("time offset (s)", v.time_offset_s, -1.0, 1.0, "%+.3f")
    imgui.end()


def _error_inspection(v) -> None:
    import glfw
    from imgui_bundle import imgui, implot

    L = v.loaded
    lib = L.tracks
    ref = lib.reference()
    fb_w, _ = glfw.get_window_size(v.window)
    if _window("Error inspection", max(350, fb_w - 460), 10, 450, 430):
        if ref is None:
            imgui.text_wrapped("This session has no reference attitude (phone or truth) to compare with.")
        elif L.source in lib.curves and ref in lib.curves:
            est, truth = lib.curves[L.source], lib.curves[ref]
            k = max(v.current_index, 0)
            d = ((est.hpr[k] - truth.hpr[k]) + 180.0) % 360.0 - 180.0
            imgui.text(f"{L.source} vs {ref}, this frame: heading {d[0]:+.2f}, pitch {d[1]:+.2f}, roll {d[2]:+.2f} deg")
            step = max(1, len(est.t) // 1500)
            for i, label in enumerate(("heading", "pitch", "roll")):
                if implot.begin_plot(f"{label} (deg)##{i}", imgui.ImVec2(-1, 95)):
                    implot.setup_axes("", "", implot.AxisFlags_.no_tick_labels if i < 2 else 0, 0)
                    wrap = (lambda a: (a + 180.0) % 360.0 - 180.0) if i == 0 else (lambda a: a)  # noqa: E731
                    ys_est = np.ascontiguousarray(wrap(est.hpr[::step, i]))
                    ys_ref = np.ascontiguousarray(wrap(truth.hpr[::step, i]))
                    xs = np.ascontiguousarray(est.t[::step])
                    implot.plot_line(L.source, xs, ys_est)
                    implot.plot_line(ref, xs, ys_ref)
                    implot.plot_inf_lines("now", np.array([est.t[k]]))
                    implot.end_plot()
        table = lib.rms_table()
        if table and imgui.begin_table("rms", 5, imgui.TableFlags_.borders):
            for h in ("RMS vs " + str(ref), "heading", "pitch", "roll", "total"):
                imgui.table_setup_column(h)
            imgui.table_headers_row()
            for row in table:
                imgui.table_next_row()
                for j, cell in enumerate(row):
                    imgui.table_next_column()
                    imgui.text(cell if j == 0 else f"{cell:.2f}")
            imgui.end_table()
    imgui.end()


def _stats(v) -> None:
    import glfw
    from imgui_bundle import imgui

    L = v.loaded
    fb_w, _ = glfw.get_window_size(v.window)
    if _window("Stats", max(350, fb_w - 460), 450, 450, 0):
        ft = np.asarray(v.stats.frame_times[-120:] or [0.0]) * 1000.0
        fps = 1000.0 / max(np.mean(ft), 1e-6)
        player = L.player
        current, mean, p95 = player.stats.summary()
        imgui.text(f"frame rate {fps:6.1f} fps   frame time {np.median(ft):5.1f} ms")
        imgui.text(f"decode queue {player.decoder.frames.qsize()}/{player.decoder.frames.maxsize}   corrupt packets {player.decoder.corrupt_packets}")
        imgui.text(f"latency now {current:5.1f} ms  mean {mean:5.1f} ms  p95 {p95:5.1f} ms")
        imgui.text(f"dropped frames {player.stats.dropped}   depth redraws {v.stats.depth_redraws}")
    imgui.end()


def _help(v) -> None:
    from imgui_bundle import imgui

    if _window("Help", 360, 120, 420, 0):
        for key, what in SHORTCUTS:
            imgui.text(f"{key:<18} {what}")
    imgui.end()

