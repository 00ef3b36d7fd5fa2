"""An archive in the viewer (`geofuse index`'s GeoParquet): the footprints of every clip near the
open session drawn on the scene, and G (or `archive open X,Y` in a script) over the scene opens
the clip that saw the point under the cursor most head-on, at that moment (app.archive.find).

Opening an archive with no session open first opens the clip of its first indexed row."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import geopandas as gpd
import numpy as np
import shapely

from app.archive import find, place_of, read_clips, read_footprints
from app.core.errors import GeofuseError
from app.scene.ground import ground_heights
from app.ui.measure import refresh
from app.ui.picking import model_point

__all__ = ["ArchiveOverlay", "load", "open_at"]

AREA_MARGIN_DEG = 0.02  # footprints within about 2 km of the session's track are drawn
LIFT_M = 0.3  # outlines just above the ground they are drawn on
PICK_RADIUS_M = 1.0


@dataclass
class ArchiveOverlay:
    """path: the archive; segments: (2N, 3) ENU m of the footprints' outlines near the session;
    footprints, clips: how many are drawn; picked: the last point opened from (lat, lon), and
    the clip and clip time it opened."""

    path: Path
    segments: np.ndarray
    footprints: int
    clips: int
    picked: tuple[float, float] | None = None
    opened: str = ""
    opened_s: float = 0.0


def _outline_segments(v, geometries: gpd.GeoSeries) -> np.ndarray:
    """The footprints' rings as segments on the scene (each vertex at the scene's ground)."""
    s = v.loaded.session
    segs = []
    for geom in geometries:
        for part in shapely.get_parts(geom):
            ring = np.asarray(part.exterior.coords)
            segs.append(np.stack([ring[:-1], ring[1:]], axis=1).reshape(-1, 2))
    if not segs:
        return np.zeros((0, 3))
    lon_lat = np.concatenate(segs)
    enu = s.frame.geodetic_to_enu(lon_lat[:, 1], lon_lat[:, 0], np.full(len(lon_lat), s.frame.h_m))
    z = ground_heights(s.scene(), enu[:, :2])
    enu[:, 2] = np.where(np.isfinite(z), z, enu[:, 2]) + LIFT_M
    return enu


def load(v, path: Path) -> None:
    """Read the archive and draw its footprints near the open session (opening its first clip
    when none is open)."""
    path = Path(path)
    if not path.is_file():
        raise GeofuseError(f"{path}: archive does not exist")
    try:
        if v.loaded is None:
            clips = read_clips(path)
            indexed = clips[clips["status"] == "indexed"]["path"]
            if not len(indexed) or not v.open(Path(indexed.iloc[0])):
                raise GeofuseError(f"{path}: no clip of the archive could be opened")
        g = v.loaded.session.gnss
        m = AREA_MARGIN_DEG
        bbox = (
            float(g.lon.min()) - m,
            float(g.lat.min()) - m,
            float(g.lon.max()) + m,
            float(g.lat.max()) + m,
        )
        rows = read_footprints(path, bbox)
        clips_seen = rows["clip"].nunique()
    except (OSError, ValueError, KeyError, AttributeError) as exc:
        raise GeofuseError(f"{path}: not an archive written by `geofuse index` ({exc})") from exc
    v.ui.archive = ArchiveOverlay(path, _outline_segments(v, rows.geometry), len(rows), clips_seen)
    refresh(v)
    v.ui.info.append(f"{path.name}: {len(rows)} footprints of {clips_seen} clips near this session")


def open_at(v, xy: tuple[float, float], now: float) -> None:
    """Open the clip that saw the scene point under view point xy most head-on, at that time."""
    overlay = v.ui.archive
    if overlay is None:
        raise GeofuseError("open an archive first (a .parquet written by `geofuse index`)")
    p = model_point(v, xy)
    lat, lon, h = v.loaded.session.frame.enu_to_geodetic(p[None])[0]
    hits = find(overlay.path, place_of((float(lat), float(lon)), PICK_RADIUS_M), height_m=float(h))
    if not hits:
        raise GeofuseError(f"no clip of the archive saw {lat:.6f}, {lon:.6f}")
    best = hits[0]
    if Path(best.clip) != Path(v.loaded.session.path) and not v.open(Path(best.clip)):
        raise GeofuseError(f"{best.clip}: could not be opened")
    v.loaded.clock.set_paused(True, now)
    v.loaded.player.seek(best.frame_s, now)
    load(v, overlay.path)
    v.ui.archive.picked = (float(lat), float(lon))
    v.ui.archive.opened, v.ui.archive.opened_s = best.clip, best.frame_s
