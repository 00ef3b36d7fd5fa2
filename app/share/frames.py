"""What is shared of one frame (pure: no GL, no I/O): the sensor's place and attitude, its field
of view, the point of interest (where the optical axis meets the scene), the footprint as a
polygon, what posed the frame, and a small picture of it.

Frames: WGS84 latitude/longitude in degrees, heights in metres above the WGS84 ellipsoid (and
above mean sea level, EGM2008, where a receiver wants that); heading, pitch, roll of the optical
axis in degrees (DESIGN.md); times in seconds (media time from the first frame; UTC as Unix
seconds where the clip has a clock)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
import shapely
from PIL import Image

from app.export.footprint import plan_footprint
from app.export.records import FrameRecord

__all__ = ["SharedFrame", "shared_frame", "thumbnail_jpeg"]

THUMBNAIL_WIDTH_PX = 320
THUMBNAIL_QUALITY = 70


def _finite(values) -> tuple[float, ...] | None:
    t = tuple(float(v) for v in values)
    return t if all(math.isfinite(v) for v in t) else None


@dataclass(frozen=True)
class SharedFrame:
    """One frame as the sinks see it. sensor: (lat, lon, h ellipsoidal m); sensor_msl_m: its
    height above mean sea level; hpr: heading, pitch, roll of the optical axis (deg); centre:
    (lat, lon, h) of the point of interest, None where the axis meets nothing within range;
    footprint: a GeoJSON geometry (Polygon or MultiPolygon, lon/lat), None where the frame sees
    no ground; source: the pose source drawn (e.g. "registered", "klv"); gnss: what the position
    stands on (used, rejected, missing; None: no GNSS); thumbnail: a JPEG of the frame or None."""

    clip: str
    index: int
    media_s: float
    utc_s: float | None
    sensor: tuple[float, float, float]
    sensor_msl_m: float
    hpr: tuple[float, float, float]
    hfov_deg: float
    vfov_deg: float
    centre: tuple[float, float, float] | None
    centre_msl_m: float | None
    slant_m: float | None
    footprint: dict | None
    source: str
    gnss: str | None = None
    thumbnail: bytes | None = None

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (the thumbnail left out: it is served apart)."""
        return {
            "clip": self.clip,
            "index": self.index,
            "media_s": self.media_s,
            "utc_s": self.utc_s,
            "sensor": list(self.sensor),
            "sensor_msl_m": self.sensor_msl_m,
            "heading_deg": self.hpr[0],
            "pitch_deg": self.hpr[1],
            "roll_deg": self.hpr[2],
            "hfov_deg": self.hfov_deg,
            "vfov_deg": self.vfov_deg,
            "centre": None if self.centre is None else list(self.centre),
            "centre_msl_m": self.centre_msl_m,
            "slant_m": self.slant_m,
            "footprint": self.footprint,
            "source": self.source,
            "gnss": self.gnss,
            "thumbnail": self.thumbnail is not None,
        }


def shared_frame(record: FrameRecord, source: str, thumbnail: bytes | None = None) -> SharedFrame:
    """The SharedFrame of an export record (app.export.records.FrameRecord)."""
    centre = _finite(record.centre)
    polygon = plan_footprint(record.ground)
    return SharedFrame(
        clip=record.clip,
        index=int(record.index),
        media_s=float(record.media_s),
        utc_s=None if record.utc_s is None else float(record.utc_s),
        sensor=tuple(float(v) for v in record.sensor),
        sensor_msl_m=float(record.sensor_msl_m),
        hpr=tuple(float(v) for v in record.hpr),
        hfov_deg=float(record.hfov_deg),
        vfov_deg=float(record.vfov_deg),
        centre=centre,
        centre_msl_m=None if centre is None else float(record.centre_msl_m),
        slant_m=None if centre is None else float(record.slant_m),
        footprint=None if polygon is None else shapely.geometry.mapping(polygon),
        source=source,
        gnss=record.gnss,
        thumbnail=thumbnail,
    )


def thumbnail_jpeg(rgb: np.ndarray, width_px: int = THUMBNAIL_WIDTH_PX) -> bytes:
    """A JPEG of an (H, W, 3) uint8 RGB frame scaled to `width_px` across (never up)."""
    image = Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8))
    if image.width > width_px:
        image = image.resize(
            (width_px, max(1, round(image.height * width_px / image.width))), Image.BILINEAR
        )
    out = io.BytesIO()
    image.save(out, "JPEG", quality=THUMBNAIL_QUALITY)
    return out.getvalue()
