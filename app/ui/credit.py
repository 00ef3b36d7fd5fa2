"""The credit line a scene's providers require (a world's imagery and heights, its buildings:
app.scene.layers.scene_credit), drawn in the bottom-right corner of the 3D view on a dark band,
with the panels shown or hidden, so that screenshots and recordings carry it as the licences
ask; a script's `state` says it ("credit"). A world's credit shows once its tiles are drawn
(not while the flat ground stands in for it).
"""

from __future__ import annotations

from collections.abc import Callable

from imgui_bundle import imgui

from app.scene.layers import scene_credit

MARGIN_PX = 4.0  # between the band and the view's edges (ImGui units)
PAD_PX = 3.0  # between the text and the band's edges
BAND = (0.0, 0.0, 0.0, 0.6)
TEXT = (1.0, 1.0, 1.0, 0.92)
MIN_WIDTH_PX = 40.0  # narrower views still get a band this wide


def text(loaded) -> str:
    """The open session's credit (loaded: app.ui.sessions.Loaded, or None): its layers', a
    world's only once drawn; '' for none."""
    if loaded is None:
        return ""
    layers = [layer for layer in loaded.session.layers if layer.kind != "world"]
    w = loaded.world
    if w is not None and w.shown is not None:
        layers += list(w.shown.layers)
    return scene_credit(layers)


def wrap(line: str, width: float, measure: Callable[[str], float]) -> list[str]:
    """`line` broken between words into lines at most `width` wide as `measure` measures
    them (a word wider than that stands alone on its line)."""
    out: list[str] = []
    for word in line.split():
        if out and measure(out[-1] + " " + word) <= width:
            out[-1] += " " + word
        else:
            out.append(word)
    return out


def shown(v) -> str:
    """The credit over the viewer's 3D view (v: the Viewer): the open session's (text), or an
    open stream's layers' once its scene is built around the first position."""
    if v.live is not None:
        return scene_credit(v.options.layers) if v.live.mesh is not None else ""
    return text(v.loaded)


def draw(v) -> None:
    """This frame's credit over the 3D view (v: the Viewer), between the panels and render."""
    credit = shown(v)
    if not credit or v.window is None:
        return
    scale = imgui.get_io().display_framebuffer_scale
    sx, sy = max(scale.x, 1e-6), max(scale.y, 1e-6)
    fb_w, fb_h = v.window.framebuffer_size()
    x, y, w, h = v.view_rect or (0, 0, fb_w, fb_h)
    right, bottom = (x + w) / sx - MARGIN_PX, (y + h) / sy - MARGIN_PX
    width = max(MIN_WIDTH_PX, w / sx - 2.0 * (MARGIN_PX + PAD_PX))
    lines = wrap(credit, width, lambda s: imgui.calc_text_size(s).x)
    line_h = imgui.get_text_line_height()
    box_w = max(imgui.calc_text_size(s).x for s in lines) + 2.0 * PAD_PX
    left, top = right - box_w, bottom - len(lines) * line_h - 2.0 * PAD_PX
    draw_list = imgui.get_foreground_draw_list(imgui.get_main_viewport())
    draw_list.add_rect_filled(
        imgui.ImVec2(left, top),
        imgui.ImVec2(right, bottom),
        imgui.get_color_u32(imgui.ImVec4(*BAND)),
    )
    colour = imgui.get_color_u32(imgui.ImVec4(*TEXT))
    for i, line in enumerate(lines):
        draw_list.add_text(imgui.ImVec2(left + PAD_PX, top + PAD_PX + i * line_h), colour, line)
