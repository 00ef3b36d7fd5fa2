"""The viewer's UI state, explicit and in one place: what the panels show and edit, what the
keyboard and mouse did last frame, requests that wait for the end of a frame. Pure data."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from app.core.constants import DRONE_DEFAULT_PITCH_DEG
from app.core.settings import OverlaySettings, ProjectionSettings
from app.ui.archive import ArchiveOverlay
from app.ui.control_points import ControlPicks
from app.ui.exporter import ExportJob, Recorder, SyncJob
from app.ui.measure import MeasureState

VIEWER_ALPHA = 0.85  # the viewer's default video opacity: the model shows through a little


@dataclass
class UiState:
    settings: ProjectionSettings = field(
        default_factory=lambda: ProjectionSettings(alpha=VIEWER_ALPHA)
    )
    overlays: OverlaySettings = field(default_factory=OverlaySettings)
    show_help: bool = False
    show_panels: bool = True
    open_path: str = ""  # the Session panel's text field
    errors: list[str] = field(default_factory=list)
    info: list[str] = field(default_factory=list)  # information: what was merely reported
    warnings: list[str] = field(default_factory=list)  # what lowers the result (app.core.messages)
    keys_down: dict[int, bool] = field(
        default_factory=dict
    )  # last frame's key states (edge detection)
    cursor: tuple[float, float] | None = None  # last frame's cursor position, screen coordinates
    course_pitch_deg: float = DRONE_DEFAULT_PITCH_DEG  # the pitch slider (applied on release)
    time_offset_s: float = 0.0  # the time-offset slider (the library holds the applied value)
    file_dialog: object | None = None  # an open portable-file-dialogs request
    screenshot_request: Path | None = None  # taken after this frame's panels are drawn
    state_request: Path | None = None
    open_request: str | Path | None = None  # dropped, chosen in the dialog, typed (or a URL)
    opening: object | None = (
        None  # a session being read in the background (app.ui.sessions.OpenJob)
    )
    stream_url: str = "udp://0.0.0.0:5600"  # the Session panel's stream field
    export_what: int = 0  # the Export panel's choice (app.ui.panels.export.EXPORTS)
    export_path: str = ""  # the Export panel's output path ("" = a name from the session's)
    export_job: ExportJob | None = None  # the running or last export
    recorder: Recorder | None = None  # while recording
    record_path: str = "out/recording.mp4"
    sync_job: SyncJob | None = None  # the running or last sync
    sync_applied: bool = False
    lens_path: str = ""  # the Session panel's lens profile field (clips)
    max_sse_px: float = 16.0  # 3D Tiles: refine tiles whose screen-space error exceeds this
    tile_errors_said: int = 0  # tile load errors already shown as information
    show_session_tab: int = (
        2  # frames until the Session tab is brought to the front (once, at start)
    )
    control: ControlPicks = field(default_factory=ControlPicks)  # control points picked by hand
    measure: MeasureState = field(default_factory=MeasureState)  # point, measure and mark
    memory_view: str = "model"  # model, memory, seen or changed (app.export.memory_view)
    memory_rule: int = 0  # the Memory panel's rule (app.export.memory.RULES)
    archive: ArchiveOverlay | None = None  # an archive's footprints drawn (app.ui.archive)
    gnss_band: tuple[float, float, float, float] | None = (
        None  # the timeline's GNSS band last drawn: x at 0 and at the end, y top and bottom (px)
    )
    quit: bool = False

    def error(self, message: str) -> None:
        if message not in self.errors:
            self.errors.append(message)
