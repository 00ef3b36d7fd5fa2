"""The viewer's ImGui panels, one module a panel (Session, Timeline, Attitude, Projection, Error
inspection, Stats, Export, Measure, Memory, Live (a stream), Help, Share (the browser map, drawn in Session); widgets: what they share). Every control runs the same
commands as the script (app.ui.commands) or the same Viewer methods; the docked layout is
app.ui.gui's, keys and mouse app.ui.inputs'.
"""

from __future__ import annotations

from app.ui.gui import Gui
from app.ui.inputs import poll_dialog
from app.ui.panels import (
    attitude,
    export,
    help,
    inspection,
    live,
    measure,
    memory,
    projection,
    session,
    stats,
    timeline,
)

__all__ = ["draw"]


def draw(v, gui: Gui, now: float) -> None:
    """The panels of this frame (after `Gui.begin_frame` and `Gui.layout`)."""
    poll_dialog(v)
    if not v.ui.show_panels:
        return
    session.draw(v)
    if v.live is not None:
        live.draw(v, now)
        projection.draw(v)
        stats.draw(v)
    elif v.loaded is not None:
        timeline.draw(v, now)
        attitude.draw(v)
        projection.draw(v)
        inspection.draw(v)
        stats.draw(v)
        export.draw(v, now)
        measure.draw(v, now)
        memory.draw(v, now)
    if v.ui.show_help:
        help.draw(v)
