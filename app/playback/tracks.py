"""Every attitude source of a session solved in the background, so that the viewer can switch
filters while the video plays without a stall. Also the curves and RMS figures the error panel
shows (heading, pitch, roll of the optical axis at every frame, against the session's reference)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from app import rotations
from app.attitude.metrics import hpr_rms
from app.session import Session, pose_track
from app.trajectory import PoseTrack


@dataclass(frozen=True)
class Curves:
    """Per-frame heading, pitch, roll (deg) of the optical axis at the pipeline's frame times."""

    t: np.ndarray
    hpr: np.ndarray
    q: np.ndarray


class TrackLibrary:
    """Solves `session.filters` one by one on a daemon thread; read `progress`, `tracks`, `errors`."""

    def __init__(self, session: Session, first: str | None = None) -> None:
        self.session = session
        order = list(session.filters)
        if first in order:  # the source shown first is solved first
            order.remove(first)
            order.insert(0, first)
        self.order = order
        self.tracks: dict[str, PoseTrack] = {}
        self.curves: dict[str, Curves] = {}
        self.errors: dict[str, str] = {}
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="geofuse-solver", daemon=True)
        self._thread.start()

    @property
    def progress(self) -> float:
        with self._lock:
            return (len(self.tracks) + len(self.errors)) / max(1, len(self.order))

    @property
    def done(self) -> bool:
        return self.progress >= 1.0

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return self.done

    def _run(self) -> None:
        t = self.session.frame_times
        for name in self.order:
            try:
                track = pose_track(self.session, name)
                _, _, q = track.at(t)
                curves = Curves(t - t[0], rotations.hpr_from_camera_quat(q), q)
                with self._lock:
                    self.tracks[name] = track
                    self.curves[name] = curves
            except Exception as exc:  # shown in the viewer; one bad source must not stop the rest
                with self._lock:
                    self.errors[name] = f"{type(exc).__name__}: {exc}"

    def reference(self) -> str | None:
        """The source to compare against: the truth if the session has one, else the phone's own."""
        for name in ("truth", "phone"):
            if name in self.session.filters:
                return name
        return None

    def rms_table(self) -> list[tuple[str, float, float, float, float]]:
        """(source, heading, pitch, roll, total) RMS in degrees against the reference, for every
        solved source (heading differences wrapped to +-180). Cached once every source is solved."""
        cached = self.__dict__.get("_table")
        if cached is not None:
            return cached
        table = self._rms_table()
        if self.done:
            self._table = table
        return table

    def _rms_table(self) -> list[tuple[str, float, float, float, float]]:
        ref = self.reference()
        if ref is None or ref not in self.curves:
            return []
        out = []
        r = self.curves[ref]
        for name in self.order:
            c = self.curves.get(name)
            if c is None or name == ref:
                continue
            out.append((name, *hpr_rms(c.q, r.q)))
        return out
