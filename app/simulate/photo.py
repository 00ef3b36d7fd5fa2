"""A sample still "photo" of the site: the model seen from a known pose, plus things the model
lacks (a banner, people, a car), so that a projection shows what imagery adds to the model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFilter, ImageFont

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import DEFAULT_FAR_M, DEFAULT_NEAR_M
from app.core.settings import ProjectionSettings
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.render.still import render_still
from app.scene.mesh import MeshData


@dataclass(frozen=True)
class PhotoPose:
    """Where the sample photo was 'taken': geodetic position and optical-axis angles."""

    lat_deg: float
    lon_deg: float
    h_m: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    hfov_deg: float = 66.0
    width: int = 640
    height: int = 360


def photo_camera(pose: PhotoPose, frame: LocalFrame) -> Camera:
    """The projector camera of a pose in `frame`."""
    position = frame.geodetic_to_enu(pose.lat_deg, pose.lon_deg, pose.h_m)
    q = rotations.camera_quat_from_hpr(pose.heading_deg, pose.pitch_deg, pose.roll_deg)
    return Camera.create(
        Intrinsics.from_fov(pose.width, pose.height, pose.hfov_deg),
        position,
        q,
        near=DEFAULT_NEAR_M,
        far=DEFAULT_FAR_M,
    )


def make_photo(mesh: MeshData, camera: Camera, seed: int = 11) -> np.ndarray:
    """Render the model through `camera` and paint extra content on it: (H, W, 3) uint8."""
    rgb = render_still(mesh, None, camera, camera, ProjectionSettings(enabled=False)).rgb
    img = Image.fromarray(rgb).filter(ImageFilter.GaussianBlur(0.6))
    draw = ImageDraw.Draw(img)
    w, h = img.size
    rng = np.random.default_rng(seed)
    # A red banner hung across the lower part of the view.
    bx0, by0, bx1, by1 = int(w * 0.30), int(h * 0.50), int(w * 0.70), int(h * 0.58)
    draw.rectangle([bx0, by0, bx1, by1], fill=(200, 24, 36), outline=(255, 255, 255), width=2)
    draw.text(
        ((bx0 + bx1) / 2, (by0 + by1) / 2),
        "WELCOME",
        fill=(255, 255, 255),
        font=ImageFont.load_default(size=int(h * 0.06)),
        anchor="mm",
    )
    # People: simple silhouettes standing on the lower third.
    for _ in range(5):
        x = rng.uniform(0.08, 0.92) * w
        base = rng.uniform(0.72, 0.95) * h
        size = base / h * 40
        colour = tuple(int(c) for c in rng.integers(20, 230, 3))
        draw.ellipse(
            [x - size * 0.12, base - size, x + size * 0.12, base - size * 0.76],
            fill=(230, 190, 160),
        )
        draw.rectangle(
            [x - size * 0.18, base - size * 0.76, x + size * 0.18, base - size * 0.3], fill=colour
        )
        draw.rectangle(
            [x - size * 0.14, base - size * 0.3, x + size * 0.14, base], fill=(40, 40, 60)
        )
    # A car at the right.
    cx, cy = w * 0.82, h * 0.86
    draw.rounded_rectangle([cx - 60, cy - 28, cx + 60, cy + 10], radius=10, fill=(30, 90, 170))
    draw.rounded_rectangle([cx - 36, cy - 48, cx + 30, cy - 24], radius=8, fill=(140, 180, 210))
    for dx in (-36, 36):
        draw.ellipse([cx + dx - 12, cy - 2, cx + dx + 12, cy + 22], fill=(20, 20, 20))
    return np.asarray(img, np.uint8)
