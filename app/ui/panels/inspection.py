"""The Error inspection panel: heading, pitch and roll against the reference, the RMS table, this
frame's error, and the registered keyframes over time."""

from __future__ import annotations

import numpy as np
from imgui_bundle import imgui, implot

from app.register.solve import keyframe_plot
from app.session.model import REGISTERED
from app.ui.panels.widgets import AMBER, colour, window


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    L = v.loaded
    lib = L.library
    ref = lib.reference()
    if window("Error inspection"):
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
        imgui.text_colored(colour(AMBER), f"keyframe {near.index}: {near.reason}")
