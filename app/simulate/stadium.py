"""The sample site: a stadium hall like the paper's (90 m x 81 m x 20 m) near 34.80 N 113.53 E,
on textured ground, with five surrounding buildings of different heights that occlude parts of
it, and facades whose detail makes misalignment visible (window grids, doors, large letters and
numbers). Built procedurally from a seed; the same seed gives the same GLB bytes.

Layout, in the site's ENU frame (metres; x = East, y = North, z = Up, ground at z = 0):
the hall spans x -45..45, y -40.5..40.5; a running track lies south of it, car parks and paths
around it. The GLB is written in glTF's Y-up axes (X = East, Y = Up, Z = South).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw, ImageFont

from app.scene import shapes

SITE_ORIGIN = (34.80, 113.53, 110.0)  # lat deg, lon deg, ellipsoidal height m
HALL_MIN = (-45.0, -40.5, 0.0)
HALL_MAX = (45.0, 40.5, 20.0)
GROUND_HALF = 180.0  # the ground square is 360 m across
GROUND_PX = 2048
FACADE_M_PER_PX = 0.1
JPEG_QUALITY = 82


@dataclass(frozen=True)
class Building:
    name: str
    min_corner: tuple[float, float, float]
    max_corner: tuple[float, float, float]
    wall_rgb: tuple[int, int, int]
    floor_m: float = 3.5


BUILDINGS = (
    Building("1", (70.0, -30.0, 0.0), (100.0, 10.0, 36.0), (176, 160, 140)),
    Building("2", (-110.0, 20.0, 0.0), (-80.0, 60.0, 24.0), (150, 160, 176)),
    Building("3", (-20.0, 68.0, 0.0), (25.0, 88.0, 14.0), (190, 170, 150)),
    Building("4", (58.0, -132.0, 0.0), (84.0, -104.0, 48.0), (140, 150, 150)),
    Building("5", (-104.0, -62.0, 0.0), (-76.0, -36.0, 10.0), (200, 185, 160), 5.0),
)


def _font(size: int) -> ImageFont.FreeTypeFont:
    return ImageFont.load_default(size=size)


def _jpeg(img: Image.Image) -> Image.Image:
    """Re-open as JPEG so that the GLB stores compact JPEG textures (trimesh keeps the format)."""
    buf = io.BytesIO()
    img.convert("RGB").save(buf, format="JPEG", quality=JPEG_QUALITY, optimize=True)
    buf.seek(0)
    return Image.open(buf)


def _noise(rng: np.random.Generator, shape: tuple[int, int], scale: int) -> np.ndarray:
    """Smooth value noise in [-1, 1] of the given (h, w) from a coarse grid upsampled by `scale`."""
    coarse = rng.uniform(-1, 1, (shape[0] // scale + 2, shape[1] // scale + 2)).astype(np.float32)
    img = Image.fromarray(((coarse + 1) * 127.5).astype(np.uint8)).resize(
        ((shape[1] // scale + 2) * scale, (shape[0] // scale + 2) * scale), Image.BICUBIC
    )
    return np.asarray(img, np.float32)[: shape[0], : shape[1]] / 127.5 - 1.0


def ground_texture(rng: np.random.Generator) -> Image.Image:
    """Top-down texture of the 360 m ground square: grass, a running track, paths, car parks."""
    n = GROUND_PX
    m_per_px = 2 * GROUND_HALF / n
    grass = np.array([86, 128, 62], np.float32)
    base = (
        grass
        + 18 * _noise(rng, (n, n), 32)[..., None]
        + 6 * rng.standard_normal((n, n, 1)).astype(np.float32)
    )
    img = Image.fromarray(np.clip(base, 0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(img)

    def px(e: float, nn: float) -> tuple[float, float]:  # ENU metres -> image pixel (row 0 = north)
        return ((e + GROUND_HALF) / m_per_px, (GROUND_HALF - nn) / m_per_px)

    def rect(e0: float, n0: float, e1: float, n1: float, **kw: object) -> None:
        (x0, y1), (x1, y0) = px(e0, n0), px(e1, n1)
        draw.rectangle([x0, y0, x1, y1], **kw)

    # Plaza around the hall and paths to the edges.
    rect(-55, -50, 55, 50, fill=(168, 164, 156))
    for e0, n0, e1, n1 in (
        (-3, 50, 3, 180),
        (-3, -180, 3, -50),
        (55, -3, 180, 3),
        (-180, -3, -55, 3),
    ):
        rect(e0, n0, e1, n1, fill=(150, 146, 140))
    # Running track south of the hall: 8 lanes around a grass infield, white lane lines.
    cx, cy, straight, r_in = 0.0, -88.0, 60.0, 14.0
    for radius, colour in ((r_in + 9.8, (176, 82, 60)), (r_in, (70, 130, 60))):
        x0, y0 = px(cx - straight / 2 - radius, cy + radius)
        x1, y1 = px(cx + straight / 2 + radius, cy - radius)
        draw.rounded_rectangle([x0, y0, x1, y1], radius=radius / m_per_px, fill=colour)
    for lane in range(1, 8):
        radius = r_in + lane * 1.22
        x0, y0 = px(cx - straight / 2 - radius, cy + radius)
        x1, y1 = px(cx + straight / 2 + radius, cy - radius)
        draw.rounded_rectangle(
            [x0, y0, x1, y1], radius=radius / m_per_px, outline=(240, 240, 235), width=1
        )
    # Finish line and lane numbers.
    x0, y0 = px(cx + 10, cy - r_in)
    x1, y1 = px(cx + 10.6, cy - r_in - 9.8)
    draw.rectangle([x0, y0, x1, y1], fill=(250, 250, 250))
    # Car parks west and east, with bay lines.
    for e0 in (-160.0, 110.0):
        rect(e0, -40, e0 + 50, 40, fill=(64, 64, 68))
        for k in range(0, 31):
            n_line = -40 + k * 2.6
            x0, y0 = px(e0 + 2, n_line)
            x1, _ = px(e0 + 22, n_line)
            draw.line([x0, y0, x1, y0], fill=(230, 230, 220), width=1)
            x0, _ = px(e0 + 28, n_line)
            x1, _ = px(e0 + 48, n_line)
            draw.line([x0, y0, x1, y0], fill=(230, 230, 220), width=1)
    # Large painted letters on the plaza, readable from above: north arrow text.
    font = _font(int(8 / m_per_px))
    draw.text(px(-6, 49), "N", fill=(250, 250, 250), font=font)
    draw.text(px(-20, -44), "GATE A", fill=(250, 220, 60), font=_font(int(5 / m_per_px)))
    return img


def _facade(
    width_m: float, height_m: float, wall: tuple[int, int, int], rng: np.random.Generator
) -> tuple[Image.Image, ImageDraw.ImageDraw, float]:
    w = max(8, int(round(width_m / FACADE_M_PER_PX)))
    h = max(8, int(round(height_m / FACADE_M_PER_PX)))
    base = np.array(wall, np.float32) + 10 * _noise(rng, (h, w), 16)[..., None]
    img = Image.fromarray(np.clip(base, 0, 255).astype(np.uint8))
    return img, ImageDraw.Draw(img), w / width_m


def _windows(
    draw: ImageDraw.ImageDraw,
    ppm: float,
    height_m: float,
    x0_m: float,
    x1_m: float,
    floor_m: float,
    bay_m: float,
    first_floor: int = 1,
    frame: tuple[int, int, int] = (60, 60, 64),
    glass: tuple[int, int, int] = (70, 100, 130),
) -> None:
    """A grid of windows on the wall between x0_m and x1_m (metres along the strip)."""
    floors = int(height_m // floor_m)
    bays = int((x1_m - x0_m - 1.0) // bay_m)
    margin = (x1_m - x0_m - bays * bay_m) / 2
    for f in range(first_floor, floors):
        top = height_m - (f * floor_m + floor_m * 0.75)
        bottom = height_m - (f * floor_m + floor_m * 0.2)
        for b in range(bays):
            left = x0_m + margin + b * bay_m + bay_m * 0.2
            right = x0_m + margin + (b + 1) * bay_m - bay_m * 0.2
            draw.rectangle(
                [left * ppm, top * ppm, right * ppm, bottom * ppm],
                fill=glass,
                outline=frame,
                width=max(1, int(0.15 * ppm)),
            )
            mid = (left + right) / 2
            draw.line(
                [mid * ppm, top * ppm, mid * ppm, bottom * ppm],
                fill=frame,
                width=max(1, int(0.1 * ppm)),
            )


def _centred_text(
    draw: ImageDraw.ImageDraw,
    text: str,
    centre_px: tuple[float, float],
    size_px: int,
    fill: tuple[int, int, int],
) -> None:
    draw.text(centre_px, text, fill=fill, font=_font(size_px), anchor="mm")


def hall_texture(rng: np.random.Generator) -> Image.Image:
    """The hall's walls as one strip (south, east, north, west): glazing bands, doors, big
    letters on the south front, a big number and compass letter on every wall."""
    spans = shapes.wall_spans(HALL_MIN, HALL_MAX)
    height = HALL_MAX[2] - HALL_MIN[2]
    img, draw, ppm = _facade(spans[-1][2], height, (214, 206, 190), rng)
    # Coloured plinth and a roof band.
    draw.rectangle([0, (height - 1.0) * ppm, img.width, img.height], fill=(120, 110, 100))
    draw.rectangle([0, 0, img.width, 1.2 * ppm], fill=(90, 96, 110))
    numbers = {"S": "1", "E": "2", "N": "3", "W": "4"}
    for facing, x0, x1 in spans:
        width = x1 - x0
        _windows(draw, ppm, height, x0 + 2, x1 - 2, floor_m=6.0, bay_m=4.5, first_floor=1)
        # Doors at ground level: three double doors per wall.
        for k in (0.25, 0.5, 0.75):
            centre = x0 + width * k
            draw.rectangle(
                [
                    (centre - 2.0) * ppm,
                    (height - 3.2) * ppm,
                    (centre + 2.0) * ppm,
                    (height - 0.05) * ppm,
                ],
                fill=(40, 44, 52),
                outline=(200, 200, 200),
                width=2,
            )
            draw.line(
                [centre * ppm, (height - 3.2) * ppm, centre * ppm, height * ppm],
                fill=(200, 200, 200),
                width=2,
            )
        # Big wall number near the west end of each wall, compass letter near the east end.
        _centred_text(
            draw, numbers[facing], ((x0 + 6) * ppm, 8.5 * ppm), int(9 * ppm), (180, 30, 30)
        )
        _centred_text(draw, facing, ((x1 - 6) * ppm, 8.5 * ppm), int(7 * ppm), (30, 60, 160))
    # The south front carries the name in 4 m letters.
    s0, s1 = spans[0][1], spans[0][2]
    draw.rectangle([(s0 + 15) * ppm, 3.6 * ppm, (s1 - 15) * ppm, 9.6 * ppm], fill=(250, 250, 245))
    _centred_text(
        draw, "GEOFUSE ARENA", (((s0 + s1) / 2) * ppm, 6.6 * ppm), int(4.2 * ppm), (20, 40, 120)
    )
    return img


def roof_texture(rng: np.random.Generator) -> Image.Image:
    """Roof seen from above (image top = north): panels, skylights and a big painted 'H'."""
    w_m, h_m = HALL_MAX[0] - HALL_MIN[0], HALL_MAX[1] - HALL_MIN[1]
    ppm = 6.0
    img = Image.new("RGB", (int(w_m * ppm), int(h_m * ppm)), (120, 124, 128))
    draw = ImageDraw.Draw(img)
    for k in range(1, int(w_m // 3)):
        draw.line([k * 3 * ppm, 0, k * 3 * ppm, img.height], fill=(104, 108, 112), width=1)
    for row in range(3):
        for col in range(6):
            x = (8 + col * 13) * ppm
            y = (10 + row * 25) * ppm
            draw.rectangle(
                [x, y, x + 6 * ppm, y + 4 * ppm], fill=(150, 190, 220), outline=(70, 70, 70)
            )
    _centred_text(draw, "H", (img.width / 2, img.height / 2), int(18 * ppm), (240, 200, 40))
    return img


def building_texture(b: Building, rng: np.random.Generator) -> Image.Image:
    spans = shapes.wall_spans(b.min_corner, b.max_corner)
    height = b.max_corner[2] - b.min_corner[2]
    img, draw, ppm = _facade(spans[-1][2], height, b.wall_rgb, rng)
    for _facing, x0, x1 in spans:
        _windows(draw, ppm, height, x0 + 1, x1 - 1, floor_m=b.floor_m, bay_m=3.2, first_floor=0)
        draw.rectangle(
            [
                ((x0 + x1) / 2 - 1.5) * ppm,
                (height - 2.8) * ppm,
                ((x0 + x1) / 2 + 1.5) * ppm,
                height * ppm,
            ],
            fill=(50, 40, 36),
        )
        _centred_text(
            draw,
            f"B{b.name}",
            (((x0 + x1) / 2) * ppm, min(4.0, height * 0.25) * ppm),
            int(min(5.0, height * 0.3) * ppm),
            (240, 240, 240),
        )
    return img


def _enu_to_gltf(v: np.ndarray) -> np.ndarray:
    """ENU (x=E, y=N, z=U) -> glTF Y-up axes (X=E, Y=U, Z=-N)."""
    return np.column_stack([v[:, 0], v[:, 2], -v[:, 1]])


def _textured(shape: shapes.Shape, image: Image.Image, name: str) -> trimesh.Trimesh:
    material = trimesh.visual.material.PBRMaterial(
        name=name,
        baseColorTexture=_jpeg(image),
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    return trimesh.Trimesh(
        vertices=_enu_to_gltf(shape.vertices),
        faces=shape.faces,
        visual=trimesh.visual.TextureVisuals(uv=shape.uvs, material=material),
        process=False,
    )


def build_site(seed: int = 7) -> trimesh.Scene:
    """The whole sample site as a trimesh Scene in glTF Y-up axes."""
    rng = np.random.default_rng(seed)
    scene = trimesh.Scene()
    g = GROUND_HALF
    ground = shapes.quad([-g, -g, 0.0], [2 * g, 0, 0], [0, 2 * g, 0])
    scene.add_geometry(_textured(ground, ground_texture(rng), "ground"), geom_name="ground")
    scene.add_geometry(
        _textured(shapes.prism_sides(HALL_MIN, HALL_MAX), hall_texture(rng), "hall_walls"),
        geom_name="hall_walls",
    )
    roof = shapes.quad(
        [HALL_MIN[0], HALL_MIN[1], HALL_MAX[2]],
        [HALL_MAX[0] - HALL_MIN[0], 0, 0],
        [0, HALL_MAX[1] - HALL_MIN[1], 0],
    )
    scene.add_geometry(_textured(roof, roof_texture(rng), "hall_roof"), geom_name="hall_roof")
    for b in BUILDINGS:
        walls = shapes.prism_sides(b.min_corner, b.max_corner)
        lo, hi = np.array(b.min_corner), np.array(b.max_corner)
        top = shapes.quad([lo[0], lo[1], hi[2]], [hi[0] - lo[0], 0, 0], [0, hi[1] - lo[1], 0])
        scene.add_geometry(
            _textured(walls, building_texture(b, rng), f"building_{b.name}"),
            geom_name=f"building_{b.name}",
        )
        roof_mesh = trimesh.Trimesh(
            vertices=_enu_to_gltf(top.vertices), faces=top.faces, process=False
        )
        roof_mesh.visual.vertex_colors = np.tile([96, 98, 104, 255], (len(top.vertices), 1))
        scene.add_geometry(roof_mesh, geom_name=f"building_{b.name}_roof")
    return scene


def write_site(out: str | Path, seed: int = 7) -> Path:
    """Build the sample site and write it as GLB to `out`; returns the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = build_site(seed).export(file_type="glb")
    out.write_bytes(data)
    return out
