"""The World Magnetic Model (pygeomag) at a place and time: declination and the field vector."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
from pygeomag import GeoMag, decimal_year_from_date

WMM_EPOCHS = (2010, 2015, 2020, 2025)  # coefficient files pygeomag ships (wmm/WMM_YYYY.COF)


def _wmm(lat: float, lon: float, h_m: float, when_unix_s: float):

    year = decimal_year_from_date(datetime.fromtimestamp(when_unix_s, UTC).date())
    epoch = max([e for e in WMM_EPOCHS if e <= year] or [WMM_EPOCHS[0]])
    gm = GeoMag(coefficients_file=f"wmm/WMM_{epoch}.COF")
    return gm.calculate(
        glat=lat, glon=lon, alt=h_m / 1000.0, time=year, allow_date_outside_lifespan=True
    )


def declination(lat: float, lon: float, h_m: float, when_unix_s: float) -> float:
    """Declination in degrees (east positive) with the model epoch that covers the date (the
    nearest one outside 2010-2030)."""
    return float(_wmm(lat, lon, h_m, when_unix_s).d)


def field_enu(lat: float, lon: float, h_m: float, when_unix_s: float) -> np.ndarray:
    """The main field in uT as East, North, Up components."""
    r = _wmm(lat, lon, h_m, when_unix_s)
    return np.array([r.y, r.x, -r.z]) / 1000.0
