"""The Session panel: the session and its scene, further clips (show, hide, offset, opacity,
source), open a manifest or clip, and the messages, warnings first."""

from __future__ import annotations

from pathlib import Path

from imgui_bundle import imgui

from app.ui.inputs import open_dialog
from app.ui.panels import share
from app.ui.panels.widgets import AMBER, RED, colour, run, window


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    ui = v.ui
    if ui.show_session_tab > 0:
        ui.show_session_tab -= 1
        if (
            ui.show_session_tab == 0
        ):  # once the docks exist: the first tab, whatever was docked last
            imgui.set_next_window_focus()
    if window("Session"):
        if ui.opening is not None:
            imgui.text_colored(colour(AMBER), f"opening {Path(ui.opening.path).name} ...")
        if v.live is not None:
            _stream(v)
        if v.loaded is not None:
            s = v.loaded.session
            imgui.text(Path(s.path).name)
            imgui.text(
                f"{len(s.frame_times)} frames, {s.video.display_size[0]}x{s.video.display_size[1]}, rotate {s.rotation_cw}"
            )
            imgui.text(f"declination {s.declination_deg:+.2f} deg")
            if s.scene_path is None:
                imgui.text_colored(
                    colour(AMBER), "no scene: the ground is assumed (flat, 1 m grid)"
                )
            for layer in s.layers:
                imgui.text_wrapped(
                    f"layer: {layer.name} ({layer.kind}"
                    + (f", draped with {layer.ortho.name}" if layer.ortho is not None else "")
                    + ")"
                    + (f"; imagery and heights: {layer.attribution}" if layer.attribution else "")
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
                    run(v, "lens", ui.lens_path.strip())
        if v.loaded is not None:
            _clips(v)
        if imgui.button("Open..."):
            open_dialog(v)
        imgui.same_line()
        imgui.set_next_item_width(-60)
        _, ui.open_path = imgui.input_text("##path", ui.open_path)
        imgui.same_line()
        if imgui.button("Open") and ui.open_path.strip():
            ui.open_request = ui.open_path.strip()  # a file, or a stream's URL
        imgui.set_next_item_width(-110)
        _, ui.stream_url = imgui.input_text("##stream", ui.stream_url)
        imgui.same_line()
        if imgui.button("Open stream") and ui.stream_url.strip():
            run(v, "open", ui.stream_url.strip())
        share.draw(v)
        for warning in ui.warnings[-6:]:
            imgui.text_colored(colour(AMBER), "warning:")
            imgui.same_line()
            imgui.text_wrapped(warning)
        for note in ui.info[-4:]:
            imgui.text_disabled("note:")
            imgui.same_line()
            imgui.text_wrapped(note)
        if ui.errors:
            imgui.separator()
            imgui.text_colored(colour(RED), f"{len(ui.errors)} error(s):")
            imgui.push_text_wrap_pos(0.0)
            for e in ui.errors[-5:]:
                imgui.text_colored(colour(RED), e)
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
    for i, (clip, span) in enumerate(zip(L.others, L.timeline.clips[1:], strict=True), start=1):
        changed, on = imgui.checkbox(f"{Path(clip.session.video.path).name}##clip{i}", clip.visible)
        if changed:
            run(v, "clip", f"{i} {'on' if on else 'off'}")
        imgui.same_line()
        imgui.text_disabled(
            f"{span.start_s:.1f}-{span.end_s:.1f} s" + (" (UTC)" if span.absolute else "")
        )
        imgui.color_button(f"##colour{i}", colour(clip.colour))
        imgui.same_line()
        imgui.set_next_item_width(120)
        changed, offset = imgui.input_float(f"offset s##clip{i}", clip.offset_s, 0.1, 1.0, "%.2f")
        if changed:
            run(v, "clip", f"{i} offset {offset}")
        imgui.set_next_item_width(120)
        alpha = v.ui.settings.alpha if clip.alpha is None else clip.alpha
        changed, alpha = imgui.slider_float(f"opacity##clip{i}", alpha, 0.0, 1.0)
        if changed:
            run(v, "clip", f"{i} alpha {alpha}")
        sources = clip.session.sources
        imgui.set_next_item_width(120)
        changed, k = imgui.combo(f"source##clip{i}", sources.index(clip.source), sources)
        if changed:
            run(v, "clip", f"{i} source {sources[k]}")


def _stream(v) -> None:
    """The open stream: where it comes from, what has arrived, where it is recorded."""
    L = v.live
    run = L.run
    imgui.text_wrapped(run.url)
    if L.renderer is None:
        imgui.text_colored(colour(AMBER), "waiting for video and a first pose...")
    silent = L.feed.silent_for(L.feed.clock(), L.opened_s)
    if silent > 2.0:
        imgui.text_colored(colour(AMBER), f"nothing has arrived for {silent:.0f} s")
    if run.mavlink is not None:
        imgui.text_wrapped(f"poses: MAVLink {run.mavlink.address}")
    imgui.text_wrapped(f"recording in {L.folder}/ (rolling segments, each a clip)")
    if imgui.button("Close stream"):
        run_close(v)
    imgui.separator()


def run_close(v) -> None:
    run(v, "live", "close")
