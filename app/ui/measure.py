"""Point, measure and mark in the viewer (app.locate.marks): a pick (L, or `measure pick` in a script)
takes the model point under the cursor in the 3D view; where the video is draped there, the
point is located as the video's pixel sees it (app.locate.location: the ray through that pixel, with the
uncertainty the pose's error explains), else as the model point itself. The picks make the
current measurement (point, line or polygon); Mark keeps it with a label, the clip and the frame
shown; marks are written beside the input after each change (never into it) and read back when
the session opens again."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.core.errors import DataFormatError, GeofuseError
from app.core.outputs import check_output, write_atomically
from app.geodesy.geoid import undulation
from app.locate.location import (
    Location,
    feature_tolerance,
    location_of,
    ray_camera,
    video_pixel,
)
from app.locate.marks import KINDS, MIN_POINTS, Mark, marks_path, measure, read_marks, write_marks
from app.scene.city.model import Feature
from app.solve.uncertainty import PoseSigmas, pose_sigmas
from app.ui.picking import model_point

MARK_SUFFIXES = (".geojson", ".json", ".kml")


@dataclass
class Pick:
    """A picked point: enu (3,) m; location: as the video sees it (None: not in the video);
    frame and media_s: the frame shown; feature: the city object it lies on (None: none)."""

    enu: np.ndarray
    location: Location | None
    frame: int
    media_s: float
    feature: Feature | None = None


@dataclass
class MeasureState:
    """kind: what the picks make (KINDS); picks: the current measurement's; marks: kept;
    label: the Mark field; saved: where the marks are kept ('' before any)."""

    kind: str = "line"
    picks: list[Pick] = field(default_factory=list)
    marks: list[Mark] = field(default_factory=list)
    label: str = ""
    saved: str = ""
    focus: bool = False  # bring the Measure panel to the front (after a pick)
    hover_on: bool = True  # read the point under the cursor as it moves (the panel's checkbox)
    hover: Pick | None = None  # the point under the cursor, as last read
    hover_xy: tuple[float, float] | None = None
    hover_at: float = -1e9  # clock time of that reading, s

    def points(self) -> np.ndarray:
        return np.array([p.enu for p in self.picks], np.float64).reshape(-1, 3)


def _sigmas(v) -> PoseSigmas | None:
    L = v.loaded
    track = L.library.track(L.source)
    return None if track is None else pose_sigmas(L.session, track)


def locate_at(v, xy: tuple[float, float]) -> Pick:
    """The point under view point xy (in [0, 1] of the 3D view) on the frame shown."""
    L = v.loaded
    p = model_point(v, xy)
    location = None
    projector = L.renderer.projector
    pixel = None if projector is None else video_pixel(projector, p)
    if pixel is not None:
        ray = ray_camera(projector, pixel)
        found = location_of(
            L.renderer.pick_map(ray), ray, pixel, L.session.frame, _sigmas(v), L.renderer.scene.mesh
        )
        # the video's own ray meets this very point (not an occluder in front of it)
        if found is not None and np.linalg.norm(np.asarray(found.enu) - p) < 0.05 * max(
            1.0, found.range_m
        ):
            location = found
    index = max(v.current_index, 0)
    eye = p if v.window_camera is None else np.asarray(v.window_camera.position, np.float64)
    distance = float(np.linalg.norm(p - eye))
    return Pick(
        p,
        location,
        index,
        float(L.session.video.pts_s[index]) if index >= 0 else 0.0,
        L.renderer.scene.mesh.feature_at(p, feature_tolerance(distance)),
    )


HOVER_EVERY_S = 0.2  # the point under a moving cursor is read at most this often (a position pass)


def hover(v, now: float, over_panels: bool) -> None:
    """Read the point under the cursor when it has moved (at most every HOVER_EVERY_S)."""
    state = v.ui.measure
    xy = None if over_panels or v.loaded is None else v.cursor_in_view()
    if not state.hover_on or xy is None:
        state.hover, state.hover_xy = None, None
        return
    if xy == state.hover_xy or now - state.hover_at < HOVER_EVERY_S:
        return
    try:
        state.hover = locate_at(v, xy)
    except GeofuseError:
        state.hover = None
    state.hover_xy, state.hover_at = xy, now


def pick(v, xy: tuple[float, float]) -> None:
    """Add the point under xy to the current measurement (a point mark keeps only the last)."""
    state = v.ui.measure
    found = locate_at(v, xy)
    state.picks = [found] if state.kind == "point" else state.picks + [found]
    state.focus = True
    refresh(v)


def set_kind(v, kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"expected one of {', '.join(KINDS)}, got {kind!r}")
    v.ui.measure.kind = kind
    v.ui.measure.picks = v.ui.measure.picks[-1:] if kind == "point" else v.ui.measure.picks


def _common_object(picks: list[Pick]) -> dict | None:
    """The city object every pick lies on (as Feature.as_dict), None if they are not one."""
    features = [p.feature for p in picks]
    if not features or any(f is None for f in features):
        return None
    if len({(f.layer, f.id) for f in features}) != 1:
        return None
    surfaces = {f.surface for f in features}
    out = features[0].as_dict()
    out["surface"] = surfaces.pop() if len(surfaces) == 1 else "several"
    return out


def keep(v, label: str) -> None:
    """Keep the current measurement as a mark with this label, and save the marks."""
    state, L = v.ui.measure, v.loaded
    if len(state.picks) < MIN_POINTS[state.kind]:
        raise GeofuseError(
            f"a {state.kind} needs {MIN_POINTS[state.kind]} picks or more (L over the model), got {len(state.picks)}"
        )
    first = state.picks[0]
    state.marks.append(
        Mark(
            state.kind,
            label.strip() or f"{state.kind} {len(state.marks) + 1}",
            Path(L.session.video.path).name,
            first.frame,
            first.media_s,
            state.points(),
            _common_object(state.picks),
        )
    )
    state.picks, state.label = [], ""
    save(v)
    refresh(v)


def save(v) -> Path:
    """The marks beside the input: NAME.marks.geojson (never the input itself)."""
    L = v.loaded
    out = export(v, marks_path(L.session.path))
    v.ui.measure.saved = str(out)
    return out


def export(v, path: Path) -> Path:
    """The marks as GeoJSON or KML at `path` (checked: never one of the inputs)."""
    L, state = v.loaded, v.ui.measure
    out = check_output(path, "marks", MARK_SUFFIXES, [*L.session.inputs, L.session.path])
    write_atomically(
        out,
        "marks",
        lambda f: write_marks(state.marks, L.session.frame, f, out.suffix.lower(), out.stem),
    )
    return out


def load(v) -> None:
    """The marks kept beside the session's input, if any: a file that cannot be read, and each
    feature in it that is no mark (left out, the others read), is an error panel entry."""
    L = v.loaded
    path = marks_path(L.session.path)
    v.ui.measure = MeasureState()
    if path.is_file():

        def skip(exc: DataFormatError) -> None:
            v.ui.error(f"{exc}: left out (keeping a mark rewrites the file without it)")

        try:
            v.ui.measure.marks = read_marks(path, L.session.frame, skip)
            v.ui.measure.saved = str(path)
        except DataFormatError as exc:
            v.ui.error(str(exc))
    refresh(v)


def goto(v, index: int, now: float) -> None:
    """Seek to the frame mark `index` (from 1) was taken from, paused there."""
    marks = v.ui.measure.marks
    if not 1 <= index <= len(marks):
        raise ValueError(f"there are {len(marks)} marks; got {index}")
    L = v.loaded
    L.clock.set_paused(True, now)
    L.player.seek(marks[index - 1].media_s, now)


def remove(v, index: int) -> None:
    marks = v.ui.measure.marks
    if not 1 <= index <= len(marks):
        raise ValueError(f"there are {len(marks)} marks; got {index}")
    del marks[index - 1]
    save(v)
    refresh(v)


def readout(p: Pick) -> str:
    """The picked point for people: as the video sees it, or the model point; the city object
    it lies on."""
    if p.location is not None:
        return p.location.line().split(": ", 1)[1]
    on = "" if p.feature is None else f"; on {p.feature.line()}"
    return "on the model, not in the video: " + ", ".join(f"{c:.2f}" for c in p.enu) + f" m ENU{on}"


def geodetic(v, p: Pick) -> tuple[float, float, float, float]:
    """(lat, lon, ellipsoidal h, sea-level h) of a pick."""
    lat, lon, h = v.loaded.session.frame.enu_to_geodetic(p.enu[None])[0]
    return float(lat), float(lon), float(h), float(h - undulation(lat, lon))


def summary(v) -> str:
    """The current measurement in a line, with the frame time."""
    state = v.ui.measure
    if not state.picks:
        return ""
    m = measure(state.points())
    t = state.picks[-1].media_s
    if state.kind == "point" or len(state.picks) == 1:
        return f"{readout(state.picks[-1])} (at {t:.2f} s)"
    return f"{m.line() if state.kind == 'polygon' else m.line().split(', area')[0]} (at {t:.2f} s)"


def refresh(v) -> None:
    """The current measurement, the marks (and an archive's footprints: app.ui.archive) as lines
    over the scene."""
    state = v.ui.measure
    segments = []

    def path(points: np.ndarray, closed: bool) -> None:
        pts = np.vstack([points, points[:1]]) if closed and len(points) > 2 else points
        if len(pts) == 1:  # a point: a small vertical tick
            pts = np.vstack([pts, pts + [0.0, 0.0, 2.0]])
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            segments.extend((a, b))

    for m in state.marks:
        path(np.asarray(m.points), m.kind == "polygon")
    if state.picks:
        path(state.points(), state.kind == "polygon")
    lift = np.array([0.0, 0.0, 0.15])  # just above the surface they lie on
    lines = np.array(segments).reshape(-1, 3) + lift
    archive = v.ui.archive
    if archive is not None and len(archive.segments):
        lines = np.concatenate([archive.segments, lines])
    v.loaded.renderer.set_outlines(lines if len(lines) else None)
