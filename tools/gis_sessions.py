"""Two sessions of the bundled sample walk on GIS scenes, for the README's screenshots:

    python tools/gis_sessions.py OUT
    geofuse view OUT/tiles/session.toml --screenshot docs/tileset.png --play 3
    geofuse view OUT/terrain/session.toml --screenshot docs/terrain.png --play 3

OUT/tiles: the sample stadium as a 3D Tiles tileset (its GLB under a root ENU->ECEF transform)
and a generated city of four levels of detail north of it, as [[layers]].
OUT/terrain: the stadium on terrain: a DEM (UTM zone 49N, heights above EGM2008) of hills that
level out under the site, with a generated orthophoto (fields, roads) in geographic coordinates.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

try:
    import numpy as np
    import pyproj
except ModuleNotFoundError as exc:  # the system Python, not the project's
    raise SystemExit(
        f"{exc.name} is not installed here: run `make setup`, then `.venv/bin/python {__file__} OUT`"
    ) from None

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.geodesy import geoid  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.scene.tiles import write as tjw  # noqa: E402
from app.simulate import tileset as tw  # noqa: E402
from app.simulate.sample import SAMPLE_DIR, SAMPLE_ORIGIN  # noqa: E402
from app.simulate.terrain import write_geotiff  # noqa: E402

SESSION_FILES = (
    "clip.mp4",
    "acc.csv",
    "gyr.csv",
    "mag.csv",
    "gnss.csv",
    "phone_orientation.csv",
    "truth_orientation.csv",
    "truth_position.csv",
    "truth_frames.csv",
)


def _copy_sample(dest: Path) -> str:
    dest.mkdir(parents=True, exist_ok=True)
    for name in SESSION_FILES:
        shutil.copy(SAMPLE_DIR / name, dest / name)
    text = (SAMPLE_DIR / "session.toml").read_text()
    return text[text.index("[video]") :]


def tiles(out: Path) -> Path:
    d = out / "tiles"
    rest = _copy_sample(d)
    frame = LocalFrame(*SAMPLE_ORIGIN)
    (d / "stadium").mkdir(exist_ok=True)
    shutil.copy(SAMPLE_DIR / "scene.glb", d / "stadium" / "scene.glb")
    root = {
        "boundingVolume": {"box": tjw.box_of([-300, -300, -5], [300, 300, 60])},
        "geometricError": 0.0,
        "refine": "REPLACE",
        "transform": tjw.column_major(tjw.enu_to_ecef_matrix(frame)),
        "content": {"uri": "scene.glb"},
    }
    tjw.write_json(
        d / "stadium" / "tileset.json",
        {"asset": {"version": "1.1"}, "geometricError": 50.0, "root": root},
    )
    city_origin = tuple(
        frame.enu_to_geodetic(np.array([0.0, 480.0, 0.0]))
    )  # north of the site, edge to edge
    tw.write_city(
        d / "city", city_origin, size_m=600.0, levels=4, blocks_per_leaf=16, leaf_detail=6
    )
    manifest = d / "session.toml"
    manifest.write_text(
        f"[origin]\nlat = {SAMPLE_ORIGIN[0]}\nlon = {SAMPLE_ORIGIN[1]}\nh = {SAMPLE_ORIGIN[2]}\n\n"
        '[scene]\npath = "stadium/tileset.json"\n\n[[layers]]\npath = "city/tileset.json"\n\n'
        + rest
    )
    return manifest


def terrain(out: Path) -> Path:
    d = out / "terrain"
    rest = _copy_sample(d)
    shutil.copy(SAMPLE_DIR / "scene.glb", d / "scene.glb")
    lat0, lon0, h0 = SAMPLE_ORIGIN
    utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32649", always_xy=True)
    e0, n0 = utm.transform(lon0, lat0)
    step, size = 2.0, 1500  # 3 km square, 2 m samples
    west, north = e0 - size * step / 2, n0 + size * step / 2
    cols, rows = np.meshgrid(np.arange(size), np.arange(size))
    e, n = west + (cols + 0.5) * step - e0, north - (rows + 0.5) * step - n0
    r = np.hypot(e, n)
    rise = np.clip((r - 280.0) / 400.0, 0.0, 1.0) ** 2  # flat under the site, hills beyond
    hills = 45.0 * np.sin(e / 310.0) * np.cos(n / 270.0) + 30.0 + 12.0 * np.sin((e + n) / 120.0)
    ground = h0 - float(geoid.undulation(lat0, lon0))  # the site's ground, above EGM2008
    write_geotiff(d / "dem.tif", ground + rise * hills, "EPSG:32649+3855", west, north, step, step)
    # orthophoto: fields in four tints, a road grid, in geographic coordinates (1/3 arc-second)
    ostep = 1.0 / 10800
    osize = int(3200 / 30.8 / 0.3333)
    lon = lon0 - osize * ostep / 2 + (np.arange(osize) + 0.5) * ostep
    lat = lat0 + osize * ostep / 2 - (np.arange(osize) + 0.5) * ostep
    lg, la = np.meshgrid(lon, lat)
    x = (lg - lon0) * 111_320 * np.cos(np.radians(lat0))
    y = (la - lat0) * 110_540
    field = ((np.floor(x / 90) * 7 + np.floor(y / 70) * 13) % 4).astype(int)
    tints = np.array([[112, 140, 72], [150, 160, 90], [120, 110, 70], [90, 125, 80]], np.uint8)
    rgb = tints[field].astype(np.int16) + np.random.default_rng(1).integers(
        -8, 8, field.shape + (3,)
    )
    road = (np.abs((x + 45) % 360 - 180) < 4) | (np.abs((y + 35) % 280 - 140) < 4)
    rgb[road] = (175, 172, 165)
    rgb[np.hypot(x, y) < 260] = (128, 128, 120)  # the site's own paving
    write_geotiff(
        d / "ortho.tif",
        np.moveaxis(np.clip(rgb, 0, 255).astype(np.uint8), -1, 0),
        "EPSG:4326",
        lon[0] - ostep / 2,
        lat[0] + ostep / 2,
        ostep,
        ostep,
        nodata=None,
    )
    manifest = d / "session.toml"
    manifest.write_text(
        '[scene]\npath = "scene.glb"\norigin = [34.8, 113.53, 110.0]\nup_axis = "Y"\n\n'
        '[dem]\npath = "dem.tif"\northo = "ortho.tif"\n\n' + rest
    )
    return manifest


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "out/gis")
    print(tiles(target))
    print(terrain(target))
