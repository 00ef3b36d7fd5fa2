"""What posed each frame, in the viewer (issue 52): the `registered` source's GNSS status per frame
(used, rejected, missing: app.camera.fixes) as coloured runs along the timeline's scrubber, and
what the Stats panel says of the frame shown: its status, and the lie or outage it is in, in the
words of the solve's messages (app.register.gnss.GnssLie.said, app.camera.fixes.outage_said).
Only `registered` tests the fixes against the scene; every other source has no status and says
so. Pure: no imgui (the panels draw what these return). Times are seconds: media time on the
player's clock (the scrubber's, video.pts_s), session time for the fixes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.camera.fixes import MISSING, REJECTED, USED, outage_said
from app.camera.trajectory import gap_intervals
from app.live.gnss_watch import GnssWatch
from app.session.camera_track import CameraTrack
from app.session.model import REGISTERED, Session

RGBA = tuple[float, float, float, float]
COLOURS: dict[str, RGBA] = {  # the timeline's band and the Stats panel's line, 0..1
    USED: (0.30, 0.72, 0.36, 1.0),
    REJECTED: (0.92, 0.22, 0.18, 1.0),
    MISSING: (0.60, 0.60, 0.64, 1.0),
}
CARRIED = "the registered keyframes carry the track"  # as app.solve.track.say_outages says it
MEANING = {
    USED: "the fix is in the track",
    REJECTED: "the fix disagrees with the scene or the IMU's motion: the track stands on the "
    "registered keyframes (and the IMU's motion between them)",
    MISSING: f"no fix: {CARRIED}",
}
LIVE_MEANING = {  # a live frame's status (app.live.gnss_watch)
    USED: "the fix poses it, tested against the registered keyframes",
    REJECTED: "the fix disagrees with the scene: the pose stands on the registered keyframes",
    MISSING: "no fix: the last pose is held",
}
GRAB_PADDING_PX = 2.0  # ImGui's slider: its grab's centre runs this far plus half the grab in


@dataclass(frozen=True)
class Run:
    """Frames in a row with one status: from media time start_s to end_s (s, the player's clock;
    the last frame's run ends at the clip's duration)."""

    start_s: float
    end_s: float
    status: str


@dataclass(frozen=True)
class FrameGnss:
    """The registered track's status of every frame (F,) and its runs along the timeline."""

    track: CameraTrack
    status: npt.NDArray[np.str_]
    runs: tuple[Run, ...]


def frame_gnss(
    track: CameraTrack | None, pts_s: npt.ArrayLike, duration_s: float
) -> FrameGnss | None:
    """The status of each frame of `track` (whose frames play at media times pts_s (F,) s on a
    clock of duration_s s) where it is the `registered` source's and stands on GNSS; else None."""
    if track is None or track.source != REGISTERED or track.fixes is None:
        return None
    status = track.fixes.at(track.clock.session_time(track.clock.media_s))
    return FrameGnss(track, status, runs(status, pts_s, duration_s))


def runs(status: npt.ArrayLike, pts_s: npt.ArrayLike, duration_s: float) -> tuple[Run, ...]:
    """Frames in a row with the same status (F,) as media-time spans: each frame from its own
    time pts_s (F,) s to the next frame's (the first from 0, the last to duration_s)."""
    status = np.asarray(status)
    pts = np.asarray(pts_s, np.float64)
    if len(status) == 0:
        return ()
    edges = np.flatnonzero(status[1:] != status[:-1]) + 1
    starts = np.r_[0, edges]
    ends = np.r_[edges, len(status)]
    out = []
    for a, b in zip(starts, ends, strict=True):
        lo = 0.0 if a == 0 else float(pts[a])
        hi = float(duration_s) if b == len(status) else float(pts[b])
        out.append(Run(lo, max(lo, hi), str(status[a])))
    return tuple(out)


@dataclass(frozen=True)
class FixLines:
    """The GNSS fixes as line segments in the session's ENU frame (m): used (2U, 3) and rejected
    (2R, 3), in pairs (a segment between two consecutive fixes is rejected where either is)."""

    used: npt.NDArray[np.float64]
    rejected: npt.NDArray[np.float64]


def fix_lines(session: Session, track: CameraTrack | None) -> FixLines | None:
    """The raw GNSS track of the session as the `registered` source judged it (its fixes as
    given, the lying ones too: what the receiver said, beside what the scene made of it), or
    None where the track tests no fixes or they are not the session's GNSS fixes. No segment
    spans an outage (app.camera.trajectory.gap_intervals) or a fix without a position."""
    if track is None or track.source != REGISTERED or track.fixes is None:
        return None
    gnss = session.gnss
    if gnss is None or len(gnss.t) != len(track.fixes.t) or len(gnss.t) < 2:
        return None
    enu = session.frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h)
    return segments(enu, track.fixes.rejected, ~np.asarray(gap_intervals(gnss.t), bool))


