"""Exports and recording from the viewer, without stalling it.

- `ExportJob`: `geofuse export ...` for the open session run as a child process (its own GL
  context and decoder, the same code as the command line), its progress read from the bar it
  prints; the viewer polls `progress`, `done` and `message`.
- `Recorder`: what the window shows, frame by frame, encoded as H.264 on a worker thread (a
  bounded queue: frames the encoder cannot take in time are dropped and counted), with the
  viewer's clock as presentation times.
"""

from __future__ import annotations

import queue
import re
import subprocess
import sys
import threading
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from app.core.worker import OneShot
from app.sync import bearings_of, estimate_offset, gyro_rates, rate_reference, video_rates

_PERCENT = re.compile(rb"(\d+(?:\.\d)?)%")
RECORD_QUEUE = 8  # frames waiting for the encoder


class ExportJob:
    """`geofuse export WHAT INPUT --out OUT --source SOURCE [extra...]` in a child process."""

    def __init__(
        self, what: str, source_path: Path, out: Path, source: str, extra: list[str] | None = None
    ) -> None:
        self.what, self.out = what, Path(out)
        cmd = [
            sys.executable,
            "-m",
            "app",
            "export",
            what,
            str(source_path),
            "--out",
            str(out),
            "--source",
            source,
            *(extra or []),
        ]
        self.progress = 0.0
        self.message = ""
        self.returncode: int | None = None
        self._proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self._thread = threading.Thread(target=self._read, name="geofuse-export", daemon=True)
        self._thread.start()

    @property
    def done(self) -> bool:
        return self.returncode is not None

    @property
    def ok(self) -> bool:
        return self.returncode == 0

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return self.done

    def cancel(self) -> None:
        if self._proc.poll() is None:
            self._proc.terminate()

    def _read(self) -> None:
        err = b""
        while (
            chunk := self._proc.stderr.read1(4096)
            if hasattr(self._proc.stderr, "read1")
            else self._proc.stderr.read(4096)
        ):
            err += chunk
            found = _PERCENT.findall(err[-200:])
            if found:
                self.progress = float(found[-1]) / 100.0
        out = self._proc.stdout.read()
        self.returncode = self._proc.wait()
        lines = [
            line
            for line in (out + b"\n" + err)
            .decode(errors="replace")
            .replace("\r", "\n")
            .splitlines()
            if line.strip() and "%" not in line
        ]
        final = [line for line in lines if line.startswith(("wrote ", "geofuse: error"))]
        self.message = (final or lines or [f"export ended with status {self.returncode}"])[-1]
        if self.ok:
            self.progress = 1.0


class Recorder:
    """Encodes window frames (H, W, 3) uint8 RGB at their clock times into an MP4 (H.264)."""

    def __init__(self, out: Path, size: tuple[int, int]) -> None:

        self.out, self.size = Path(out), size
        self.frames = 0
        self.dropped = 0
        self.error: str | None = None
        self._t0: float | None = None
        self._queue: queue.Queue[tuple[np.ndarray, float] | None] = queue.Queue(
            maxsize=RECORD_QUEUE
        )
        self._container = av.open(str(self.out), "w")
        w, h = (size[0] // 2) * 2, (size[1] // 2) * 2  # H.264 with 4:2:0 needs even sizes
        self._stream = self._container.add_stream("libx264", rate=30)
        self._stream.width, self._stream.height, self._stream.pix_fmt = w, h, "yuv420p"
        self._stream.time_base = Fraction(1, 90000)
        self._stream.codec_context.time_base = self._stream.time_base
        self._stream.codec_context.options = {"preset": "veryfast", "crf": "20", "bf": "0"}
        self._thread = threading.Thread(target=self._run, name="geofuse-recorder", daemon=True)
        self._thread.start()

    def add(self, rgb: np.ndarray, now: float) -> None:
        """One frame shown at clock time `now` (seconds); dropped (counted) when the encoder lags."""
        if self._t0 is None:
            self._t0 = now
        try:
            self._queue.put_nowait((rgb, now - self._t0))
        except queue.Full:
            self.dropped += 1

    def stop(self) -> None:
        self._queue.put(None)
        self._thread.join()

    def _run(self) -> None:

        last_pts = -1
        try:
            while (item := self._queue.get()) is not None:
                rgb, t = item
                pts = int(round(t * 90000))
                if pts <= last_pts:
                    continue  # two frames at one clock time (a paused or fixed clock): keep the first
                frame = av.VideoFrame.from_ndarray(
                    np.ascontiguousarray(rgb[: self._stream.height, : self._stream.width]),
                    format="rgb24",
                )
                frame.pts, frame.time_base = pts, self._stream.time_base
                for packet in self._stream.encode(frame):
                    self._container.mux(packet)
                self.frames += 1
                last_pts = pts
            for packet in self._stream.encode(None):
                self._container.mux(packet)
        except Exception as exc:  # shown in the viewer; recording must not take the viewer down
            self.error = f"{self.out}: recording stopped ({type(exc).__name__}: {exc})"
        finally:
            self._container.close()


class SyncJob(OneShot):
    """`geofuse sync` for the open session on a worker thread (app.sync), started at once: the
    video's rotation rates, the gyroscope's, and the offset between them; `curves()` gives both
    magnitudes for the viewer's plot, on the session clock, before and after the offset."""

    def __init__(self, session) -> None:
        self.session = session
        self.progress = 0.0
        self.result = None
        self.video = self.gyro = None
        super().__init__("geofuse-sync")
        self.start()

    def _failed(self) -> str:
        return "sync failed"

    def _work(self) -> None:
        s = self.session
        self.gyro = gyro_rates(s)
        self.video = video_rates(
            s.video, bearings_of(s), s.rotation_cw, lambda f: setattr(self, "progress", f)
        )
        self.result = estimate_offset(
            self.video, self.gyro, float(s.frame_times[0] - s.video.pts_s[0])
        )

    def curves(self, points: int = 600) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Rate magnitudes (rad/s) against seconds from the first frame: video before and after
        the offset, and the gyroscope."""
        if self.result is None:
            return {}
        start = float(self.session.frame_times[0] - self.session.video.pts_s[0])
        t = np.linspace(self.video.t[0], self.video.t[-1], points)

        def mag(c, tt: np.ndarray) -> np.ndarray:
            omega = np.nan_to_num(c.omega)
            rates = [np.interp(tt, c.t, omega[:, j]) for j in range(omega.shape[1])]
            return np.linalg.norm(np.column_stack(rates), axis=1)

        name = rate_reference(self.session) or "reference"
        return {
            "video": (t, mag(self.video.along(self.gyro), t)),
            f"{name}, before": (t, mag(self.gyro, t + start)),
            f"{name}, after": (t, mag(self.gyro, t + start + self.result.offset_s)),
        }
