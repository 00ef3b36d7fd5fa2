"""The Measure panel: what lies under the cursor, the picks' distances and areas, and the marks
kept beside the input."""

from __future__ import annotations

from imgui_bundle import imgui

from app.ui import measure
from app.ui.panels.widgets import AMBER, colour, run, window


def draw(v, now: float) -> None:
    """Point, measure and mark: the last pick's coordinates, the measurement, the marks."""

    state = v.ui.measure
    if state.focus:
        imgui.set_next_window_focus()
        state.focus = False
    if window("Measure"):
        imgui.text_wrapped(
            "L over the draped video or the model picks a point; picks make a line or a polygon."
        )
        _, state.hover_on = imgui.checkbox("read the point under the cursor", state.hover_on)
        if state.hover is not None:
            imgui.text_colored(colour(AMBER), f"under the cursor: {measure.readout(state.hover)}")
        for kind in ("point", "line", "polygon"):
            if imgui.radio_button(kind, state.kind == kind):
                run(v, "measure", kind)
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
                imgui.text_colored(colour(AMBER), "on the model, not in the video")
            imgui.text_wrapped(measure.summary(v))
            if imgui.button("Undo"):
                run(v, "measure", "undo")
            imgui.same_line()
            if imgui.button("Clear"):
                run(v, "measure", "clear")
            _, state.label = imgui.input_text("label", state.label)
            imgui.same_line()
            if imgui.button("Mark"):
                run(v, "measure", f"mark {state.label}")
        for i, m in enumerate(state.marks, start=1):
            if imgui.small_button(f"Go##{i}"):
                run(v, "measure", f"goto {i}", now)
            imgui.same_line()
            if imgui.small_button(f"x##{i}"):
                run(v, "measure", f"delete {i}")
            imgui.same_line()
            imgui.text(f"{i}. {m.label} ({m.kind}, frame {m.frame}, {m.media_s:.2f} s)")
        if state.saved:
            imgui.text_wrapped(f"kept in {state.saved}")
    imgui.end()
