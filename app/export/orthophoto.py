"""`geofuse export ortho`: the true orthophoto of a clip, or of several on one timeline, painted
frame by frame (app.export.ortho) and written as Cloud Optimized GeoTIFFs.

Frames are taken and painted as app.export.painting does it (several clips in time order, onto
the first one's scene). The area is the one the frames see (their
footprints' box, or `area` given as lat/lon corners), the cell `gsd` metres (default: the
video's median ground sampling at the footprints' centres, rounded up to 5 cm).

Files: OUT.tif, RGBA uint8 (alpha 0 where the clip saw nothing), and OUT.seen.tif, float64: band
1 the time each cell was seen (UTC s where the clips have a clock, else seconds from the first
frame; NaN unseen),
band 2 its quality (0 unseen); both COGs with overviews, in the grid's CRS (the site's UTM zone
by default). A GeoTIFF holds one sample type, so the picture and its float bands are two files.
OUT.tif credits what its scene's imagery and heights came from (a world's providers:
app.scene.layers.scene_credit) in its TIFFTAG_COPYRIGHT and ATTRIBUTION metadata.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj
import rasterio
from rasterio.enums import ColorInterp
from rasterio.transform import Affine

from app.core.outputs import check_output, write_via_path
from app.export.ortho import Grid, OrthoMemory, make_grid, surface
from app.export.painting import (
    DEFAULT_EVERY_S,
    ClipToPaint,
    clips_on_a_timeline,
    paint_frame_indices,
    paint_frames,
    planned_cameras,
    scene_to_paint,
)
from app.render.views import ModelViews
from app.session.camera_track import CameraTrack
from app.session.model import Session

AREA_MARGIN_M = 5.0
SEEN_SUFFIX = ".seen.tif"


@dataclass(frozen=True)
class OrthoOptions:
    """gsd: metres a cell (None: from the video); crs: the output CRS (None: the site's UTM);
    area: (lat_min, lon_min, lat_max, lon_max) deg or None (what the frames see); rule:
    newest, best or first; every_s: seconds of video between frames painted."""

    gsd: float | None = None
    crs: pyproj.CRS | None = None
    area: tuple[float, float, float, float] | None = None
    rule: str = "newest"
    every_s: float = DEFAULT_EVERY_S


def seen_path(out: Path) -> Path:
    """Where the time and quality bands go beside OUT.tif."""
    return out.with_name(out.stem + SEEN_SUFFIX)


def _ground_box(
    clips: list[ClipToPaint], plans: list[np.ndarray], views: ModelViews
) -> tuple[np.ndarray, np.ndarray, float]:
    """(lo, hi) ENU x, y of what the frames see (the surface under their image's corners and
    centre, from their distance maps), and the median ground sampling (m a video pixel) at
    their centres."""
    points, gsds = [], []
    looked = [(c, k) for c, frames in zip(clips, plans, strict=True) for k in frames[:: max(1, len(frames) // 40)]]  # fmt: skip
    for clip, k in looked:
        cam = clip.camera(int(k))
        _, positions = views.render(cam.pinhole(64 / cam.intrinsics.width))
        p = positions.reshape(-1, 3)
        p = p[np.isfinite(p[:, 0])]
        if len(p):
            points.append(p[:, :2])
            centre = positions[positions.shape[0] // 2, positions.shape[1] // 2]
            if np.all(np.isfinite(centre)):
                rng = float(np.linalg.norm(centre - np.asarray(cam.position)))
                gsds.append(rng / cam.intrinsics.fx)
    if not points:
        raise ValueError("the frames see none of the scene: nothing to paint")
    allp = np.concatenate(points)
    lo, hi = allp.min(axis=0) - AREA_MARGIN_M, allp.max(axis=0) + AREA_MARGIN_M
    return lo, hi, float(np.median(gsds)) if gsds else 0.1


def _grid(
    session: Session,
    clips: list[ClipToPaint],
    plans: list[np.ndarray],
    views: ModelViews,
    options: OrthoOptions,
) -> Grid:
    """The grid over the area given, or what the frames see; cells of the gsd given, or the
    video's ground sampling rounded up to 5 cm (the frames are looked at only when either is
    wanted)."""
    if options.area is None or options.gsd is None:
        lo, hi, video_gsd = _ground_box(clips, plans, views)
    if options.area is not None:
        la0, lo0, la1, lo1 = options.area
        corners = session.frame.geodetic_to_enu(
            np.array([la0, la1]), np.array([lo0, lo1]), np.zeros(2)
        )
        lo, hi = corners.min(axis=0)[:2], corners.max(axis=0)[:2]
    gsd = options.gsd or max(0.05, np.ceil(video_gsd / 0.05) * 0.05)
    return make_grid(session.frame, lo, hi, gsd, options.crs)


def paint_clip(
    session: Session,
    track: CameraTrack,
    options: OrthoOptions = OrthoOptions(),
    progress: Callable[[float], None] | None = None,
    grid: Grid | None = None,
    further: list[tuple[Session, CameraTrack]] = (),
) -> OrthoMemory:
    """The orthophoto memory of a clip under one solved track, with the further clips (session,
    solved track) on its timeline (see the module docstring); on `grid` when given (another
    clip's or source's, to compare them cell by cell)."""
    clips, utc0 = clips_on_a_timeline([(session, track), *further])
    plans = [paint_frame_indices(c.track, options.every_s) for c in clips]
    scene = scene_to_paint(session.scene(), planned_cameras(clips, plans))
    views = ModelViews(scene)
    try:
        grid = grid or _grid(session, clips, plans, views, options)
        points, normals = surface(scene, grid, session.frame)
        memory = OrthoMemory(grid, points, normals, options.rule)
        paint_frames(memory.memory, views, clips, plans, utc0, progress)
    finally:
        views.release()
    return memory


def write_orthophoto(
    memory: OrthoMemory, out: Path, inputs: list[Path], credit: str = ""
) -> tuple[Path, Path]:
    """OUT.tif (RGBA uint8) and OUT.seen.tif (float64 time and quality) as COGs; atomically,
    never over an input; credit: the scene's (scene_credit), written into OUT.tif's metadata
    ('' none). Returns both paths."""
    out = check_output(out, "--out", (".tif", ".tiff"), inputs)
    seen = check_output(seen_path(out), "--out", (".tif",), inputs)
    g: Grid = memory.grid
    rows, cols = g.shape
    transform = Affine(*g.transform)
    rgba = np.concatenate(
        [memory.rgb, np.where(memory.seen, 255, 0).astype(np.uint8)[..., None]], axis=2
    ).transpose(2, 0, 1)
    bands = np.stack([memory.time, memory.quality.astype(np.float64)])

    def write(path: Path, data: np.ndarray, extra: dict) -> None:
        profile = {
            "driver": "COG",
            "width": cols,
            "height": rows,
            "count": data.shape[0],
            "dtype": data.dtype.name,
            "crs": g.crs.to_wkt(),
            "transform": transform,
            "compress": "deflate",
            "overview_resampling": "average" if data.dtype == np.uint8 else "nearest",
            **extra,
        }
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(data)
            if data.shape[0] == 4 and credit:
                dst.update_tags(TIFFTAG_COPYRIGHT=credit, ATTRIBUTION=credit)
            if data.shape[0] == 4:
                dst.colorinterp = [
                    ColorInterp.red,
                    ColorInterp.green,
                    ColorInterp.blue,
                    ColorInterp.alpha,
                ]
            else:
                dst.set_band_description(1, "seen at (UTC s, or session s without a clock)")
                dst.set_band_description(2, "quality (incidence cosine / (1 + range / 100 m))")

    write_via_path(out, "--out", lambda p: write(p, rgba, {}))
    write_via_path(seen, "--out", lambda p: write(p, bands, {"nodata": np.nan}))
    return out, seen
