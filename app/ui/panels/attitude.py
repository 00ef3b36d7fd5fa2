"""The Attitude panel: the pose source (filters, recorded, course, registered) with each one's
solving state and the heading note."""

from __future__ import annotations

from imgui_bundle import imgui

from app.session.model import COURSE, REGISTERED
from app.ui.panels.widgets import AMBER, RED, colour, run, window


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    L = v.loaded
    if window("Attitude"):
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
                run(v, "source", name)
        for name, err in errors.items():
            imgui.text_colored(colour(RED), f"{name}: {err}")
        registered = lib.track(REGISTERED)
        if registered is not None and registered.registration is not None:
            imgui.text_wrapped(registered.registration.summary())
        ahrs = L.source.endswith("-ahrs")
        if L.source[:3] in ("gd-", "cf-") and L.session.mag is not None:
            changed, ahrs = imgui.checkbox("AHRS (with magnetometer)", ahrs)
            if changed:
                run(v, "ahrs", "on" if ahrs else "off")
        if L.session.heading_note:
            imgui.text_colored(colour(AMBER), L.session.heading_note)
        if COURSE in L.session.sources:
            _, v.ui.course_pitch_deg = imgui.slider_float(
                "camera pitch (deg)", v.ui.course_pitch_deg, -90.0, 30.0, "%.0f"
            )
            if imgui.is_item_deactivated_after_edit():
                run(v, "pitch", str(v.ui.course_pitch_deg))
        elif L.session.mag is None:
            imgui.text_colored(colour(AMBER), "no magnetometer: IMU filters only")
        elif not L.source.endswith("-ahrs") and L.source[:3] in ("gd-", "cf-"):
            imgui.text_wrapped("IMU heading anchored to the compass's mean over the clip")
    imgui.end()
