"""The Timeline panel: play, pause, step, speed, loop, the scrubber (under `registered`, a band
along its bottom coloured by what posed each frame: app.ui.gnss), and each further clip's span."""

from __future__ import annotations

from pathlib import Path

from imgui_bundle import imgui

from app.playback.clock import SPEEDS
from app.ui import gnss
from app.ui.panels.widgets import colour, run, window

BAND_PX = 4.0  # the GNSS band's height along the scrubber's bottom edge


def draw(v, now: float) -> None:
    """This frame's panel (v: the Viewer; now: its clock, seconds)."""
    if window("Timeline"):
        clock = v.loaded.clock
        if imgui.button("Pause" if not clock.paused else "Play"):
            run(v, "toggle", None, now)
        imgui.same_line()
        if imgui.button("<"):
            run(v, "step", "-1", now)
        imgui.same_line()
        if imgui.button(">"):
            run(v, "step", "1", now)
        imgui.same_line()
        imgui.set_next_item_width(80)
        idx = SPEEDS.index(clock.speed) if clock.speed in SPEEDS else SPEEDS.index(1.0)
        changed, idx = imgui.combo("speed", idx, [f"{s:g}x" for s in SPEEDS])
        if changed:
            run(v, "speed", str(SPEEDS[idx]), now)
        imgui.same_line()
        _, clock.loop = imgui.checkbox("loop", clock.loop)
        imgui.same_line()
        media = clock.time(now)
        imgui.text(f"{media:7.2f} / {clock.duration:.2f} s   frame {max(v.current_index, 0)}")
        imgui.set_next_item_width(-1)
        changed, t = imgui.slider_float("##scrub", media, 0.0, clock.duration, "%.2f s")
        if changed or imgui.is_item_deactivated_after_edit():
            run(v, "seek", str(t), now)  # dragging scrubs; release shows the exact frame
        _gnss_band(v)
        _spans(v)
    imgui.end()


def _gnss_band(v) -> None:
    """Along the scrubber (the last item drawn) a band of the frames' GNSS status under the
    registered source; where it lies kept in v.ui.gnss_band (framebuffer pixels)."""
    shown = gnss.shown(v.loaded)
    v.ui.gnss_band = None if shown is None else band(shown.runs, v.loaded.clock.duration)


def band(runs: tuple[gnss.Run, ...], duration: float) -> tuple[float, float, float, float]:
    """Along the last item drawn (a scrubber over media time 0..duration s) a band of the
    frames' GNSS status (green used, red rejected, grey missing), each run's colour under the
    grab's position at its times; where it lies (x at 0 and at duration, top and bottom y;
    framebuffer pixels). The live panel draws a stream's along its scrubber too."""
    lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
    grab = imgui.get_style().grab_min_size
    y0, y1 = hi.y - 1.0 - BAND_PX, hi.y - 1.0
    draw = imgui.get_window_draw_list()
    for r in runs:
        xa = gnss.slider_x(r.start_s, duration, lo.x, hi.x, grab)
        xb = gnss.slider_x(r.end_s, duration, lo.x, hi.x, grab)
        draw.add_rect_filled(
            imgui.ImVec2(xa, y0),
            imgui.ImVec2(max(xb, xa + 1.0), y1),
            imgui.get_color_u32(colour(gnss.COLOURS[r.status])),
        )
    if imgui.is_item_hovered():
        imgui.set_tooltip(
            "GNSS per frame: green used, red rejected (it disagrees with the scene or the IMU), grey missing"
        )
    scale = imgui.get_io().display_framebuffer_scale
    return (
        gnss.slider_x(0.0, duration, lo.x, hi.x, grab) * scale.x,
        gnss.slider_x(duration, duration, lo.x, hi.x, grab) * scale.x,
        y0 * scale.y,
        y1 * scale.y,
    )


def _spans(v) -> None:
    """Each further clip's span under the slider, on the first clip's media time: a bar over the
    part of the timeline where it shows a frame, and what it shows now."""
    L = v.loaded
    if not L.others:
        return
    first = L.timeline.clips[0]
    shift = first.start_s - float(L.session.video.pts_s[0])  # timeline - media time of the first
    width = imgui.get_content_region_avail().x
    for clip, span in zip(L.others, L.timeline.clips[1:], strict=True):
        lo = max(0.0, (span.start_s - shift) / max(L.clock.duration, 1e-9))
        hi = min(1.0, (span.end_s - shift) / max(L.clock.duration, 1e-9))
        imgui.dummy(imgui.ImVec2(max(0.0, lo) * width, 4))
        imgui.same_line(0.0, 0.0)
        imgui.push_style_color(imgui.Col_.plot_histogram, colour(clip.colour))
        imgui.progress_bar(1.0, imgui.ImVec2(max(1.0, (hi - lo) * width), 6), "")
        imgui.pop_style_color()
        imgui.same_line()
        shown = (
            "hidden"
            if not clip.visible
            else ("no frame" if clip.frame is None else f"frame {clip.frame}")
        )
        imgui.text_disabled(f"{Path(clip.session.video.path).name}: {shown}")
