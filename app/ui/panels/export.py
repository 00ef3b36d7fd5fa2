"""The Export panel: footprints, FMV CSV, KLV and video written by a child `geofuse export`, and
Record."""

from __future__ import annotations

from pathlib import Path

from imgui_bundle import imgui

from app.ui.panels.widgets import RED, colour, run, window

EXPORTS = (
    ("footprints", ".geojson"),
    ("footprints", ".kml"),
    ("footprints", ".kmz"),
    ("fmv-csv", ".csv"),
    ("klv", ".ts"),
    ("video", ".mp4"),
)


def draw(v, now: float) -> None:
    """This frame's panel (v: the Viewer; now: its clock, seconds)."""
    ui = v.ui
    if window("Export"):
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
                run(v, "export", f"{what} {ui.export_path}", now)
        elif imgui.button("Cancel"):
            job.cancel()
        if job is not None:
            imgui.progress_bar(
                job.progress, imgui.ImVec2(-1, 0), f"{job.what} {100 * job.progress:.0f} %"
            )
            if job.done:
                imgui.text_colored(colour((0.5, 1.0, 0.5, 1.0) if job.ok else RED), job.message)
        imgui.separator()
        rec = ui.recorder
        if rec is None:
            imgui.set_next_item_width(-80)
            _, ui.record_path = imgui.input_text("##record", ui.record_path)
            imgui.same_line()
            if imgui.button("Record"):
                run(v, "record", f"start {ui.record_path}", now)
        else:
            imgui.text_colored(colour(RED), f"recording {rec.out.name}: {rec.frames} frames")
            imgui.same_line()
            if imgui.button("Stop"):
                run(v, "record", "stop", now)
    imgui.end()
