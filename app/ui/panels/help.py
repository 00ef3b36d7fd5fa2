"""The Help window: every key and mouse action."""

from __future__ import annotations

from imgui_bundle import imgui

from app.ui.panels.widgets import window

SHORTCUTS = (
    ("Space", "play / pause"),
    ("Left / Right", "step one frame back / forward"),
    ("[ / ]", "slower / faster (0.25x-4x)"),
    ("W A S D, Q E", "move (free roam) / move the orbit target"),
    ("right mouse drag", "look around / orbit"),
    ("mouse wheel", "roam speed / orbit distance"),
    ("O", "orbit around the point under the mouse cursor"),
    ("F", "free roam"),
    ("P", "through the phone: ride the video's camera"),
    ("R", "reset the view"),
    ("I", "AHRS / IMU toggle"),
    ("V, then M", "control point: the feature under the cursor in the video, then on the model"),
    ("L", "locate: where the point under the cursor lies (Measure panel: distances, areas, marks)"),
    ("G", "with an archive open: the clip that saw the point under the cursor, at that moment"),
    ("H or F1", "this help"),
    ("Ctrl+O, or drop a file", "open a manifest or clip"),
)


def draw(v) -> None:
    """This frame's panel (v: the Viewer)."""
    imgui.set_next_window_pos(imgui.ImVec2(360, 120), imgui.Cond_.first_use_ever)
    if window("Help"):
        for key, what in SHORTCUTS:
            imgui.text(f"{key:<22} {what}")
    imgui.end()
