"""The Projection panel: transparency, depth bias and map size, the nine-case rule, overlays and
the error map, the time offset with Sync (its rate curves), and control points by hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from imgui_bundle import imgui, implot

from app.sync import rate_reference
from app.ui.panels.widgets import AMBER, RED, colour, run, window

DEPTH_SIZES = (1024, 2048, 4096)


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    ui = v.ui
    if window("Projection"):
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
                run(v, "offset", str(ui.time_offset_s))
            imgui.same_line()
            job = ui.sync_job
            if (
                rate_reference(v.loaded.session) is not None
                and (job is None or job.done)
                and imgui.button("Sync")
            ):
                run(v, "sync", None)
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
            colour(AMBER),
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
        run(v, "control", "solve")
    imgui.same_line()
    if picks.pairs and imgui.button("Clear"):
        run(v, "control", "clear")
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
        imgui.text_colored(colour(RED), job.error)
        return
    r = job.result
    imgui.text(f"sync: {1000 * r.offset_s:+.1f} ms, confidence {r.confidence:.2f}")
    curves = job.curves()
    if curves and implot.begin_plot("rotation rate (rad/s)##sync", imgui.ImVec2(-1, 110)):
        for label, (t, y) in curves.items():
            implot.plot_line(label, np.ascontiguousarray(t), np.ascontiguousarray(y))
        implot.end_plot()
