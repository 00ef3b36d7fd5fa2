"""The solver library: every attitude source of a session solved in the background into a camera
track (app.session.camera_track), so that the viewer can switch sources while the video plays without a
stall; and the curves and RMS figures the error panel shows (heading, pitch, roll of the optical
axis at every frame, against the reference: the truth at the moments the frames show, else the
phone).

The library owns its state. Readers get immutable snapshots (`track`, `curves`, `errors`);
changing a setting that a solve depends on (the live time offset, a course pitch) is a request
(`set_time_offset`, `set_course_pitch`): the library re-solves on its worker thread under its own
lock and bumps `version` when the result is in.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, replace

import numpy as np

from app.attitude.metrics import hpr_rms
from app.session.camera_track import CameraTrack, frame_clock
from app.session.model import COURSE, REGISTERED, TRUTH, Session
from app.solve.track import solve_track

REFERENCE_ORDER = (TRUTH, "phone")  # what the others are compared with, first found


@dataclass(frozen=True)
class Curves:
    """Per-frame heading, pitch, roll (deg) of the optical axis; t: seconds from the first frame."""

    t: np.ndarray
    hpr: np.ndarray
    q: np.ndarray


def curves_of(track: CameraTrack) -> Curves:
    poses = track.frame_poses()
    return Curves(poses.time_s - poses.time_s[0], poses.hpr, poses.q)


class SolverLibrary:
    """Solves `session.sources` one by one on a daemon thread (the `first` one first)."""

    def __init__(self, session: Session, first: str | None = None) -> None:
        self.session = session
        order = list(session.sources)
        if REGISTERED in order:  # it takes about as long as the clip: solved after the others
            order.remove(REGISTERED)
            order.append(REGISTERED)
        if first in order:
            order.remove(first)
            order.insert(0, first)
        self.order: tuple[str, ...] = tuple(order)
        self._tracks: dict[str, CameraTrack] = {}
        self._curves: dict[str, Curves] = {}
        self._errors: dict[str, str] = {}
        self._partial: dict[
            str, float
        ] = {}  # sources being solved that report progress (registration)
        self._truth_timed: CameraTrack | None = None
        self._correction = (0.0, 0.0, 0.0)  # offset s, drift ppm, pivot session s
        self._course_pitch = session.course_pitch_deg
        self._version = 0
        self._pending = 0
        self._table: list | None = None
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._jobs: queue.Queue[str | None] = queue.Queue()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="geofuse-solver", daemon=True)
        for name in self.order:
            self._submit(name)
        self._thread.start()

    # --- reading -------------------------------------------------------------------------------

    @property
    def progress(self) -> float:
        with self._lock:
            done = len(self._tracks) + len(self._errors)
            partial = sum(
                f
                for n, f in self._partial.items()
                if n not in self._tracks and n not in self._errors
            )
            return (done + partial) / max(1, len(self.order))

    def source_progress(self, name: str) -> float | None:
        """How far a long solve of `name` has got (0..1), while it runs; None otherwise."""
        with self._lock:
            if name in self._tracks or name in self._errors:
                return None
            return self._partial.get(name)

    @property
    def done(self) -> bool:
        """Every source solved or failed, and no re-solve pending."""
        with self._lock:
            return self._pending == 0

    @property
    def version(self) -> int:
        """Bumped whenever a track changes (a solve finished, an offset or pitch applied)."""
        with self._lock:
            return self._version

    @property
    def time_offset_s(self) -> float:
        with self._lock:
            return self._correction[0]

    @property
    def course_pitch_deg(self) -> float | None:
        with self._lock:
            return self._course_pitch

    def wait(self, timeout: float | None = None, but: tuple[str, ...] = ()) -> bool:
        """Block until the library is idle (every request done), or with `but` until every
        source but those is solved or failed; False on timeout."""
        names = [n for n in self.order if n not in but]
        with self._idle:
            if not but:
                return self._idle.wait_for(lambda: self._pending == 0, timeout)
            return self._idle.wait_for(
                lambda: all(n in self._tracks or n in self._errors for n in names), timeout
            )

    def track(self, name: str | None) -> CameraTrack | None:
        """The camera track of a solved source (with the live time offset), else None."""
        with self._lock:
            return self._tracks.get(name) if name else None

    def truth_track(self) -> CameraTrack | None:
        """The true camera at the frames' true times (simulated sessions), else None."""
        with self._lock:
            return self._truth_timed

    def curves(self, name: str | None) -> Curves | None:
        with self._lock:
            return self._curves.get(name) if name else None

    def solved(self) -> list[str]:
        with self._lock:
            return [n for n in self.order if n in self._tracks]

    def errors(self) -> dict[str, str]:
        with self._lock:
            return dict(self._errors)

    def reference(self) -> str | None:
        """The source to compare against: the truth if the session has one, else the phone's own."""
        return next((n for n in REFERENCE_ORDER if n in self.order), None)

    def rms_table(self) -> list[tuple[str, float, float, float, float]]:
        """(source, heading, pitch, roll, total) RMS in degrees against the reference, for every
        solved source (heading differences wrapped to +-180). Cached until a track changes."""
        with self._lock:
            if self._table is not None:
                return self._table
            curves, done = dict(self._curves), self._pending == 0
        ref = self.reference()
        table = []
        if ref in curves:
            r = curves[ref]
            table = [
                (n, *hpr_rms(curves[n].q, r.q)) for n in self.order if n != ref and n in curves
            ]
        if done:
            with self._lock:
                self._table = table
        return table

    # --- requests ------------------------------------------------------------------------------

    def set_time_offset(
        self, offset_s: float, drift_ppm: float = 0.0, pivot_s: float = 0.0
    ) -> None:
        """Correct every track's frame clock by offset_s seconds and a clock drift of drift_ppm
        about session time pivot_s (a sync's result; applied at once: no solve needed)."""
        correction = (float(offset_s), float(drift_ppm), float(pivot_s))
        with self._lock:
            if correction == self._correction:
                return
            self._correction = correction
            self._tracks = {n: t.with_offset(*correction) for n, t in self._tracks.items()}
            self._version += 1

    def set_course_pitch(self, pitch_deg: float) -> None:
        """A drone clip without gimbal attitude: re-solve the course source at this pitch (deg)."""
        if COURSE not in self.order:
            return
        with self._lock:
            self._course_pitch = float(pitch_deg)
        self._submit(COURSE)

    def resolve_registered(self) -> None:
        """Register again (control points were kept beside the input); the old track stays
        until the new one is in."""
        if REGISTERED in self.order:
            with self._lock:
                self._errors.pop(REGISTERED, None)
                self._partial[REGISTERED] = 0.0
            self._submit(REGISTERED)

    def use_session(self, session: Session) -> None:
        """The session again with another scene (its world built in the background,
        app.ui.world): `registered` is solved against it, added where only this session offers
        it, again where it was solved or begun before (the old track stays until the new one is
        in); a solve still queued reads this session when it runs."""
        with self._lock:
            self.session = session
            added = REGISTERED in session.sources and REGISTERED not in self.order
            begun = any(REGISTERED in d for d in (self._tracks, self._errors, self._partial))
            if added:
                self.order = (*self.order, REGISTERED)
        if added:
            self._submit(REGISTERED)
        elif begun:
            self.resolve_registered()

    def close(self, wait_s: float = 10.0) -> None:
        """Stop solving: a registration under way stops at its next keyframe; waits up to
        wait_s seconds for the worker to end (it is a daemon thread either way)."""
        self._closed.set()
        self._jobs.put(None)
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(wait_s)

    # --- the worker ----------------------------------------------------------------------------

    def _submit(self, name: str) -> None:
        with self._lock:
            self._pending += 1
        self._jobs.put(name)

    def _run(self) -> None:
        while (name := self._jobs.get()) is not None:
            try:
                self._solve(name)
            except Exception as exc:  # shown in the viewer; one bad source must not stop the rest
                with self._lock:
                    self._errors[name] = f"{type(exc).__name__}: {exc}"
            finally:
                with self._idle:
                    self._pending -= 1
                    self._version += 1
                    self._table = None
                    self._idle.notify_all()

    def _partly(self, name: str, fraction: float) -> None:
        with self._lock:
            self._partial[name] = float(fraction)

    def _solve(self, name: str) -> None:
        with self._lock:
            pitch = self._course_pitch
        track = solve_track(
            self.session,
            name,
            progress=lambda f: self._partly(name, f),
            stop=self._closed.is_set,
            background=True,
            course_pitch_deg=pitch if name == COURSE else None,
        )
        truth = (
            replace(track, clock=frame_clock(self.session, true_timing=True))
            if name == TRUTH
            else None
        )
        # The reference is the true pose of each frame at the moment it shows, so a source that
        # corrects the frame times (registered) is compared with what the frames really show.
        curves = curves_of(truth if truth is not None else track)
        with self._lock:
            self._tracks[name] = track.with_offset(*self._correction)
            self._curves[name] = curves
            self._errors.pop(name, None)
            if truth is not None:
                self._truth_timed = truth
