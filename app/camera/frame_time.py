"""Frame times on one page: which video frame is shown at a media time (`frame_at`), which frame
a decoded frame's or a record's own time is (`frame_of`), and the one correction from the
pipeline's frame times to the session clock (`corrected_times`: a time offset and a clock drift,
as `geofuse sync` finds them). Media time: seconds from the video's first frame (its
presentation times, app.io.video.media_seconds); session time: the session clock's seconds.
Pure numpy, so every layer may use it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FRAME_TIME_TOLERANCE_S = 1e-6  # a media time this close to a frame's is that frame's


def frame_at(pts_s: np.ndarray, t_media: float) -> int:
    """The frame shown at media time t (s from the first frame), as a player shows it: the last
    frame whose presentation time is at or before t (FRAME_TIME_TOLERANCE_S absorbs rounding),
    the first before it. The one answer to "which frame at t" for the viewer, `render --session`,
    `export --from/--to` and the exports."""
    k = int(np.searchsorted(pts_s, float(t_media) + FRAME_TIME_TOLERANCE_S, side="right")) - 1
    return min(max(0, k), len(pts_s) - 1)


def frame_of(pts_s: np.ndarray, t_media: float) -> int | None:
    """The frame whose own presentation time is t (a decoded frame's or a packet's, or a record's
    written from it), whatever either clock's rounding: the nearest frame, when within half its
    interval to the next; None otherwise."""
    k = frame_at(pts_s, t_media)
    if k + 1 < len(pts_s) and pts_s[k + 1] - t_media < t_media - pts_s[k]:
        k += 1
    # Half the shorter of its intervals to its neighbours (only those two: this runs per frame).
    gaps = [pts_s[j + 1] - pts_s[j] for j in (k - 1, k) if 0 <= j and j + 1 < len(pts_s)]
    half = 0.5 * min(gaps) if gaps else np.inf
    return k if abs(pts_s[k] - t_media) <= half else None


def frame_span(
    pts_s: np.ndarray, start_s: float | None = None, end_s: float | None = None
) -> tuple[int, int]:
    """(first, last) frame shown from media time start_s to end_s (s; None: the clip's ends), by
    frame_at. Raises ValueError when no frame lies between them."""
    first = frame_at(pts_s, start_s) if start_s is not None else 0
    last = frame_at(pts_s, end_s) if end_s is not None else len(pts_s) - 1
    if (start_s is not None and end_s is not None and end_s < start_s) or first > last:
        raise ValueError(
            f"no frame between {start_s} and {end_s} s (the video runs 0 to {pts_s[-1]:.3f} s)"
        )
    return first, last


def corrected_times(
    session_s: npt.ArrayLike, offset_s: float, drift_ppm: float = 0.0, pivot_s: float = 0.0
) -> np.ndarray:
    """Session times (s) with a time offset (s) and a clock drift (parts per million, about the
    session time pivot_s) applied: t + offset_s + drift_ppm 1e-6 (t - pivot_s). The manifest's
    "auto" offset, the viewer's Sync button and its offset slider all go through here."""
    t = np.asarray(session_s, np.float64)
    return t + offset_s + drift_ppm * 1e-6 * (t - pivot_s)