def segments(enu: npt.ArrayLike, rejected: npt.ArrayLike, joined: npt.ArrayLike) -> FixLines:
    """Consecutive fixes' segments: points enu (N, 3) m, rejected (N,) each fix's verdict,
    joined (N-1,) whether fix i and i+1 are to be joined (not across an outage); a segment with
    a non-finite end is left out."""
    p = np.asarray(enu, np.float64).reshape(-1, 3)
    bad = np.asarray(rejected, bool)
    keep = np.asarray(joined, bool) & np.isfinite(p[:-1]).all(1) & np.isfinite(p[1:]).all(1)
    lying = bad[:-1] | bad[1:]

    def pairs(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
        i = np.flatnonzero(mask)
        return np.stack([p[i], p[i + 1]], axis=1).reshape(-1, 3)

    return FixLines(pairs(keep & ~lying), pairs(keep & lying))


def slider_x(t_s: float, duration_s: float, x0: float, x1: float, grab_px: float) -> float:
    """Where on screen (px) an ImGui slider spanning x0..x1 (px) puts its grab's centre for media
    time t_s (s) of 0..duration_s: the grab's centre runs from GRAB_PADDING_PX + grab_px / 2
    inside either end (ImGui's SliderBehavior), so the band under it lines up with the grab."""
    lo = x0 + GRAB_PADDING_PX + grab_px / 2
    hi = x1 - GRAB_PADDING_PX - grab_px / 2
    return lo + (hi - lo) * float(np.clip(t_s / max(duration_s, 1e-9), 0.0, 1.0))


def frame_said(
    session: Session, source: str, track: CameraTrack | None, index: int
) -> list[tuple[str, str | None]]:
    """What the Stats panel says of frame `index` under `source` (whose solved track is `track`,
    None while it is being solved): lines with the status they speak of (None: no status)."""
    if source != REGISTERED:
        return [
            (
                f"GNSS: no per-frame status under {source}: only `registered` tests the fixes "
                "against the scene",
                None,
            )
        ]
    if track is None:
        return [("GNSS: per-frame status once `registered` is solved", None)]
    if track.fixes is None:
        return [("GNSS: none (the track stands on no GNSS)", None)]
    k = int(np.clip(index, 0, track.frame_count - 1))
    t = float(track.clock.session_time([track.clock.media_s[k]])[0])
    status = str(track.fixes.at([t])[0])
    lines: list[tuple[str, str | None]] = [
        (f"GNSS this frame: {status} ({MEANING[status]})", status)
    ]
    t0 = float(session.frame_times[0])
    check = None if track.registration is None else track.registration.gnss
    if status == REJECTED and check is not None:
        lie = check.lie_at(t)
        if lie is not None:
            lines.append((lie.said(t0, session.utc_of), status))
    elif status == MISSING:
        t1 = float(session.frame_times[-1])
        for a, b in track.fixes.outages(t0, t1):
            if a <= t <= b:
                lines.append((f"{outage_said(a, b, t0)}: {CARRIED}", status))
    return lines


def shown(L) -> FrameGnss | None:
    """The per-frame status the viewer shows for the open session L (app.ui.sessions.Loaded):
    the registered track's while `registered` is the source shown (kept in L.gnss until the
    library's track changes: a time offset applied, a re-solve); None otherwise."""
    if L.source != REGISTERED:
        return None
    track = L.library.track(REGISTERED)
    if track is None:
        return None
    if L.gnss is None or L.gnss.track is not track:
        L.gnss = frame_gnss(track, L.player.schedule.pts, L.clock.duration)
    return L.gnss


def state(L, index: int, band: tuple[float, float, float, float] | None) -> dict:
    """The viewer's GNSS status for a script's `state`: the source, the status of frame `index`
    (None: no status), what the Stats panel says, the timeline band drawn (x at media time 0 and
    at the clip's end, top and bottom y; framebuffer pixels from the top left; None: not drawn)
    and its colours (RGB 0..255)."""
    said = frame_said(L.session, L.source, L.library.track(L.source), index)
    return {
        "source": L.source,
        "frame": next((s for _, s in said if s is not None), None),
        "said": [text for text, _ in said],
        "band": None if band is None else [float(c) for c in band],
        "duration_s": float(L.clock.duration),
        "colours": {k: [round(255 * c) for c in rgba[:3]] for k, rgba in COLOURS.items()},
    }


def live_said(
    watch: GnssWatch | None, status: str | None, t_s: float
) -> list[tuple[str, str | None]]:
    """What the Live and Stats panels say of a stream's frame shown now (media time t_s s, its
    GNSS status; None: none taken yet), with the status each line speaks of (None: no status):
    the status, and while they last the lie's alarm and an outage."""
    if watch is None:
        return [("GNSS: not tested (live registration is off, or no textured scene to register against)", None)]  # fmt: skip
    if status is None:
        return [("GNSS: tested once frames are drawn", None)]
    return [(f"GNSS this frame: {status} ({LIVE_MEANING[status]})", status), *watch.said_now(t_s)]


def live_runs(watch: GnssWatch | None, span: tuple[float, float]) -> tuple[Run, ...]:
    """A stream's frames in a row with one status (app.live.gnss_watch.GnssWatch.runs) over
    the recorded span (first, last media s), on the live scrubber's time (0 at the span's first
    second); () where the fixes are not tested."""
    if watch is None:
        return ()
    t0, t1 = span
    out = []
    for a, b, status in list(watch.runs):
        a, b = max(a, t0), min(b, t1)
        if b >= a:
            out.append(Run(a - t0, b - t0, status))
    return tuple(out)
