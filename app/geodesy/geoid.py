"""Geoid undulation N (m): ellipsoidal height h = orthometric height H + N (WGS84).

National DEMs, SRTM and the Copernicus DEM give heights above a geoid (EGM96 or EGM2008); GNSS
receivers and geofuse's world frame use heights above the WGS84 ellipsoid. The two differ by
-107 m to +86 m over the globe. geofuse ships EGM2008 on a 10 arc-minute grid
(app/geodesy/data/egm2008_10min.npz, see tools/geoid_grid.py; 3.7 cm RMS against the full 2.5' grid).
EGM96 heights are converted with the same EGM2008 undulations: the two models differ by less than
a metre almost everywhere (a few metres in the Himalaya and the Andes), which callers say.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np
import numpy.typing as npt

VERTICAL_DATUMS = ("ellipsoid", "egm2008", "egm96")
# EPSG codes of vertical CRSs, as GeoTIFFs and compound CRSs name them
EPSG_VERTICAL = {5773: "egm96", 3855: "egm2008", 4979: "ellipsoid", 4326: "ellipsoid"}


@lru_cache(maxsize=1)
def _grid() -> tuple[np.ndarray, float, float, float]:
    with resources.files("app.geodesy").joinpath("data/egm2008_10min.npz").open("rb") as fh:
        z = np.load(fh)
        return (
            z["undulation_cm"].astype(np.float32) / 100.0,
            float(z["lat0_deg"]),
            float(z["lon0_deg"]),
            float(z["step_deg"]),
        )


def undulation(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> np.ndarray:
    """EGM2008 geoid undulation N (m above the WGS84 ellipsoid) at (lat, lon) degrees, bilinear."""
    grid, lat0, lon0, step = _grid()
    lat = np.clip(np.asarray(lat_deg, np.float64), -90.0, 90.0)
    lon = np.mod(np.asarray(lon_deg, np.float64) - lon0, 360.0)
    fi = np.clip((lat - lat0) / step, 0.0, grid.shape[0] - 1.000001)
    fj = np.clip(lon / step, 0.0, grid.shape[1] - 1.000001)
    i, j = np.floor(fi).astype(int), np.floor(fj).astype(int)
    a, b = fi - i, fj - j
    return (
        grid[i, j] * (1 - a) * (1 - b)
        + grid[i + 1, j] * a * (1 - b)
        + grid[i, j + 1] * (1 - a) * b
        + grid[i + 1, j + 1] * a * b
    ).astype(np.float64)


def to_ellipsoidal(
    height_m: npt.ArrayLike, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, datum: str
) -> np.ndarray:
    """Heights (m) above `datum` ('ellipsoid', 'egm2008' or 'egm96') -> above the WGS84 ellipsoid."""
    h = np.asarray(height_m, np.float64)
    if datum == "ellipsoid":
        return h
    if datum not in VERTICAL_DATUMS:
        raise ValueError(
            f"unknown vertical datum {datum!r} (expected one of {', '.join(VERTICAL_DATUMS)})"
        )
    return h + undulation(lat_deg, lon_deg)
