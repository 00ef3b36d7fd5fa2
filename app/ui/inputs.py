"""The viewer's keyboard and mouse: keys run the same commands as a script (app.ui.commands),
WASD/QE and the right mouse button navigate; Ctrl+O and the Session panel's button open the
system's file dialog, polled each frame."""

from __future__ import annotations

from pathlib import Path

import glfw
from imgui_bundle import portable_file_dialogs as pfd

from app.core.errors import GeofuseError
from app.ui.gui import Gui

OPEN_FILTERS = [
    "Sessions and clips",
    "*.toml *.TOML *.mp4 *.MP4 *.mov *.MOV *.ts *.TS",
    "All files",
    "*",
]
KEY_COMMANDS = {  # key name in glfw -> (command, argument)
    "KEY_SPACE": ("toggle", None), "KEY_RIGHT": ("step", "1"), "KEY_LEFT": ("step", "-1"),
    "KEY_RIGHT_BRACKET": ("faster", None), "KEY_LEFT_BRACKET": ("slower", None), "KEY_I": ("ahrs", None),
    "KEY_O": ("view", "orbit"), "KEY_F": ("view", "free"), "KEY_P": ("view", "phone"), "KEY_R": ("view", "reset"),
    "KEY_H": ("help", None), "KEY_F1": ("help", None), "KEY_V": ("control", "video"), "KEY_M": ("control", "model"),
    "KEY_L": ("measure", "pick"), "KEY_G": ("archive", "open"),
}  # fmt: skip


def handle_input(v, gui: Gui, dt: float, now: float) -> None:
    """Keys run commands (edge-triggered), WASD/QE and the right mouse button navigate."""

    w, ui = v.window, v.ui
    if not gui.wants_keyboard():
        for key_name, (command, arg) in KEY_COMMANDS.items():
            key = getattr(glfw, key_name)
            down = w.key_down(key)
            pressed = down and not ui.keys_down.get(key, False)
            ui.keys_down[key] = down
            if pressed and (command in ("view", "help") or v.loaded is not None):
                try:
                    v.apply(command, arg, now)
                except (ValueError, GeofuseError) as exc:
                    ui.error(f"{command}: {exc}")
        ctrl = w.key_down(glfw.KEY_LEFT_CONTROL) or w.key_down(glfw.KEY_RIGHT_CONTROL)
        o = w.key_down(glfw.KEY_O)
        if ctrl and o and not ui.keys_down.get(-1, False):
            open_dialog(v)
        ui.keys_down[-1] = ctrl and o
        axis = lambda plus, minus: float(w.key_down(plus)) - float(w.key_down(minus))  # noqa: E731
        v.nav.move(
            dt,
            axis(glfw.KEY_W, glfw.KEY_S),
            axis(glfw.KEY_D, glfw.KEY_A),
            axis(glfw.KEY_E, glfw.KEY_Q),
        )
    x, y = w.cursor()
    last, ui.cursor = ui.cursor, (x, y)
    if last is not None and not gui.wants_mouse() and w.mouse_down(glfw.MOUSE_BUTTON_RIGHT):
        v.nav.look(x - last[0], y - last[1])


def open_dialog(v) -> None:
    """The system's file dialog (portable-file-dialogs: zenity or kdialog on Linux), polled each
    frame; where no dialog program exists the Session panel's path field still works."""

    if v.ui.file_dialog is None:
        try:
            v.ui.file_dialog = pfd.open_file(
                "Open a session manifest or a clip", str(Path.cwd()), OPEN_FILTERS
            )
        except Exception as exc:  # no dialog program on this desktop
            v.ui.error(f"no file dialog available ({exc}): type the path in the Session panel")


def poll_dialog(v) -> None:
    """A file chosen in the dialog becomes the viewer's next session to open."""
    d = v.ui.file_dialog
    if d is not None and d.ready():
        v.ui.file_dialog = None
        chosen = d.result()
        if chosen:
            v.ui.open_request = Path(chosen[0])
