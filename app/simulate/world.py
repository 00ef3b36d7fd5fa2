"""A world that differs from its model, for honest tests of registration: the video is rendered
from this world while the session names the plain model.

What a real site differs by, each modelled here:
- the textures "taken again": another exposure, white balance and gamma, blurred and noisy, with
  weathering stains (a photogrammetry model's textures come from another day and camera);
- objects the model lacks, in front of the facades and on the ground: trees, kiosks, parked
  cars, lamp posts and bins (the sample's moving cars, people and banner come on top);
- another light: the sun from another side, so faces brighten and darken otherwise;
- the video camera's own blur and sensor noise on every frame.

Frames: ENU metres of the site (app.simulate.stadium). Textures are uint8 RGBA, bottom row first
(app.scene.mesh.Primitive).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from app.scene import shapes
from app.scene.mesh import MeshData, Primitive
from app.simulate.stadium import BUILDINGS, HALL_MAX, HALL_MIN


@dataclass(frozen=True)
class Look:
    """How the world's camera saw the textures, against the model's: exposure (a gain), white
    balance (per-channel gains R, G, B), gamma, Gaussian blur (sigma, texels), noise (sigma, grey
    levels), stains (relative depth of low-frequency weathering)."""

    exposure: float = 1.15
    white_balance: tuple[float, float, float] = (1.07, 1.0, 0.88)
    gamma: float = 0.9
    blur_texels: float = 0.8
    noise: float = 6.0
    stains: float = 0.12


@dataclass(frozen=True)
class CameraEffects:
    """The video camera's own optics and sensor: Gaussian blur (sigma, pixels) and noise (sigma,
    grey levels), applied to each rendered frame."""

    blur_px: float = 0.7
    noise: float = 3.0
    seed: int = 11

    def __call__(self, rgb: np.ndarray, k: int) -> np.ndarray:
        out = (
            cv2.GaussianBlur(rgb, (0, 0), self.blur_px).astype(np.float32)
            if self.blur_px > 0
            else rgb.astype(np.float32)
        )
        out += (
            np.random.default_rng((self.seed, k))
            .normal(0.0, self.noise, out.shape)
            .astype(np.float32)
        )
        return np.clip(out + 0.5, 0, 255).astype(np.uint8)


# The sun from the south-west, lower than the viewer's light (app.render.passes.LIGHT_DIR, from the
# south-east): the hall's south front and the buildings' west faces light otherwise.
WORLD_LIGHT = np.array([-0.55, -0.55, 0.63])


@dataclass(frozen=True)
class World:
    """The scene the video is rendered from: mesh (ENU), light direction (ENU, toward the light),
    the camera's effects."""

    mesh: MeshData
    light_dir: np.ndarray
    camera: CameraEffects


