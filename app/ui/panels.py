"""The viewer's ImGui panels (Session, Timeline, Attitude, Projection, Error inspection, Stats,
Export, Help). Every control runs the same commands as the script (app.ui.commands) or the same
Viewer methods; the docked layout is app.ui.gui's, keys and mouse app.ui.inputs'.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
from imgui_bundle import imgui, implot

from app.core.errors import GeofuseError
from app.playback.clock import SPEEDS
from app.register.solve import keyframe_plot
from app.session.model import COURSE, REGISTERED
from app.sync import rate_reference
from app.ui import measure
from app.ui.gui import Gui
from app.ui.inputs import open_dialog, poll_dialog

log = logging.getLogger("geofuse.viewer")

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
    ("V, then M", "control point: the feature under the cursor in the video, then on the model"),
    ("L", "locate: where the point under the cursor lies (Measure panel: distances, areas, marks)"),
    ("G", "with an archive open: the clip that saw the point under the cursor, at that moment"),
    ("H or F1", "this help"),
    ("Ctrl+O, or drop a file", "open a manifest or clip"),
)
DEPTH_SIZES = (1024, 2048, 4096)
RED = (1.0, 0.35, 0.3, 1.0)
AMBER = (1.0, 0.8, 0.3, 1.0)
EXPORTS = (
    ("footprints", ".geojson"),
    ("footprints", ".kml"),
    ("footprints", ".kmz"),
    ("fmv-csv", ".csv"),
    ("klv", ".ts"),
    ("video", ".mp4"),
)


def _vec4(c):

    return imgui.ImVec4(*c)


# --- panels --------------------------------------------------------------------------------------


def draw(v, gui: Gui, now: float) -> None:
    """The panels of this frame (after `Gui.begin_frame` and `Gui.layout`)."""
    poll_dialog(v)
    if not v.ui.show_panels:
        return
    _session(v)
    if v.loaded is not None:
        _playback(v, now)
        _attitude(v)
        _projection(v)
        _error_inspection(v)
        _stats(v)
        _export(v, now)
        _measure(v, now)
    if v.ui.show_help:
        _help(v)


def _window(title: str) -> bool:

    expanded, _ = imgui.begin(title)
    return expanded


def _run(v, name: str, arg: str | None, now: float = 0.0) -> None:

    try:
        v.apply(name, arg, now)
    except (ValueError, GeofuseError) as exc:
        v.ui.error(f"{name}: {exc}")


def _session(v) -> None:

    ui = v.ui
    if ui.show_session_tab > 0:
        ui.show_session_tab -= 1
        if (
            ui.show_session_tab == 0
        ):  # once the docks exist: the first tab, whatever was docked last
            imgui.set_next_window_focus()
    if _window("Session"):
        if v.loaded is not None:
            s = v.loaded.session
            imgui.text(Path(s.path).name)
            imgui.text(
                f"{len(s.frame_times)} frames, {s.video.display_size[0]}x{s.video.display_size[1]}, rotate {s.rotation_cw}"
            )
            imgui.text(f"declination {s.declination_deg:+.2f} deg")
            if s.scene_path is None:
                imgui.text_colored(_vec4(AMBER), "no scene: the ground is assumed (flat, 1 m grid)")
            for layer in s.layers:
                imgui.text_wrapped(
                    f"layer: {layer.name} ({layer.kind}"
                    + (f", draped with {layer.ortho.name}" if layer.ortho is not None else "")
                    + ")"
                )
            lens = s.lens
            imgui.text_wrapped(
                f"lens: {lens.kind}, {lens.name or 'profile'}"
                if lens is not None
                else f"lens: pinhole, {s.intrinsics.hfov_deg:.1f} deg across"
            )
            if Path(s.path).suffix.lower() != ".toml":
                imgui.set_next_item_width(-100)
                _, ui.lens_path = imgui.input_text("##lens", ui.lens_path)
                imgui.same_line()
                if imgui.button("Use lens") and ui.lens_path.strip():
                    _run(v, "lens", ui.lens_path.strip())
        if v.loaded is not None:
            _clips(v)
        if imgui.button("Open..."):
            open_dialog(v)
        imgui.same_line()
        imgui.set_next_item_width(-60)
        _, ui.open_path = imgui.input_text("##path", ui.open_path)
        imgui.same_line()
        if imgui.button("Open") and ui.open_path.strip():
            ui.open_request = Path(ui.open_path.strip())
        for warning in ui.warnings[-6:]:
            imgui.text_colored(_vec4(AMBER), "warning:")
            imgui.same_line()
            imgui.text_wrapped(warning)
        for note in ui.info[-4:]:
            imgui.text_disabled("note:")
            imgui.same_line()
            imgui.text_wrapped(note)
        if ui.errors:
            imgui.separator()
            imgui.text_colored(_vec4(RED), f"{len(ui.errors)} error(s):")
            imgui.push_text_wrap_pos(0.0)
            for e in ui.errors[-5:]:
                imgui.text_colored(_vec4(RED), e)
            imgui.pop_text_wrap_pos()
            if imgui.button("Clear errors"):
                ui.errors.clear()
        imgui.text_disabled("H: help and shortcuts; drop a file here to open it")
    imgui.end()


def _clips(v) -> None:
    """Further clips on the timeline: each shown or hidden, with its offset and its span."""
    L = v.loaded
    if not L.others:
        return
    imgui.separator()
    imgui.text(f"{1 + len(L.others)} clips on one timeline ({L.timeline.duration_s:.1f} s)")
    for i, (clip, span) in enumerate(zip(L.others, L.timeline.clips[1:]), start=1):
        changed, on = imgui.checkbox(f"{Path(clip.session.video.path).name}##clip{i}", clip.visible)
        if changed:
            _run(v, "clip", f"{i} {'on' if on else 'off'}")
        imgui.same_line()
        imgui.text_disabled(
            f"{span.start_s:.1f}-{span.end_s:.1f} s" + (" (UTC)" if span.absolute else "")
        )
        imgui.color_button(f"##colour{i}", _vec4(clip.colour))
        imgui.same_line()
        imgui.set_next_item_width(120)
        changed, offset = imgui.input_float(f"offset s##clip{i}", clip.offset_s, 0.1, 1.0, "%.2f")
        if changed:
            _run(v, "clip", f"{i} offset {offset}")
        imgui.set_next_item_width(120)
        alpha = v.ui.settings.alpha if clip.alpha is None else clip.alpha
        changed, alpha = imgui.slider_float(f"opacity##clip{i}", alpha, 0.0, 1.0)
        if changed:
            _run(v, "clip", f"{i} alpha {alpha}")
        sources = clip.session.sources
        imgui.set_next_item_width(120)
        changed, k = imgui.combo(f"source##clip{i}", sources.index(clip.source), sources)
        if changed:
            _run(v, "clip", f"{i} source {sources[k]}")


def _playback(v, now: float) -> None:

    if _window("Timeline"):
        clock = v.loaded.clock
        if imgui.button("Pause" if not clock.paused else "Play"):
            _run(v, "toggle", None, now)
        imgui.same_line()
        if imgui.button("<"):
            _run(v, "step", "-1", now)
        imgui.same_line()
        if imgui.button(">"):
            _run(v, "step", "1", now)
        imgui.same_line()
        imgui.set_next_item_width(80)
        idx = SPEEDS.index(clock.speed) if clock.speed in SPEEDS else SPEEDS.index(1.0)
        changed, idx = imgui.combo("speed", idx, [f"{s:g}x" for s in SPEEDS])
        if changed:
            _run(v, "speed", str(SPEEDS[idx]), now)
        imgui.same_line()
        _, clock.loop = imgui.checkbox("loop", clock.loop)
        imgui.same_line()
        media = clock.time(now)
        imgui.text(f"{media:7.2f} / {clock.duration:.2f} s   frame {max(v.current_index, 0)}")
        imgui.set_next_item_width(-1)
        changed, t = imgui.slider_float("##scrub", media, 0.0, clock.duration, "%.2f s")
        if changed or imgui.is_item_deactivated_after_edit():
            _run(v, "seek", str(t), now)  # dragging scrubs; release shows the exact frame
        _spans(v)
    imgui.end()


def _spans(v) -> None:
    """Each further clip's span under the slider, on the first clip's media time: a bar over the
    part of the timeline where it shows a frame, and what it shows now."""
    L = v.loaded
    if not L.others:
        return
    first = L.timeline.clips[0]
    shift = first.start_s - float(L.session.video.pts_s[0])  # timeline - media time of the first
    width = imgui.get_content_region_avail().x
    for clip, span in zip(L.others, L.timeline.clips[1:]):
        lo = max(0.0, (span.start_s - shift) / max(L.clock.duration, 1e-9))
        hi = min(1.0, (span.end_s - shift) / max(L.clock.duration, 1e-9))
        imgui.dummy(imgui.ImVec2(max(0.0, lo) * width, 4))
        imgui.same_line(0.0, 0.0)
        imgui.push_style_color(imgui.Col_.plot_histogram, _vec4(clip.colour))
        imgui.progress_bar(1.0, imgui.ImVec2(max(1.0, (hi - lo) * width), 6), "")
        imgui.pop_style_color()
        imgui.same_line()
        shown = (
            "hidden"
            if not clip.visible
            else ("no frame" if clip.frame is None else f"frame {clip.frame}")
        )
        imgui.text_disabled(f"{Path(clip.session.video.path).name}: {shown}")


def _attitude(v) -> None:

    L = v.loaded
    if _window("Attitude"):
        lib = L.library
        solved, errors = lib.solved(), lib.errors()
        if not lib.done:
            imgui.progress_bar(
                lib.progress, imgui.ImVec2(-1, 0), f"solving {len(solved)}/{len(lib.order)}"
            )
        for name in L.session.sources:
            partly = lib.source_progress(name)
            solving = " (solving)" if partly is None else f" (registering {100 * partly:.0f} %)"
            label = name + ("" if name in solved else " (failed)" if name in errors else solving)
            if imgui.radio_button(label, L.source == name) and name in solved:
                _run(v, "source", name)
        for name, err in errors.items():
            imgui.text_colored(_vec4(RED), f"{name}: {err}")
        registered = lib.track(REGISTERED)
        if registered is not None and registered.registration is not None:
            imgui.text_wrapped(registered.registration.summary())
        ahrs = L.source.endswith("-ahrs")
        if L.source[:3] in ("gd-", "cf-") and L.session.mag is not None:
            changed, ahrs = imgui.checkbox("AHRS (with magnetometer)", ahrs)
            if changed:
                _run(v, "ahrs", "on" if ahrs else "off")
        if L.session.heading_note:
            imgui.text_colored(_vec4(AMBER), L.session.heading_note)
        if COURSE in L.session.sources:
            _, v.ui.course_pitch_deg = imgui.slider_float(
                "camera pitch (deg)", v.ui.course_pitch_deg, -90.0, 30.0, "%.0f"
            )
            if imgui.is_item_deactivated_after_edit():
                _run(v, "pitch", str(v.ui.course_pitch_deg))
        elif L.session.mag is None:
            imgui.text_colored(_vec4(AMBER), "no magnetometer: IMU filters only")
        elif not L.source.endswith("-ahrs") and L.source[:3] in ("gd-", "cf-"):
            imgui.text_wrapped("IMU heading anchored to the compass's mean over the clip")
    imgui.end()


def _projection(v) -> None:

    ui = v.ui
    if _window("Projection"):
        s = ui.settings
        _, enabled = imgui.checkbox("project the video", s.enabled)
        _, alpha = imgui.slider_float("transparency", s.alpha, 0.0, 1.0, "%.2f")
        _, bias = imgui.slider_float("depth bias (m)", s.bias_constant_m, 0.0, 1.0, "%.2f")
        _, slope = imgui.slider_float("slope bias (texels)", s.bias_slope, 0.0, 8.0, "%.1f")
        _, rule = imgui.checkbox("nine-case neighbourhood rule", s.neighbourhood)
        idx = DEPTH_SIZES.index(s.depth_long_side) if s.depth_long_side in DEPTH_SIZES else 1
        _, idx = imgui.combo("depth map", idx, [str(d) for d in DEPTH_SIZES])
        if v.loaded is not None and v.loaded.renderer.scene.tilesets:
            _, ui.max_sse_px = imgui.slider_float(
                "3D Tiles detail (px error)", ui.max_sse_px, 1.0, 64.0, "%.0f"
            )
        ui.settings = replace(
            s,
            enabled=enabled,
            alpha=alpha,
            bias_constant_m=bias,
            bias_slope=slope,
            neighbourhood=rule,
            depth_long_side=DEPTH_SIZES[idx],
        )
        o = ui.overlays
        _, fr = imgui.checkbox("frustum", o.frustum)
        imgui.same_line()
        _, tr = imgui.checkbox("trajectory", o.trajectory)
        ui.overlays = replace(o, frustum=fr, trajectory=tr)
        if v.loaded is not None and "truth" in v.loaded.session.sources:
            _, em = imgui.checkbox("projection error on the model (m)", ui.overlays.error_map)
            _, scale = imgui.slider_float(
                "error scale (m)", ui.overlays.error_scale_m, 0.5, 20.0, "%.1f"
            )
            ui.overlays = replace(ui.overlays, error_map=em, error_scale_m=scale)
            if em:
                for frac, colour in (
                    (0.0, (0.10, 0.80, 0.25, 1.0)),
                    (0.5, (1.00, 0.85, 0.10, 1.0)),
                    (1.0, (0.90, 0.10, 0.10, 1.0)),
                ):
                    imgui.color_button(
                        f"##legend{frac}", imgui.ImVec4(*colour), 0, imgui.ImVec2(14, 14)
                    )
                    imgui.same_line()
                    imgui.text(f"{frac * scale:.1f} m" + (" and more" if frac == 1.0 else ""))
                    if frac < 1.0:
                        imgui.same_line()
        else:
            imgui.text_disabled("projection error: needs a session with ground truth")
        if v.loaded is not None:
            imgui.set_next_item_width(-110)
            _, ui.time_offset_s = imgui.slider_float(
                "##offset", ui.time_offset_s, -1.0, 1.0, "offset %+.3f s"
            )
            if imgui.is_item_deactivated_after_edit():
                _run(v, "offset", str(ui.time_offset_s))
            imgui.same_line()
            job = ui.sync_job
            if (
                rate_reference(v.loaded.session) is not None
                and (job is None or job.done)
                and imgui.button("Sync")
            ):
                _run(v, "sync", None)
            _sync_curves(ui.sync_job)
            _control_points(v)
    imgui.end()


def _control_points(v) -> None:
    """Control points by hand: how to pick, the pairs with their residuals, Solve and Clear."""

    picks = v.ui.control
    if not imgui.collapsing_header(f"Control points ({len(picks.pairs)})"):
        return
    imgui.text_wrapped(
        "Hover a feature in the draped video and press V, then the same feature on the model and press M (lower the transparency to see the model). Four pairs or more."
    )
    if picks.pending is not None:
        imgui.text_colored(
            _vec4(AMBER),
            f"video pixel {picks.pending[1][0]:.0f}, {picks.pending[1][1]:.0f} of frame {picks.pending[0]}: now the model (M)",
        )
    sol = picks.solution
    for i, (frame, uv, _) in enumerate(picks.pairs):
        res = (
            f": {sol.residual_px[i]:.1f} px, {sol.residual_m[i]:.2f} m"
            if sol is not None and i < len(sol.residual_px)
            else ""
        )
        imgui.text(f"{i + 1}. frame {frame}, pixel {uv[0]:.0f}, {uv[1]:.0f}{res}")
    if len(picks.pairs) >= 4 and imgui.button("Solve"):
        _run(v, "control", "solve")
    imgui.same_line()
    if picks.pairs and imgui.button("Clear"):
        _run(v, "control", "clear")
    if sol is not None:
        imgui.text_wrapped(
            f"boresight {sol.boresight_deg:.2f} deg, position correction {np.linalg.norm(sol.offset_m):.2f} m; kept in {picks.saved}; registering again"
        )


def _sync_curves(job) -> None:
    """The sync's progress, then the two rate curves before and after the offset."""

    if job is None:
        return
    if not job.done:
        imgui.progress_bar(job.progress, imgui.ImVec2(-1, 0), "optical flow")
        return
    if job.error:
        imgui.text_colored(_vec4(RED), job.error)
        return
    r = job.result
    imgui.text(f"sync: {1000 * r.offset_s:+.1f} ms, confidence {r.confidence:.2f}")
    curves = job.curves()
    if curves and implot.begin_plot("rotation rate (rad/s)##sync", imgui.ImVec2(-1, 110)):
        for label, (t, y) in curves.items():
            implot.plot_line(label, np.ascontiguousarray(t), np.ascontiguousarray(y))
        implot.end_plot()


