"""A live feed's GNSS tested against the scene as it arrives (issue 52, forward only): each
keyframe that live registration kept (app.live.register) puts the feed's fix at that moment
beside where the scene says the camera was, and the fixes are judged by app.register.gnss's
test, its settings, thresholds and words (check_fixes over the keyframes of the last HISTORY_S,
each keyframe's fix its own sample: the running median is then one-sided, over the newest three;
GnssLie.said): a lie (a drag-off past the fixes' accuracy, a jump, a frozen fix while the scene
moves, a height that disagrees) raises the alarm at the keyframe that exceeds the threshold,
said once with where it began and how far it had gone by then (the median residual at the
alarm: the files' centred medians smear it over sparse keyframes). From then the fixes are `rejected` (the
drawn pose stands on the scene: app.live.register follows the keyframes), until a keyframe's fix
has agreed with the scene for merge_s (said: "GNSS agrees with the scene again from ...").

Each frame drawn gets its status (app.camera.fixes: used, rejected, missing): `missing` where
the newest fix behind it is older than the outage limit (app.core.constants.GAP_MIN_S, the
files' gap rule at 1 Hz fixes or faster), or held (no longer current: the scene carries the
pose, app.live.register); an outage is shown as ongoing while it lasts and said
with its span when a fix comes again (app.camera.fixes.outage_said). Times are media seconds of
the feed (0: its first frame), positions local ENU metres. Thread-safe: the registration thread
tests keyframes, the drawing thread asks per frame.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from app.camera.fixes import MISSING, REJECTED, STATES, USED, outage_said
from app.core.constants import GAP_MIN_S
from app.core.messages import Messages
from app.register.gnss import (
    DISAGREES,
    HEIGHT,
    JUMP_SHARE,
    CheckSettings,
    GnssLie,
    check_fixes,
    clip_time,
    own_offset,
)

HISTORY_S = 60.0  # keyframes tested together: the baseline's 30 s before an alarm, and more
JUMP_FAR = 3.0  # a keyframe's own fix this many thresholds off, the one before within: a jump
STEADY_KEYFRAMES = 3  # tested before a jump is taken from one keyframe (the gate is on by then)
SUSPECT_ACCURACIES = 2.5  # a fix this many stated accuracies off its own offset: keyframes sooner
DRIFT_S = 6.0  # a drift judged over this long (s): the newest keyframe's one-sided median lags
# a drag by a keyframe, so 2 m/s walks the 6 m floor only over longer than files' 4 s
UNSEEN_S = 5.0  # keyframes tested farther apart than this (s): the fixes went untested between
# (fog, sky, a featureless field: nothing registered), so a lie caught after began unseen
HELD_LATE_S = 1.0  # a held-off jump still drawn held this close (s) to the keyframe past it


@dataclass(frozen=True)
class Verdict:
    """One keyframe's test: lying (the fixes are rejected from now), disagrees (this keyframe's
    own fix lies beyond the threshold, before any median: where the drawn pose must stand on
    the scene at once) and the threshold it was held to (m, horizontal)."""

    lying: bool
    disagrees: bool
    threshold_m: float


class GnssWatch:
    """See the module docstring. accuracy_m: the fixes' accuracy (m, 1 sigma per axis) where
    the feed states none (None: CheckSettings.accuracy_m); settings: the test's (None:
    app.register.gnss's defaults, as files are tested); utc_of(media s) -> Unix s or None:
    the feed's clock where it gives one (KLV's Precision Time Stamp)."""

    def __init__(
        self,
        messages: Messages,
        accuracy_m: float | None = None,
        settings: CheckSettings | None = None,
        utc_of: Callable[[float], float | None] | None = None,
        outage_s: float = GAP_MIN_S,
        history_s: float = HISTORY_S,
        drift_s: float = DRIFT_S,
    ) -> None:
        settings = settings or CheckSettings()
        self.messages, self.settings, self.utc_of = messages, settings, utc_of
        self.accuracy_m = settings.accuracy_m if accuracy_m is None else float(accuracy_m)
        self.outage_s, self.history_s = outage_s, history_s
        # each fix sampled at its keyframe
        self._test = replace(settings, reach_s=math.inf, drift_s=drift_s)
        self._t: list[float] = []
        self._fix: list[np.ndarray] = []
        self._scene: list[np.ndarray] = []
        self._acc: list[float] = []
        self._dis: list[bool] = []  # each keyframe's own fix beyond the threshold
        self.tested = 0  # keyframes tested
        self.lies: list[GnssLie] = []  # said, the last one ongoing while `lying`
        self.lying = False
        self._agree_since: float | None = None
        self._last_bad_s = math.nan
        self.frames = dict.fromkeys(STATES, 0)  # frames drawn, by status
        self.runs: list[list] = []  # [start s, end s, status]: frames drawn in a row, by status
        self.outages: list[tuple[float, float]] = []  # ended, (start, end) media s
        self.outage_since: float | None = None  # the last fix before the outage going on
        self.unseen: list[tuple[float, float]] = []  # (from, to) s: no keyframe tested fixes
        self._held: list[float] | None = None  # [first, last] frame of the last held-off jump
        self.held_off_m = 0.0  # the telemetry's jumps the frame drawn last did not follow (m)
        self._far_off = False  # the newest keyframe's fix far off its own offset (`suspect`)
        self._lock = threading.Lock()

    @property
    def suspect(self) -> bool:
        """Whether the newest keyframe's fix lies farther from the scene than the GNSS's own
        offset by more than SUSPECT_ACCURACIES of its stated accuracy, or a lie is going on:
        keyframes are then offered more often (app.live.register), the sooner to tell a
        drag-off from the fix's own wander. No accusation: nothing is rejected for it."""
        with self._lock:
            return self.lying or self._far_off

    def _newest_far_off(self) -> bool:
        """`suspect`'s test of the newest keyframe, made as it is tested (under the lock)."""
        if len(self._t) <= STEADY_KEYFRAMES:
            return False
        raw = self._fix[-1] - self._scene[-1] - self._baseline(self._t[-1])
        return bool(np.linalg.norm(raw[:2]) > SUSPECT_ACCURACIES * self._acc[-1])

    @property
    def keyframe_times(self) -> list[float]:
        """Media times (s) of the keyframes tested over the last history_s."""
        with self._lock:
            return list(self._t)

    def threshold_m(self, accuracy_m: float) -> tuple[float, float]:
        """(horizontal, vertical) m beyond which a fix stating accuracy_m (m) disagrees: as
        app.register.gnss.check_fixes holds it."""
        h, v = self.settings.thresholds(accuracy_m)
        return float(h), float(v)

    def keyframe(
        self,
        t_s: float,
        fix_enu: npt.ArrayLike,
        scene_enu: npt.ArrayLike,
        accuracy_m: float | None = None,
    ) -> Verdict:
        """A keyframe kept at media time t_s (s): the feed's fix then (fix_enu (3,) ENU m, its
        stated horizontal accuracy_m or None) against the registered position (scene_enu (3,)
        ENU m). The alarm is said here, and the agreement that ends a lie."""
        acc = accuracy_m if accuracy_m is not None and math.isfinite(accuracy_m) else None
        acc = self.accuracy_m if acc is None else float(acc)
        fix, scene = np.asarray(fix_enu, np.float64), np.asarray(scene_enu, np.float64)
        h, v = self.threshold_m(acc)
        raw = fix - scene
        disagrees = bool(np.linalg.norm(raw[:2]) > h or abs(raw[2]) > v)
        with self._lock:
            since = self._untested_since()
            if since is not None and t_s - since > UNSEEN_S:
                self.unseen.append((since, float(t_s)))
            self._t.append(float(t_s))
            self._fix.append(fix)
            self._scene.append(scene)
            self._acc.append(acc)
            self._dis.append(disagrees)
            while self._t[0] < t_s - self.history_s:
                for kept in (self._t, self._fix, self._scene, self._acc, self._dis):
                    kept.pop(0)
            self.tested += 1
            self._far_off = self._newest_far_off()
            if len(self._t) < 2:
                return Verdict(self.lying, disagrees, h)
            t = np.array(self._t)
            check = check_fixes(t, self._fix, self._acc, t, self._scene, self._test)
            bad = bool(check.status.rejected[-1])  # (the newest: rejected only where it is bad)
            if not self.lying and bad and check.lies:
                lie = check.lies[-1]
                now = self._off(lie.kind, check.residual[-1])
                lie = replace(lie, caught_s=float(t_s), worst_s=float(t_s), worst_m=now)
                self._alarm(replace(lie, began_s=self._stepped(lie)))
            elif not self.lying and self._jumped(h):
                far = float(np.linalg.norm(raw[:2]))
                self._alarm(GnssLie(t_s, t_s, t_s, far, t_s, self._baseline(t_s)))
            elif self.lying:
                self._judge(t_s, bad, check.residual[-1])
            return Verdict(self.lying, disagrees, h)

    def _jumped(self, threshold_m: float) -> bool:
        """Whether the newest keyframe's own fix lies JUMP_FAR thresholds (threshold_m, m) or
        more off the scene across, the one before it within its threshold, after
        STEADY_KEYFRAMES tested: a jump, said at once (the median of the newest three passes it
        one keyframe later; a keyframe registered that far astray is set aside by live
        registration's gate before it is tested)."""
        if len(self._t) <= STEADY_KEYFRAMES or self._dis[-2]:
            return False
        raw = self._fix[-1] - self._scene[-1]
        return bool(np.linalg.norm(raw[:2]) > JUMP_FAR * threshold_m)

    def _baseline(self, t_s: float) -> np.ndarray:
        """The GNSS's own offset (ENU m) before media time t_s (s): the median fix - scene of
        the keyframes over the settings' baseline span before it (zero where none)."""
        raw = np.asarray(self._fix) - np.asarray(self._scene)
        base = own_offset(np.asarray(self._t), raw, t_s, self.settings)
        return np.zeros(3) if base is None else base

    @staticmethod
    def _off(kind: str, residual: np.ndarray) -> float:
        """How far (m) a lie of `kind` takes a median residual (3,) fix - scene (ENU m): up
        for a height lie, across otherwise."""
        return float(abs(residual[2]) if kind == HEIGHT else np.linalg.norm(residual[:2]))

    def _stepped(self, lie: GnssLie) -> float:
        """Where a lie caught now began: a `disagrees` lie (horizontal) at the first of the
        keyframes in a row whose own fixes disagree, where the residual stepped into it from
        the keyframe before by more than JUMP_SHARE of the distance at the alarm (a jump: the
        one-sided median at the newest keyframe blurs a step that the files' centred one
        keeps); else where the test put it."""
        first = len(self._dis)
        while first > 0 and self._dis[first - 1]:
            first -= 1
        if lie.kind != DISAGREES or first == 0 or first == len(self._dis):
            return lie.began_s
        step = (self._fix[first] - self._scene[first]) - (
            self._fix[first - 1] - self._scene[first - 1]
        )
        jumped = np.linalg.norm(step[:2]) > JUMP_SHARE * lie.worst_m
        return self._t[first] if jumped else lie.began_s

    def _untested_since(self) -> float | None:
        """Since when (media s) the fixes have gone untested: the last keyframe tested, or the
        end of an outage after it (no fix to test before); None before any keyframe and while an
        outage goes on. Under the lock."""
        if not self._t or self.outage_since is not None:
            return None
        return max([self._t[-1], *(b for _, b in self.outages)])

    def _dated(self, lie: GnssLie) -> GnssLie:
        """A lie caught now (began_s where the test put it), dated anew where the fixes went
        untested before it: where the run of keyframes whose own fixes disagree (or the newest)
        begins an `unseen` span and the test puts the start inside it, the lie began unseen
        within it (`unseen_from_s`, began_s the first keyframe that saw it), unless the
        telemetry's own jump was held off from a frame inside it until that keyframe (a jump:
        dated from that frame; a glitch held off and let go earlier dates nothing)."""
        first = len(self._t) - 1
        while first > 0 and self._dis[first] and self._dis[first - 1]:
            first -= 1
        after = self._t[first]
        span = next((a for a, b in reversed(self.unseen) if b == after), None)
        if span is None or lie.began_s < span:
            return lie
        held = self._held
        if held is not None and span < held[0] <= after and held[1] >= after - HELD_LATE_S:
            return replace(lie, began_s=held[0])
        return replace(lie, began_s=after, unseen_from_s=span)

    def _alarm(self, lie: GnssLie) -> None:
        lie = self._dated(lie)
        self.lying, self._agree_since, self._last_bad_s = True, None, lie.caught_s
        self.lies.append(lie)
        self.messages.add(lie.said(0.0, self.utc_of))

    def _judge(self, t_s: float, bad: bool, residual: np.ndarray) -> None:
        """A keyframe during a lie: how far it has gone, and whether the fixes agree again."""
        lie = self.lies[-1]
        if bad:
            self._agree_since, self._last_bad_s = None, t_s
            off = self._off(lie.kind, residual)
            if off > lie.worst_m:
                self.lies[-1] = replace(lie, worst_s=t_s, worst_m=float(off), ended_s=t_s)
            else:
                self.lies[-1] = replace(lie, ended_s=t_s)
            return
        if self._agree_since is None:
            self._agree_since = t_s
        if t_s - self._agree_since >= self.settings.merge_s:
            self.lying = False
            self.lies[-1] = replace(lie, ended_s=self._last_bad_s)
            self.messages.add(
                f"GNSS agrees with the scene again from {clip_time(self._agree_since, 0.0, self.utc_of)}: used again",
                "info",
            )

    def frame(
        self, t_s: float, fix_age_s: float, held_off_m: float = 0.0, held: bool = False
    ) -> str:
        """The status of the frame of media time t_s (s) drawn now, whose newest fix is
        fix_age_s (s) older than it (inf: none yet), held_off_m (m) of the telemetry's jumps not
        drawn (app.live.register.LiveRegistration.held_off: the fix not used as given, so
        `rejected`), held: its fix no longer current (app.live.register's HELD_S: the scene,
        not the fix, carries it, so `missing`, an outage only past outage_s): counted, and an
        outage said when it ends."""
        with self._lock:
            if held_off_m > 0.0:  # (kept once it ends: the keyframe past it is tested after)
                if self.held_off_m > 0.0 and self._held is not None:
                    self._held[1] = float(t_s)
                else:
                    self._held = [float(t_s), float(t_s)]
            self.held_off_m = held_off_m
            if fix_age_s > self.outage_s:
                status = MISSING
                if self.outage_since is None:
                    self.outage_since = t_s - fix_age_s if math.isfinite(fix_age_s) else t_s
            elif held:  # missing, no outage said yet: a dropout of a second is no outage
                status = MISSING
            else:
                if self.outage_since is not None:
                    span = (self.outage_since, t_s - fix_age_s)
                    self.outages.append(span)
                    self.messages.add(outage_said(*span, 0.0))
                    self.outage_since = None
                status = REJECTED if self.lying or held_off_m > 0.0 else USED
            self.frames[status] += 1
            if self.runs and self.runs[-1][2] == status and t_s >= self.runs[-1][1]:
                self.runs[-1][1] = t_s
            else:
                self.runs.append([t_s, t_s, status])
            return status

    def said_now(self, t_s: float) -> list[tuple[str, str]]:
        """What the viewer says of the frame drawn now (media time t_s s), with the status each
        line speaks of: the alarm while the fixes are rejected, an outage going on."""
        with self._lock:
            out = []
            if self.outage_since is not None:
                gone = t_s - self.outage_since
                out.append(
                    (
                        f"no GNSS since {clip_time(self.outage_since, 0.0, self.utc_of)} ({gone:.0f} s so far)",
                        MISSING,
                    )
                )
            if self.lying:
                out.append((self.lies[-1].said(0.0, self.utc_of), REJECTED))
            elif (since_s := self._untested_since()) is not None and t_s - since_s > UNSEEN_S:
                since, gone = clip_time(since_s, 0.0, self.utc_of), t_s - since_s
                out.append(
                    (
                        f"GNSS untested since {since} ({gone:.0f} s): no keyframe has registered, so a lie would not be seen",
                        USED,
                    )
                )
            if not self.lying and self.held_off_m > 0.0:
                out.append(
                    (
                        f"GNSS jumped {self.held_off_m:.0f} m as no aircraft moves: not drawn until a keyframe past it registers",
                        REJECTED,
                    )
                )
            return out

    def line(self) -> str:
        """The summary's part: frames by status, the lies with their times, the outages."""
        with self._lock:
            n = self.frames
            parts = [
                f"GNSS against the scene ({self.tested} keyframes): {n[USED]} frames used, "
                f"{n[REJECTED]} rejected, {n[MISSING]} missing"
            ]
            for k, lie in enumerate(self.lies):
                going = self.lying and k == len(self.lies) - 1
                end = "going on at the end" if going else f"to t = {lie.ended_s:.1f} s"
                began = f"t = {lie.began_s:.1f} s"
                if lie.unseen_from_s is not None:
                    began = f"between t = {lie.unseen_from_s:.1f} and {lie.began_s:.1f} s"
                parts.append(
                    f"GNSS {lie.kind} from {began} (caught at t = "
                    f"{lie.caught_s:.1f} s, {lie.worst_m:.0f} m by t = {lie.worst_s:.1f} s), {end}"
                )
            parts += [
                f"GNSS untested from t = {a:.1f} to {b:.1f} s ({b - a:.0f} s: no keyframe registered)"
                for a, b in self.unseen
            ]
            parts += [outage_said(a, b, 0.0) for a, b in self.outages]
            if self.outage_since is not None:
                parts.append(f"no GNSS from t = {self.outage_since:.1f} s to the end")
            if not self.lies:
                parts.append("no lie")
            return "; ".join(parts)
