"""The Stats panel: what posed the frame shown (its GNSS status under `registered`, or a stream's
as its live test says it, and the lie or outage it is in: app.ui.gnss), frame rate and time, the decode queue, latency, dropped frames,
triangles, 3D Tiles on the GPU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from app.ui import gnss
from app.ui.panels.widgets import colour, window


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    if window("Stats"):
        ft = np.asarray(v.stats.frame_times[-120:] or [0.0]) * 1000.0
        fps = 1000.0 / max(np.mean(ft), 1e-6)
        if v.live is not None:
            _live(v, fps, ft)
            imgui.end()
            return
        _gnss(v)
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
        if v.loaded.world is not None:
            imgui.text_wrapped(v.loaded.world.status())
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


def _gnss(v) -> None:
    """The frame's GNSS status in its timeline colour, and the lie or outage it is in."""
    L = v.loaded
    said_lines(gnss.frame_said(L.session, L.source, L.library.track(L.source), v.current_index))


def said_lines(said: list[tuple[str, str | None]]) -> None:
    """Lines with the GNSS status each speaks of, in its timeline colour (None: greyed)."""
    for text, status in said:
        shade = (
            imgui.get_style_color_vec4(imgui.Col_.text_disabled)
            if status is None
            else colour(gnss.COLOURS[status])
        )
        imgui.push_style_color(imgui.Col_.text, shade)
        imgui.text_wrapped(text)
        imgui.pop_style_color()


def _live(v, fps: float, ft: np.ndarray) -> None:
    """A stream's figures: the frame rate, and latency from a frame's arrival to the screen over
    the last frames shown (and what geofuse adds past the jitter buffer)."""
    run = v.live.feed.run
    imgui.text(f"frame rate {fps:6.1f} fps   frame time {np.median(ft):5.1f} ms")
    imgui.text(
        f"latency arrival -> shown  p50 {run.latency_ms(50):5.1f} ms  p95 {run.latency_ms(95):5.1f} ms"
    )
    imgui.text(
        f"past the {1000 * run.delay_s:.0f} ms jitter buffer  p50 {run.added_ms(50):5.1f} ms  p95 {run.added_ms(95):5.1f} ms"
    )
    r = v.live.renderer
    if r is not None:
        imgui.text(f"triangles drawn {r.scene_pass.triangles:,}")
    L = v.live
    said_lines(gnss.live_said(L.feed.gnss, L.feed.gnss_now, L.shown_s or 0.0))