def _error_inspection(v) -> None:

    L = v.loaded
    lib = L.library
    ref = lib.reference()
    if _window("Error inspection"):
        est, truth = lib.curves(L.source), lib.curves(ref)
        if ref is None:
            imgui.text_disabled("no reference attitude (phone or truth) to compare with")
        elif est is not None and truth is not None and L.source != ref:
            k = max(v.current_index, 0)
            d = ((est.hpr[k] - truth.hpr[k]) + 180.0) % 360.0 - 180.0
            imgui.text_wrapped(
                f"{L.source} vs {ref}, this frame: heading {d[0]:+.2f}, pitch {d[1]:+.2f}, roll {d[2]:+.2f} deg"
            )
            step = max(1, len(est.t) // 1500)
            for i, label in enumerate(("heading", "pitch", "roll")):
                if implot.begin_plot(f"{label} (deg)##{i}", imgui.ImVec2(-1, 90)):
                    implot.setup_axes("", "", implot.AxisFlags_.no_tick_labels if i < 2 else 0, 0)
                    wrap = (lambda a: (a + 180.0) % 360.0 - 180.0) if i == 0 else (lambda a: a)  # noqa: E731
                    xs = np.ascontiguousarray(est.t[::step])
                    implot.plot_line(L.source, xs, np.ascontiguousarray(wrap(est.hpr[::step, i])))
                    implot.plot_line(ref, xs, np.ascontiguousarray(wrap(truth.hpr[::step, i])))
                    implot.plot_inf_lines("now", np.array([est.t[k]]))
                    implot.end_plot()
        _keyframes(v, lib)
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


def _keyframes(v, lib) -> None:
    """The registered source's keyframes over time: inliers of those used and of those not, the
    reprojection error, and why the nearest keyframe to this frame was not used."""

    track = lib.track(REGISTERED)
    if track is None or track.registration is None:
        return
    plot = keyframe_plot(track.registration, float(track.clock.session_s[0]))
    imgui.text_wrapped(track.registration.summary())
    if implot.begin_plot("keyframes: inliers##reg", imgui.ImVec2(-1, 110)):
        implot.setup_axes("", "", 0, 0)
        for label, (xs, ys) in (("used", plot.used), ("not used", plot.unused)):
            if len(xs):
                implot.plot_scatter(label, xs, ys)
        if len(plot.error_t):
            implot.plot_line("error (px x 100)", plot.error_t, plot.error_px * 100.0)
        implot.plot_inf_lines(
            "now",
            np.array(
                [float(track.clock.session_s[max(v.current_index, 0)] - track.clock.session_s[0])]
            ),
        )
        implot.end_plot()
    near = plot.nearest(max(v.current_index, 0))
    if near is not None and not near.used:
        imgui.text_colored(_vec4(AMBER), f"keyframe {near.index}: {near.reason}")


def _stats(v) -> None:

    if _window("Stats"):
        ft = np.asarray(v.stats.frame_times[-120:] or [0.0]) * 1000.0
        fps = 1000.0 / max(np.mean(ft), 1e-6)
        player = v.loaded.player
        current, mean, p95 = player.stats.summary()
        imgui.text(f"frame rate {fps:6.1f} fps   frame time {np.median(ft):5.1f} ms")
        imgui.text(
            f"decode queue {player.decoder.frames.qsize()}/{player.decoder.frames.maxsize}   corrupt packets {player.decoder.corrupt_packets}"
        )
        imgui.text(f"latency now {current:5.1f} ms  mean {mean:5.1f} ms  p95 {p95:5.1f} ms")
        imgui.text(
            f"dropped frames {player.stats.dropped} (decoder skipped {player.decoder.skipped})   depth redraws {v.stats.depth_redraws}"
        )
        r = v.loaded.renderer
        imgui.text(
            f"triangles drawn {r.scene_pass.triangles:,}   in the depth map {r.depth.triangles:,}"
        )
        for layer in r.scene.tilesets:
            s = layer.stream
            skipped = ", ".join(f"{n} {k}" for k, n in s.skipped.snapshot().items())
            imgui.text_wrapped(
                f"{Path(layer.tileset.location.rstrip('/')).name}: {len(layer.resident)} tiles on the GPU ({layer.bytes_held / 2**20:.0f} MB of {layer.cache_bytes / 2**20:.0f}), "
                f"{s.pending} loading, {s.failures} failed"
                + (f"; skipped {skipped}" if skipped else "")
            )
    imgui.end()


def _export(v, now: float) -> None:

    ui = v.ui
    if _window("Export"):
        labels = [f"{what} ({suffix})" for what, suffix in EXPORTS]
        _, ui.export_what = imgui.combo("format", ui.export_what, labels)
        what, suffix = EXPORTS[ui.export_what]
        default = str(Path("out") / f"{Path(v.loaded.session.path).stem}-{what}{suffix}")
        imgui.set_next_item_width(-60)
        _, ui.export_path = imgui.input_text("##export", ui.export_path or default)
        if not ui.export_path.lower().endswith(suffix):
            ui.export_path = str(Path(ui.export_path).with_suffix(suffix))
        imgui.same_line()
        job = ui.export_job
        if job is None or job.done:
            if imgui.button("Export"):
                _run(v, "export", f"{what} {ui.export_path}", now)
        elif imgui.button("Cancel"):
            job.cancel()
        if job is not None:
            imgui.progress_bar(
                job.progress, imgui.ImVec2(-1, 0), f"{job.what} {100 * job.progress:.0f} %"
            )
            if job.done:
                imgui.text_colored(_vec4((0.5, 1.0, 0.5, 1.0) if job.ok else RED), job.message)
        imgui.separator()
        rec = ui.recorder
        if rec is None:
            imgui.set_next_item_width(-80)
            _, ui.record_path = imgui.input_text("##record", ui.record_path)
            imgui.same_line()
            if imgui.button("Record"):
                _run(v, "record", f"start {ui.record_path}", now)
        else:
            imgui.text_colored(_vec4(RED), f"recording {rec.out.name}: {rec.frames} frames")
            imgui.same_line()
            if imgui.button("Stop"):
                _run(v, "record", "stop", now)
    imgui.end()


def _measure(v, now: float) -> None:
    """Point, measure and mark: the last pick's coordinates, the measurement, the marks."""

    state = v.ui.measure
    if state.focus:
        imgui.set_next_window_focus()
        state.focus = False
    if _window("Measure"):
        imgui.text_wrapped(
            "L over the draped video or the model picks a point; picks make a line or a polygon."
        )
        _, state.hover_on = imgui.checkbox("read the point under the cursor", state.hover_on)
        if state.hover is not None:
            imgui.text_colored(_vec4(AMBER), f"under the cursor: {measure.readout(state.hover)}")
        for kind in ("point", "line", "polygon"):
            if imgui.radio_button(kind, state.kind == kind):
                _run(v, "measure", kind)
            imgui.same_line()
        imgui.new_line()
        if state.picks:
            last = state.picks[-1]
            lat, lon, h, msl = measure.geodetic(v, last)
            imgui.text(f"{lat:.7f}, {lon:.7f}")
            imgui.text(f"{h:.2f} m ellipsoidal, {msl:.2f} m above sea level")
            loc = last.location
            if loc is not None:
                unc = "" if loc.uncertainty_m is None else f", +-{loc.uncertainty_m:.2f} m"
                imgui.text(f"range {loc.range_m:.2f} m from the camera{unc}")
            else:
                imgui.text_colored(_vec4(AMBER), "on the model, not in the video")
            imgui.text_wrapped(measure.summary(v))
            if imgui.button("Undo"):
                _run(v, "measure", "undo")
            imgui.same_line()
            if imgui.button("Clear"):
                _run(v, "measure", "clear")
            _, state.label = imgui.input_text("label", state.label)
            imgui.same_line()
            if imgui.button("Mark"):
                _run(v, "measure", f"mark {state.label}")
        for i, m in enumerate(state.marks, start=1):
            if imgui.small_button(f"Go##{i}"):
                _run(v, "measure", f"goto {i}", now)
            imgui.same_line()
            if imgui.small_button(f"x##{i}"):
                _run(v, "measure", f"delete {i}")
            imgui.same_line()
            imgui.text(f"{i}. {m.label} ({m.kind}, frame {m.frame}, {m.media_s:.2f} s)")
        if state.saved:
            imgui.text_wrapped(f"kept in {state.saved}")
    imgui.end()


def _help(v) -> None:

    imgui.set_next_window_pos(imgui.ImVec2(360, 120), imgui.Cond_.first_use_ever)
    if _window("Help"):
        for key, what in SHORTCUTS:
            imgui.text(f"{key:<22} {what}")
    imgui.end()