def retake_texture(
    texture: np.ndarray, rng: np.random.Generator, look: Look = Look()
) -> np.ndarray:
    """The texture (H, W, 4) uint8 as another camera on another day would have taken it."""
    rgb = texture[..., :3].astype(np.float32) / 255.0
    rgb = np.power(
        np.clip(rgb * look.exposure * np.asarray(look.white_balance, np.float32), 0.0, 1.0),
        look.gamma,
    )
    h, w = rgb.shape[:2]
    coarse = rng.uniform(-1.0, 1.0, (max(2, h // 64), max(2, w // 64))).astype(np.float32)
    stains = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    rgb = rgb * (1.0 + look.stains * stains)[..., None]
    if look.blur_texels > 0:
        rgb = cv2.GaussianBlur(rgb, (0, 0), look.blur_texels)
    rgb = rgb * 255.0 + rng.normal(0.0, look.noise, rgb.shape).astype(np.float32)
    out = texture.copy()
    out[..., :3] = np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
    return out


def _clear(x: float, y: float, r: float) -> bool:
    """True where a footprint of radius r (m) at (x, y) stays off the hall, the buildings, the
    walking path (y = -62 +- 3 m) and the movers' lanes (y -58..-44)."""
    boxes = [(HALL_MIN, HALL_MAX)] + [(b.min_corner, b.max_corner) for b in BUILDINGS]
    for lo, hi in boxes:
        if lo[0] - r - 1 < x < hi[0] + r + 1 and lo[1] - r - 1 < y < hi[1] + r + 1:
            return False
    return not (-65.0 - r < y < -42.5 + r)


def _tree(x: float, y: float, height: float, crown_m: float) -> list[shapes.Shape]:
    trunk = shapes.box([x - 0.2, y - 0.2, 0.0], [x + 0.2, y + 0.2, height * 0.45])
    c = crown_m / 2
    crown = shapes.box([x - c, y - c, height * 0.4], [x + c, y + c, height])
    return [trunk, crown]


def clutter(rng: np.random.Generator) -> list[Primitive]:
    """Objects the model lacks (ENU m): a row of trees and kiosks between the path and the hall's
    south front (they hide parts of it), parked cars, lamp posts and bins, trees elsewhere."""
    trunks, crowns, kiosks, cars, posts = [], [], [], [], []
    for x in np.arange(-70.0, 75.0, 13.0) + rng.uniform(-2.0, 2.0, 12):  # along the hall's front
        y = -41.5 - rng.uniform(0.0, 0.8)
        h = rng.uniform(5.0, 8.0)
        t, c = _tree(float(x), y, h, rng.uniform(2.5, 3.6))
        trunks.append(t)
        crowns.append(c)
    placed = 0
    while placed < 30:  # trees elsewhere on the site
        x, y = rng.uniform(-170, 170, 2)
        if _clear(x, y, 3.0):
            t, c = _tree(float(x), float(y), rng.uniform(6.0, 11.0), rng.uniform(3.0, 5.0))
            trunks.append(t)
            crowns.append(c)
            placed += 1
    for x in (-30.0, 12.0, 38.0):  # kiosks on the path's north verge
        kiosks.append(shapes.box([x - 1.5, -67.5, 0.0], [x + 1.5, -65.5, 2.6]))
    for i, x in enumerate(np.arange(-60.0, 60.0, 5.5)):  # parked cars south of the path
        if rng.uniform() < 0.7:
            cars.append(shapes.box([x - 2.1, -74.0, 0.0], [x + 2.1, -72.2, 1.5 + 0.1 * (i % 3)]))
    for x in np.arange(-60.0, 70.0, 20.0):  # lamp posts and bins along the path
        posts.append(shapes.box([x - 0.1, -64.6, 0.0], [x + 0.1, -64.4, 5.5]))
        posts.append(shapes.box([x + 1.0, -64.9, 0.0], [x + 1.6, -64.3, 0.9]))
    return [
        shapes.Shape.concat(trunks).primitive((0.36, 0.27, 0.18, 1.0), name="world-trunks"),
        shapes.Shape.concat(crowns).primitive((0.22, 0.42, 0.16, 1.0), name="world-crowns"),
        shapes.Shape.concat(kiosks).primitive((0.85, 0.75, 0.35, 1.0), name="world-kiosks"),
        shapes.Shape.concat(cars).primitive((0.35, 0.38, 0.45, 1.0), name="world-cars"),
        shapes.Shape.concat(posts).primitive((0.25, 0.25, 0.27, 1.0), name="world-posts"),
    ]


def world_of(model: MeshData, seed: int = 5, look: Look = Look()) -> World:
    """The world a model stands for: its textures retaken, clutter added, another light."""
    rng = np.random.default_rng(seed)
    prims = [
        replace(p, texture=retake_texture(p.texture, rng, look)) if p.textured else p
        for p in model.primitives
    ]
    return World(MeshData(prims + clutter(rng), list(model.tilesets)), WORLD_LIGHT, CameraEffects())
