"""The viewer's ImGui: ImGui and ImPlot on the window, and the docked layout. The panels dock
around the 3D view (imgui-bundle's docking): Session, Attitude, Projection and Export as tabs at
the top left, Error inspection and Stats below them, the Timeline (a stream's Live panel) along the bottom. The 3D view is
the dock space's central node and keeps about two thirds of the window; the user may move,
collapse and re-dock panels, and the layout is remembered between runs in
$XDG_CONFIG_HOME/geofuse/imgui.ini (never in the user's working folder).
"""

from __future__ import annotations

import logging
from pathlib import Path

from imgui_bundle import imgui, implot
from imgui_bundle.python_backends.glfw_backend import GlfwRenderer

log = logging.getLogger("geofuse.viewer")

LEFT_FRACTION = 0.26  # of the window's width: the left panel column
BOTTOM_FRACTION = 0.13  # of the window's height: the timeline
LEFT_LOWER_FRACTION = 0.45  # of the left column: Error inspection and Stats
TOP_PANELS = ("Session", "Attitude", "Projection", "Export", "Measure", "Memory")
LOWER_PANELS = ("Error inspection", "Stats")


class Gui:
    """ImGui and ImPlot on a window: docking on, the layout remembered in `ini_path`."""

    def __init__(self, window, ini_path: Path) -> None:

        imgui.create_context()
        implot.create_context()
        io = imgui.get_io()
        io.config_flags |= imgui.ConfigFlags_.docking_enable
        try:
            ini_path.parent.mkdir(parents=True, exist_ok=True)
            io.set_ini_filename(str(ini_path))
        except OSError:  # a read-only home: run with the default layout, remember nothing
            io.set_ini_filename("")
        self.window = window
        self.renderer = GlfwRenderer(window.handle)
        self.dock_id = 0
        self._layout_checked = False

    def begin_frame(self) -> None:

        self.renderer.process_inputs()
        imgui.new_frame()

    def wants_mouse(self) -> bool:

        return bool(imgui.get_io().want_capture_mouse)

    def wants_keyboard(self) -> bool:

        return bool(imgui.get_io().want_capture_keyboard)

    def layout(self, viewer) -> tuple[int, int, int, int]:
        """Lay the dock space over the window (building the default layout when none was saved);
        returns the 3D view's rectangle (x, y from the top, w, h) in framebuffer pixels."""

        internal = imgui.internal
        viewport = imgui.get_main_viewport()
        self.dock_id = imgui.dock_space_over_viewport(
            0, viewport, imgui.DockNodeFlags_.passthru_central_node
        )
        if not self._layout_checked:
            self._layout_checked = True
            node = internal.dock_builder_get_node(self.dock_id)
            if node is None or node.is_leaf_node():
                self._build_default_layout(viewport)
        central = internal.dock_builder_get_central_node(self.dock_id)
        fb_w, fb_h = self.window.framebuffer_size()
        io = imgui.get_io()
        sx = fb_w / max(io.display_size.x, 1.0)
        sy = fb_h / max(io.display_size.y, 1.0)
        if central is None:
            return 0, 0, fb_w, fb_h
        x0, y0 = (central.pos.x - viewport.pos.x) * sx, (central.pos.y - viewport.pos.y) * sy
        return (
            int(round(x0)),
            int(round(y0)),
            max(1, int(round(central.size.x * sx))),
            max(1, int(round(central.size.y * sy))),
        )

    def _build_default_layout(self, viewport) -> None:

        internal = imgui.internal
        internal.dock_builder_remove_node(self.dock_id)
        internal.dock_builder_add_node(
            self.dock_id,
            internal.DockNodeFlagsPrivate_.dock_space | imgui.DockNodeFlags_.passthru_central_node,
        )
        internal.dock_builder_set_node_size(self.dock_id, viewport.size)
        _, bottom, rest = internal.dock_builder_split_node_py(
            self.dock_id, imgui.Dir.down, BOTTOM_FRACTION
        )
        _, left, _ = internal.dock_builder_split_node_py(rest, imgui.Dir.left, LEFT_FRACTION)
        _, lower, upper = internal.dock_builder_split_node_py(
            left, imgui.Dir.down, LEFT_LOWER_FRACTION
        )
        for name in TOP_PANELS:
            internal.dock_builder_dock_window(name, upper)
        for name in LOWER_PANELS:
            internal.dock_builder_dock_window(name, lower)
        internal.dock_builder_dock_window("Timeline", bottom)
        internal.dock_builder_dock_window("Live", bottom)  # a stream's timeline
        internal.dock_builder_finish(self.dock_id)

    def render(self) -> None:

        imgui.render()
        self.renderer.render(imgui.get_draw_data())

    def shutdown(self) -> None:

        ini = imgui.get_io().get_ini_filename()
        if ini:
            try:
                imgui.save_ini_settings_to_disk(ini)
            except OSError as exc:
                log.warning("could not save the panel layout to %s (%s)", ini, exc)
        try:
            self.renderer.shutdown()
        except Exception:  # PyOpenGL may already have lost the context at exit: nothing to free
            log.debug("imgui renderer shutdown failed", exc_info=True)
