"""What the panels share: their colours for warnings and errors, the ImGui window they draw
into, and running one of the viewer's commands with its error shown rather than raised."""

from __future__ import annotations

from imgui_bundle import imgui

from app.core.errors import GeofuseError

RED = (1.0, 0.35, 0.3, 1.0)
AMBER = (1.0, 0.8, 0.3, 1.0)


def colour(c: tuple[float, float, float, float]) -> imgui.ImVec4:
    """An RGBA tuple (0..1) as ImGui takes it."""
    return imgui.ImVec4(*c)


def window(title: str) -> bool:
    """Begin the docked window `title`; True when it is expanded (draw its contents)."""
    expanded, _ = imgui.begin(title)
    return expanded


def run(v, name: str, arg: str | None, now: float = 0.0) -> None:
    """The viewer's command `name` (app.ui.commands) with `arg`; a refusal is shown, not raised."""
    try:
        v.apply(name, arg, now)
    except (ValueError, GeofuseError) as exc:
        v.ui.error(f"{name}: {exc}")
