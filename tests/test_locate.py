"""`geofuse locate` and app.locate.location: the point of the scene a pixel sees, occlusion included,
checked against numbers worked out by hand, a lens profile's own projection, the sky, and the
sample's footprints."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from app.camera.lens import read_profile
from app.camera.profiles import still_camera
from app.cli import main
from app.export.records import frame_records
from app.geodesy.enu import LocalFrame
from app.locate.location import Locator, locate
from app.scene import load_scene
from app.session import open_session
from app.simulate.sample import SAMPLE_DIR
from tests.conftest import ROOT

ORIGIN = (46.05, 14.5, 300.0)
FOV = 60.0
SIZE = (640, 480)
# A wall 30 m north (x -20..20, z 0..20) and a 4 m box 10..14 m north of the camera, which
# stands at (0, 0, 2) looking north, level.
BOX = [(-2.0, 10.0, 0.0), (2.0, 14.0, 4.0)]


def _obj(path: Path) -> Path:
    v, f = [], []

    def quad(a, b, c, d):
        n = len(v)
        v.extend([a, b, c, d])
        f.append((n + 1, n + 2, n + 3))
        f.append((n + 1, n + 3, n + 4))

    quad((-20, 30, 0), (20, 30, 0), (20, 30, 20), (-20, 30, 20))  # the wall
    (x0, y0, z0), (x1, y1, z1) = BOX
    quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1))  # the box's south face
    quad((x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1))
    quad((x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1))
    quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1))
    quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1))
    path.write_text(
        "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a} {b} {c}\n" for a, b, c in f)
    )
    return path


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    d = tmp_path_factory.mktemp("locate")
    image = d / "frame.png"
    Image.fromarray(np.zeros((SIZE[1], SIZE[0], 3), np.uint8)).save(image)
    return _obj(d / "site.obj"), image


def _args(scene: Path, image: Path, pitch: float = 0.0, *pixels: str) -> list[str]:
    lat, lon, h = ORIGIN
    args = ["locate", "--scene", str(scene), "--origin", f"{lat},{lon},{h}", "--image", str(image)]
    args += ["--pose", f"{lat},{lon},{h + 2},0,{pitch},0", "--fov", str(FOV), "--json"]
    for p in pixels:
        args += ["--pixel", p]
    return args


def test_a_box_in_front_of_a_wall_and_the_wall_beside_it(still, capsys):
    """The centre pixel's ray meets the box's south face at (0, 10, 2), 10 m away, head-on; a
    ray a quarter to the right (x = y / 4) passes the box and meets the wall at (7.5, 30, 2),
    30.92 m away."""
    scene, image = still
    fx = SIZE[0] / 2 / math.tan(math.radians(FOV / 2))
    beside = f"{SIZE[0] / 2 + 0.25 * fx},{SIZE[1] / 2}"
    assert main(_args(scene, image, 0.0, f"{SIZE[0] / 2},{SIZE[1] / 2}", beside)) == 0
    box, wall = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(box["enu_m"], [0.0, 10.0, 2.0], atol=0.01)
    assert box["range_m"] == pytest.approx(10.0, abs=0.01)
    assert box["incidence_deg"] == pytest.approx(90.0, abs=0.5)
    np.testing.assert_allclose(wall["enu_m"], [7.5, 30.0, 2.0], atol=0.02)
    assert wall["range_m"] == pytest.approx(30.0 * math.hypot(1.0, 0.25), abs=0.02)
    frame = LocalFrame(*ORIGIN)
    lat, lon, h = frame.enu_to_geodetic(np.array([[7.5, 30.0, 2.0]]))[0]
    assert wall["latitude"] == pytest.approx(lat, abs=1e-7)
    assert wall["longitude"] == pytest.approx(lon, abs=1e-7)
    assert wall["ellipsoid_height_m"] == pytest.approx(h, abs=0.02)


def test_the_sky_and_a_pixel_outside_the_image_are_refused(still, capsys):
    scene, image = still
    # pitched 60 deg up: the top rows see above the 20 m wall (its top is 33.7 deg up at 30 m)
    assert main(_args(scene, image, 60.0, "320,10", "700,10")) == 1
    sky, outside = json.loads(capsys.readouterr().out)
    assert "sky" in sky["error"] and "outside the 640x480 image" in outside["error"]


def test_a_distorted_lens_pixel_lands_where_the_profile_says(still):
    """Through a GoPro wide lens, a pixel near the corner meets the wall at the point that the
    profile's own projection (Lens.distort, the model the profile defines) takes back to that
    pixel, and far from where a pinhole of the same focal length would put it."""
    scene, _ = still
    frame = LocalFrame(*ORIGIN)
    mesh = load_scene(scene, frame)
    profile = (
        ROOT / "app/camera/lens_profiles/GoPro/GoPro_HERO8 Black_Wide_HS Boost_2.7k_16by9.json"
    )
    width, height = read_profile(profile).width, read_profile(profile).height
    cam = still_camera((width, height), [0.0, 0.0, 2.0], (0.0, 0.0, 0.0), profile=profile)
    pixel = (0.85 * width, 0.4 * height)
    locator = Locator(mesh, frame)
    try:
        (loc,) = locator.locate(cam, [pixel])
    finally:
        locator.release()
    uv, depth = cam.project(np.array([loc.enu]))
    assert depth[0] > 0 and np.hypot(*(uv[0] - pixel)) < 0.1  # back to the pixel through the lens
    assert loc.enu[1] == pytest.approx(30.0, abs=0.01)  # on the wall
    intr = cam.intrinsics
    pinhole_x = 30.0 * (pixel[0] - intr.cx) / intr.fx
    assert abs(loc.enu[0] - pinhole_x) > 1.0  # the lens matters here


def test_locate_agrees_with_the_footprint_centre_on_the_sample():
    """The centre pixel of the frame at 20 s lands where that frame's footprint centre does."""
    session = open_session(SAMPLE_DIR / "session.toml")
    (loc,) = locate(session, 20.0, [[320.0, 180.0]])
    record = next(
        r for r in frame_records(session, session.sources[0], 1) if abs(r.media_s - 20.0) < 0.02
    )
    assert loc.lat == pytest.approx(record.centre[0], abs=1e-7)
    assert loc.lon == pytest.approx(record.centre[1], abs=1e-7)
    assert loc.height_m == pytest.approx(record.centre[2], abs=0.05)
    assert loc.range_m == pytest.approx(record.slant_m, abs=0.05)
    assert loc.uncertainty_m is not None and loc.uncertainty_m > 0


def test_pixels_from_a_csv_and_a_bad_line(still, tmp_path, capsys):
    scene, image = still
    good = tmp_path / "px.csv"
    good.write_text("x,y\n320,240\n100,240\n")
    assert main(_args(scene, image) + ["--pixels", str(good)]) == 0
    assert len(json.loads(capsys.readouterr().out)) == 2
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n320,240\nleft,top\n")
    assert main(_args(scene, image) + ["--pixels", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.csv:3" in err and "X,Y" in err
