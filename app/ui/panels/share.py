"""The Share toggle, in the Session panel: the browser map of what the viewer shows (`share on`
/ `share off`, app.ui.share), its URL with its access token (Copy puts it on the clipboard), how
many browsers follow it, and what it said."""

from __future__ import annotations

from imgui_bundle import imgui

from app.ui.panels.widgets import AMBER, colour, run


def draw(v) -> None:
    """This frame's part of the Session panel (v: the Viewer)."""
    server = v.share.web
    imgui.separator()
    changed, on = imgui.checkbox("Share: the browser map", server is not None)
    if changed:
        run(v, "share", "on" if on else "off")
        server = v.share.web
    if server is None:
        imgui.same_line()
        imgui.text_disabled("(on this machine only)")
        return
    imgui.same_line()
    imgui.text_disabled(
        f"{server.clients} browser{'' if server.clients == 1 else 's'}, "
        f"{server.frames_published} frames"
    )
    if imgui.button("Copy URL"):
        imgui.set_clipboard_text(server.url)
    imgui.same_line()
    imgui.text_wrapped(server.url)
    if server.warning:
        imgui.text_colored(colour(AMBER), "warning:")
        imgui.same_line()
        imgui.text_wrapped(server.warning)
    for said in server.messages.items[-2:]:
        imgui.text_disabled("note:")
        imgui.same_line()
        imgui.text_wrapped(said)
