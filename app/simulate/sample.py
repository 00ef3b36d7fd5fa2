"""The bundled sample: paths and the sample photo's pose. `make demo` goes through here."""

from __future__ import annotations

from pathlib import Path

from app.simulate.photo import PhotoPose
from app.simulate.stadium import SITE_ORIGIN

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_DIR = ROOT / "assets" / "sample"
SAMPLE_SCENE = SAMPLE_DIR / "scene.glb"
SAMPLE_PHOTO = SAMPLE_DIR / "photo.jpg"
SAMPLE_ORIGIN = SITE_ORIGIN
# Standing on the track south-east of the hall, 1.6 m above the ground, looking at its south front.
SAMPLE_PHOTO_POSE = PhotoPose(
    lat_deg=34.799345,
    lon_deg=113.530262,
    h_m=111.6,
    heading_deg=348.0,
    pitch_deg=7.0,
    roll_deg=-1.5,
)
