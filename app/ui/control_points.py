"""Control points picked in the viewer: a feature in the draped video, then the same feature on
the model, four pairs or more; solved into the clip's boresight and position correction
(app.register.points), each pair's residual shown, and the points kept beside the input (never
in it), where the `registered` source starts from them.

A pick is a point of the 3D view (x, y in [0, 1] from its top-left corner). "Video" picks the
model point under it and asks the projector which video pixel is draped there (the pixel the
person sees at that place); "model" picks the model point itself (ENU metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.core.errors import GeofuseError
from app.core.outputs import check_output
from app.locate.location import video_pixel
from app.register.points import (
    MIN_PAIRS,
    ControlPoints,
    ControlSolution,
    control_path,
    solve_control,
    write_points,
)
from app.ui.picking import model_point


@dataclass
class ControlPicks:
    """pairs: (video frame, video pixel (u, v), model point ENU m); pending: a video pick waiting
    for its model point; solution: the last solve (None before one)."""

    pairs: list[tuple[int, tuple[float, float], np.ndarray]] = field(default_factory=list)
    pending: tuple[int, tuple[float, float]] | None = None
    solution: ControlSolution | None = None
    saved: str = ""


def pick_video(v, picks: ControlPicks, xy: tuple[float, float]) -> None:
    """The video pixel draped at view point xy, on the frame shown."""
    projector = v.loaded.renderer.projector
    if projector is None:
        raise GeofuseError("no video frame is shown yet")
    pixel = video_pixel(projector, model_point(v, xy))
    if pixel is None:
        raise GeofuseError("the video does not cover that point of the model")
    picks.pending = (max(v.current_index, 0), pixel)


def pick_model(v, picks: ControlPicks, xy: tuple[float, float]) -> None:
    """The model point at view point xy, paired with the pending video pick."""
    if picks.pending is None:
        raise GeofuseError("pick the feature in the video first (V), then on the model (M)")
    frame, uv = picks.pending
    picks.pairs.append((frame, uv, model_point(v, xy)))
    picks.pending = None


def as_points(session, picks: ControlPicks) -> ControlPoints:
    """The pairs as control points (geodetic, ellipsoidal heights)."""
    enu = np.array([p for _, _, p in picks.pairs], np.float64).reshape(-1, 3)
    return ControlPoints(
        np.array([f for f, _, _ in picks.pairs], np.int64), np.array([uv for _, uv, _ in picks.pairs], np.float64).reshape(-1, 2),
        session.frame.enu_to_geodetic(enu),
    )  # fmt: skip


def solve(v, picks: ControlPicks) -> None:
    """Solve against the source shown, keep the points beside the input, and re-register."""
    L = v.loaded
    if len(picks.pairs) < MIN_PAIRS:
        raise GeofuseError(f"{len(picks.pairs)} pairs; pick at least {MIN_PAIRS}")
    track = L.library.track(L.source)
    if track is None:
        raise GeofuseError(f"{L.source} is not solved yet")
    points = as_points(L.session, picks)
    picks.solution = solve_control(track, points)
    for note in picks.solution.notes:  # shown as the session's other warnings are
        L.session.messages.add_once(f"control: {note}", note)
    out = check_output(
        control_path(L.session.path),
        "control points",
        (".csv",),
        list(L.session.inputs) + [L.session.path],
    )
    write_points(out, points)
    picks.saved = str(out)
    L.library.resolve_registered()
