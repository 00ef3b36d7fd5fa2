"""The Memory panel: paint what the clips saw onto the scene (rule newest, best or first), and
show the scene as the Model, the Memory, when each part was seen or what changed since the model,
as it was at the timeline's moment (app.ui.memory)."""

from __future__ import annotations

import datetime as dt

from imgui_bundle import imgui

from app.export.memory import RULES
from app.export.memory_view import RAMP
from app.ui.panels.widgets import RED, colour, run, window

LABELS = {"model": "Model", "memory": "Memory", "seen": "Seen at", "changed": "Changed"}


def draw(v, now: float) -> None:
    """This frame's panel (v: the Viewer; now: its clock, seconds)."""
    ui, L = v.ui, v.loaded
    if window("Memory"):
        imgui.text_wrapped("What the clips saw, kept on the model's surfaces.")
        _, ui.memory_rule = imgui.combo("keep", ui.memory_rule, list(RULES))
        p = L.memory
        if imgui.button("Paint" if p is None else "Paint again"):
            run(v, "memory", f"paint {RULES[ui.memory_rule]}", now)
        if p is not None:
            imgui.same_line()
            imgui.progress_bar(
                p.progress, imgui.ImVec2(-1, 0), f"{p.frames_painted} of {p.frames_total} frames"
            )
        for k, (view, label) in enumerate(LABELS.items()):
            if k:
                imgui.same_line()
            if imgui.radio_button(label, ui.memory_view == view):
                run(v, "memory", view, now)
        if p is None:
            imgui.text_disabled("nothing painted yet")
        elif p.error:
            imgui.text_colored(colour(RED), p.error)
        else:
            _details(v, p)
    imgui.end()


def _details(v, p) -> None:
    if p.boxes is not None and p.page_stats is not None:
        s, scene = p.page_stats, v.loaded.renderer.scene
        imgui.text_wrapped(
            f"in pages: {s.made:,} of {s.pages:,} painted ({p.memory.texel_m:.2f} m finest), "
            f"{p.nbytes / 1e6:.0f} MB held, {s.evicted} spilled to disk, {s.reloaded} read back; "
            f"{len(scene.memory_pages)} on the GPU ({scene.memory_pages_bytes / 1e6:.0f} MB); "
            f"{len(p.clips)} clip(s), rule {p.rule}"
        )
    elif p.atlas is not None and p.memory is not None:
        mb = p.nbytes / 1e6
        imgui.text_wrapped(
            f"{len(p.atlas.points):,} surface samples at {p.atlas.texel_m:.2f} m, {mb:.0f} MB; "
            f"{len(p.clips)} clip(s), rule {p.rule}"
        )
    view = v.ui.memory_view
    if view == "seen" and p.range_s is not None:
        t0, t1 = p.range_s
        for k, (_, r, g, b) in enumerate(RAMP):
            if k:
                imgui.same_line()
            imgui.color_button(f"##ramp{k}", imgui.ImVec4(r / 255, g / 255, b / 255, 1.0), 0, imgui.ImVec2(14, 14))  # fmt: skip
        imgui.same_line()
        imgui.text(f"{_when(v, t0)} .. {_when(v, t1)}")
    elif view == "changed":
        if not any(prim.textured for prim in v.loaded.session.scene().primitives):
            imgui.text_disabled("the model has no texture: compared with its flat colours")
        imgui.text_wrapped("red: the video differs from the model's own colour")


def _when(v, t: float) -> str:
    """A timeline time as UTC clock time where the timeline has a clock, else seconds."""
    utc0 = v.loaded.timeline.utc0
    if utc0 is None:
        return f"{t:.1f} s"
    return dt.datetime.fromtimestamp(utc0 + t, dt.UTC).strftime("%H:%M:%S")
