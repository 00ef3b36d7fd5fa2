"""The viewer's background jobs: an export in a child process, the recorder of what the window
shows, and the sync of the video's times against the sensors (app.ui.exporter runs them). A
mixin of app.ui.viewer.Viewer: the commands (app.ui.commands) call these methods on the viewer."""

from __future__ import annotations

from pathlib import Path

from app.core.errors import GeofuseError
from app.core.outputs import check_output
from app.export import EXPORT_SUFFIXES
from app.sync import rate_reference, timed_by
from app.ui.exporter import ExportJob, Recorder, SyncJob

JOB_WAIT_S = (
    600.0  # a script's `wait exported` / `wait synced` gives up after this long (real seconds)
)


class ViewerJobs:
    """Export, record and sync for a Viewer (uses its ui, loaded, options, window and
    set_time_offset)."""

    def wait_until_exported(self) -> None:
        """Hold everything until the running export has finished (a script's `wait exported`)."""
        job = self.ui.export_job
        if job is not None and not job.wait(JOB_WAIT_S):
            raise GeofuseError(f"the export did not finish within {JOB_WAIT_S:g} s")

    def start_export(self, what: str, out: Path) -> None:
        """Export the open session under the current source, in a child process (app.ui.exporter)."""

        if what not in EXPORT_SUFFIXES:
            raise ValueError(f"expected one of {sorted(EXPORT_SUFFIXES)}, got {what!r}")
        if self.ui.export_job is not None and not self.ui.export_job.done:
            raise ValueError("an export is running; wait for it or cancel it")
        s = self.loaded.session
        check_output(out, "export", EXPORT_SUFFIXES[what], s.inputs)
        clip = s.path.suffix.lower() != ".toml"
        extra = [
            *(["--srt", str(self.options.srt)] if clip and self.options.srt else []),
            *(["--lens", str(self.options.lens)] if clip and self.options.lens else []),
        ]
        self.ui.export_job = ExportJob(what, s.path, out, self.loaded.source, extra)

    def start_sync(self) -> None:
        """Find the video <-> gyroscope offset in the background (app.ui.exporter.SyncJob); it
        becomes the session's time offset when found."""
        job = self.ui.sync_job
        if job is not None and not job.done:
            raise ValueError("a sync is running")
        if rate_reference(self.loaded.session) is None:
            raise ValueError(
                "this session has no gyroscope, no recorded attitude and no course: the offset cannot be found from rotation"
            )
        self.ui.sync_job, self.ui.sync_applied = SyncJob(self.loaded.session), False

    def wait_until_synced(self) -> None:
        job = self.ui.sync_job
        if job is not None and not job.wait(JOB_WAIT_S):
            raise GeofuseError(f"the sync did not finish within {JOB_WAIT_S:g} s")
        self._apply_sync()

    def _apply_sync(self) -> None:
        job = self.ui.sync_job
        if job is None or not job.done or self.ui.sync_applied:
            return
        self.ui.sync_applied = True
        if job.error:
            self.ui.error(job.error)
        elif job.result is not None:
            r = job.result
            self.set_time_offset(
                r.offset_s, r.drift_ppm, r.reference_s
            )  # the drift too, as "auto" does
            self.ui.info.append(
                f"time offset {1000 * job.result.offset_s:+.1f} ms from the video against {timed_by(job.session)} (confidence {job.result.confidence:.2f})"
            )

    def start_recording(self, out: Path) -> None:
        if self.ui.recorder is not None:
            raise ValueError("already recording")
        check_output(out, "record", (".mp4",), self.loaded.session.inputs)
        out.parent.mkdir(parents=True, exist_ok=True)
        self.ui.recorder = Recorder(out, self.window.framebuffer_size())

    def stop_recording(self) -> None:
        rec, self.ui.recorder = self.ui.recorder, None
        if rec is not None:
            rec.stop()
            self.ui.info.append(
                rec.error
                or f"recorded {rec.out}: {rec.frames} frames"
                + (f", {rec.dropped} dropped" if rec.dropped else "")
            )
