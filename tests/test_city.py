"""City models as scene layers: CityJSON (document and Sequence) and CityGML 2.0/3.0 written here,
in a projected compound CRS, placed where pyproj and the geoid put them; a wall's pixel located
through the GPU where the frustum says, named with its object; a district of 100,000 buildings
opened in bounded memory; damaged files refused naming the file and the object."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile

import numpy as np
import pyproj
import pytest

from app.core.errors import SceneError
from app.geodesy.crs import parse_crs, vertical_datum, vertical_name
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.scene.city.model import KIND_CODE, KIND_COLORS, Surface, triangulate
from app.scene.city.read import read_city
from app.scene.layers import Layer, layer_kind, load_layers
from app.simulate.city import (
    Building,
    district,
    write_citygml,
    write_cityjson,
    write_cityjsonseq,
)
from tests.conftest import ROOT

# UTM zone 32N + EGM2008 heights, in the OGC compound URL form CityJSON files use
COMPOUND = (
    "https://www.opengis.net/def/crs-compound?"
    "1=https://www.opengis.net/def/crs/EPSG/0/32632&2=https://www.opengis.net/def/crs/EPSG/0/3855"
)
SITE = (480_000.0, 5_550_000.0)  # near Frankfurt: the geoid lies ~48 m above the ellipsoid
BUILDINGS = [
    Building.box(
        "A",
        (480_010.0, 5_550_020.0, 480_030.0, 5_550_035.0),
        100.0,
        112.0,
        {"function": "residential", "measuredHeight": 12.0},
    ),
    Building.box(
        "B", (479_960.0, 5_550_040.0, 479_975.0, 5_550_060.0), 101.5, 125.0, {"function": "office"}
    ),
]


def _geodetic(x, y):
    lon, lat = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True).transform(
        x, y
    )
    return float(lat), float(lon)


def sample_manifest_text() -> str:
    """The sample session's manifest with its files named by absolute paths (to be written
    anywhere)."""
    sample = ROOT / "assets/sample"
    return re.sub(
        r'"([\w./-]+\.(?:mp4|glb|csv))"',
        lambda m: f'"{sample / m.group(1)}"',
        (sample / "session.toml").read_text(),
    )


def _frame() -> LocalFrame:
    lat, lon = _geodetic(*SITE)
    return LocalFrame(lat, lon, 100.0 + float(undulation(lat, lon)))


def _expected_enu(frame: LocalFrame, x: float, y: float, h_egm2008: float) -> np.ndarray:
    """Where a point of the file lies, worked out apart from the reader: pyproj to WGS84, the
    EGM2008 undulation added to the height, then the session frame."""
    lat, lon = _geodetic(x, y)
    return np.asarray(
        frame.geodetic_to_enu(lat, lon, h_egm2008 + float(undulation(lat, lon)))
    ).reshape(3)


def _render(gl_ctx, mesh, camera) -> np.ndarray:
    """The scene alone (no video, no overlays) seen by `camera`: (H, W, 3) uint8."""
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer

    renderer = FusionRenderer(gl_ctx, mesh)
    try:
        return render_to_array(
            renderer, camera, ProjectionSettings(), OverlaySettings(frustum=False, trajectory=False)
        )
    finally:
        renderer.release()


def test_crs_spellings_of_city_files():
    for text in (
        "EPSG:32632+3855",
        COMPOUND,
        "urn:ogc:def:crs,crs:EPSG::32632,crs:EPSG::3855",
    ):
        crs = parse_crs(text)
        assert crs.sub_crs_list[0].to_epsg() == 32632 and vertical_datum(crs) == "egm2008"
    rd = parse_crs("https://www.opengis.net/def/crs/EPSG/0/7415")  # 3D BAG: RD New + NAP
    assert vertical_datum(rd) is None and vertical_name(rd) == "NAP height"
    adv = parse_crs("urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH")
    assert adv.sub_crs_list[0].to_epsg() == 25832 and vertical_name(adv) == "DHHN2016 height"
    assert parse_crs("urn:ogc:def:crs:EPSG::25833").to_epsg() == 25833
    with pytest.raises(ValueError, match="unknown CRS"):
        parse_crs("EPSG:999999")


def test_a_wall_with_a_window_is_triangulated_in_its_own_plane():
    """A 10 x 5 m wall facing south with a 2 x 1 m hole: 48 m2 of triangles, all facing the way
    the ring winds (south), none in the hole."""
    wall = np.array([[0, 0, 0], [10, 0, 0], [10, 0, 5], [0, 0, 5]], float) + [500_000, 5_000_000, 0]
    hole = np.array([[4, 0, 2], [4, 0, 3], [6, 0, 3], [6, 0, 2]], float) + [500_000, 5_000_000, 0]
    tris = triangulate(Surface([wall, hole], "wall"))
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert 0.5 * np.linalg.norm(n, axis=1).sum() == pytest.approx(48.0)
    assert np.all(n[:, 1] < 0) and np.allclose(n[:, [0, 2]], 0)
    centres = tris.mean(axis=1) - [500_000, 5_000_000, 0]
    assert not np.any(
        (centres[:, 0] > 4) & (centres[:, 0] < 6) & (centres[:, 2] > 2) & (centres[:, 2] < 3)
    )


@pytest.fixture(scope="module")
def city_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("city")
    files = {
        "cityjson": write_cityjson(
            d / "two.city.json", BUILDINGS, COMPOUND, translate=(*SITE, 0.0)
        ),
        "sequence": write_cityjsonseq(
            d / "two.city.jsonl", BUILDINGS, COMPOUND, translate=(*SITE, 0.0)
        ),
        "citygml2": write_citygml(d / "two.gml", BUILDINGS, "EPSG:32632+3855", "2.0"),
        "citygml3": write_citygml(
            d / "two3.xml", BUILDINGS, "urn:ogc:def:crs,crs:EPSG::32632,crs:EPSG::3855", "3.0"
        ),
    }
    zipped = d / "two.zip"
    with zipfile.ZipFile(zipped, "w") as z:
        z.write(files["citygml2"], "district/two.gml")
    files["zip"] = zipped
    return files


@pytest.mark.parametrize("kind", ["cityjson", "sequence", "citygml2", "citygml3", "zip"])
def test_every_format_places_the_buildings_where_pyproj_and_the_geoid_do(city_files, kind):
    frame = _frame()
    city = read_city(city_files[kind], frame)
    assert city.objects_read == 2 and city.datum == "egm2008"
    table = city.mesh.features[0]
    assert table.ids == ["A", "B"]
    assert table.attributes[0]["function"] == "residential"
    a = table.triangles[table.starts[0] : table.starts[1]].reshape(-1, 3)
    (x0, y0), _, (x1, y1), _ = BUILDINGS[0].footprint
    corners = np.array(
        [_expected_enu(frame, x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (100.0, 112.0)]
    )
    assert a.min(axis=0) == pytest.approx(corners.min(axis=0), abs=0.01)
    assert a.max(axis=0) == pytest.approx(corners.max(axis=0), abs=0.01)
    # LoD2 box: 2 triangles a face, 6 faces; roof, walls and ground by their semantics
    kinds = table.kinds[table.starts[0] : table.starts[1]]
    assert len(kinds) == 12
    assert [int(np.sum(kinds == KIND_CODE[k])) for k in ("roof", "wall", "ground")] == [2, 8, 2]
    assert "EGM2008" in city.crs_name


def test_the_vertical_datum_decides_the_heights(city_files, tmp_path):
    """Read as above the ellipsoid, the same file sits one geoid undulation (~48 m) lower; a CRS
    with no vertical part is taken as above sea level and that is said."""
    frame = _frame()
    geoid_heights = read_city(city_files["cityjson"], frame).mesh.primitives[0].positions
    ellipsoid = (
        read_city(city_files["cityjson"], frame, vertical="ellipsoid").mesh.primitives[0].positions
    )
    n = float(undulation(*_geodetic(*SITE)))
    assert 40 < n < 55
    assert np.median(geoid_heights[:, 2] - ellipsoid[:, 2]) == pytest.approx(n, abs=0.05)
    plain = write_cityjson(tmp_path / "plain.city.json", BUILDINGS, "EPSG:32632")
    city = read_city(plain, frame)
    assert any("above sea level (EGM2008)" in m for m in city.notes.items)
    assert city.mesh.primitives[0].positions[:, 2] == pytest.approx(geoid_heights[:, 2], abs=1e-3)


def test_a_walls_pixel_lands_where_the_frustum_says_and_names_its_building(city_files, gl_ctx):
    """A camera 30 m south of building A looks at its south wall: the pixel where the camera's
    frustum puts the wall's middle is located (GPU position pass) on that very point, named as
    A's wall with its attributes; the picture shows the wall in its kind's colour and B's roof
    in the roof's."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera, look_at_quat
    from app.locate.location import Locator

    frame = _frame()
    city = read_city(city_files["cityjson"], frame)
    (x0, y0), _, (x1, _), _ = BUILDINGS[0].footprint
    wall = _expected_enu(frame, (x0 + x1) / 2, y0, 104.0)
    eye = wall + [0.0, -30.0, 2.0]
    camera = Camera.create(
        Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0), eye, look_at_quat(eye, wall), far=2000.0
    )
    uv, depth = camera.project(wall[None])
    assert depth[0] > 0 and np.all((uv[0] > 0) & (uv[0] < [320, 240]))
    locator = Locator(city.mesh, frame)
    try:
        (loc,) = locator.locate(camera, [uv[0]])
    finally:
        locator.release()
    assert loc is not None and np.asarray(loc.enu) == pytest.approx(wall, abs=0.02)
    assert loc.feature is not None and (loc.feature.id, loc.feature.surface) == ("A", "wall")
    assert loc.feature.attributes["function"] == "residential"
    assert "Building A, wall" in loc.line() and loc.as_dict()["object"]["id"] == "A"

    image = _render(gl_ctx, city.mesh, camera).astype(float)
    px = image[int(uv[0, 1]), int(uv[0, 0])]
    wall_rgb = KIND_COLORS[KIND_CODE["wall"]]
    assert px[0] > 60 and abs(px[0] / px[1] - wall_rgb[0] / wall_rgb[1]) < 0.15  # off-white
    # seen from above, B's roof is tile red
    top_eye = _expected_enu(frame, 479_967.5, 5_550_050.0, 200.0)
    top = Camera.create(
        Intrinsics(64, 64, 60.0, 60.0, 32.0, 32.0),
        top_eye,
        look_at_quat(top_eye, top_eye - [0, 0, 1], (0.0, 1.0, 0.0)),
        far=2000.0,
    )
    roof = _render(gl_ctx, city.mesh, top)
    r, g, _ = roof[32, 32].astype(float)
    assert r > 1.5 * g


MEASURE_READ = """
import json, sys
import numpy as np
from app.geodesy.enu import LocalFrame
from app.scene.city.read import read_city
frame, track = LocalFrame(*json.loads(sys.argv[2])), np.array(json.loads(sys.argv[3]))
read_city(sys.argv[4], frame)  # what any city loads once (the geoid grid, PROJ's database)
if sys.stdin.readline() != "go\\n":  # the test says go once the district is written
    sys.exit("no go: the district was not written")
def status(key):  # kB; VmHWM: the peak resident memory since exec (ru_maxrss is the parent's)
    return int(open("/proc/self/status").read().split(key + ":")[1].split()[0])
before = status("VmRSS")
try:
    open("/proc/self/clear_refs", "w").write("5")  # the peak starts again from now
except OSError:
    pass  # then the peak since exec: the warm-up's, a few MB above `before`
city = read_city(sys.argv[1], frame, track, margin_m=500.0)
grown = status("VmHWM") - before
print(json.dumps([grown * 1024, city.objects_read, city.objects_in_file, city.notes.items]))
"""


def test_a_district_of_100000_buildings_opens_in_bounded_memory(tmp_path, city_files):
    """100,000 LoD2 buildings (a 70 MB CityJSON document) around a track at one corner: only
    the buildings within the margin are read, and the process grows by far less than the
    document takes parsed whole (over a gigabyte of Python objects), measured in a process of
    its own (its peak resident memory against what it held before reading)."""
    frame = _frame()
    track = [_geodetic(SITE[0] + 100, SITE[1] + 100)]
    origin = [frame.lat_deg, frame.lon_deg, frame.h_m]
    # The measured read runs in a process of its own (its own peak memory). Started first, it
    # loads what any city loads while the district is written, then reads it when told to; the
    # capped read runs here meanwhile, on the machine's other core, instead of after it.
    measure = subprocess.Popen(
        [
            sys.executable,
            "-c",
            MEASURE_READ,
            str(tmp_path / "district.city.json"),
            json.dumps(origin),
            json.dumps(track),
            str(city_files["cityjson"]),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = write_cityjson(
            tmp_path / "district.city.json",
            district(100_000, SITE),
            COMPOUND,
            translate=(*SITE, 0.0),
        )
        assert path.stat().st_size > 50e6
        try:
            measure.stdin.write("go\n")
            measure.stdin.flush()
        except BrokenPipeError:
            pass  # it failed before: its stderr says why, below
        # a cap on triangles keeps the nearest and says so
        capped = read_city(path, frame, np.array(track), margin_m=500.0, max_triangles=1200)
    finally:
        stdout, stderr = measure.communicate()
    assert measure.returncode == 0, stderr[-3000:]
    grown, read, in_file, notes = json.loads(stdout)
    assert in_file == 100_000
    # the grid is 30 m a side: about (500 + 100)^2 * pi / 4 / 900 buildings in the quarter disc
    assert 200 < read < 450
    # the vertex array (800,000 x 3 float64: 19 MB) twice while its blocks are joined, and
    # the parser's buffers: json.load of the same file grows by 640 MB
    assert grown < 60e6, f"grew by {grown / 1e6:.0f} MB"
    assert any("within 500 m of the track" in m for m in notes)
    # and the capped read (made above, meanwhile) kept the nearest and said so
    assert capped.triangles <= 1200 and capped.objects_read == 100
    assert "b0" in capped.mesh.features[0].ids  # the building at the track is kept
    assert any("left out" in m for m in capped.notes.items)


def _broken(tmp_path, name: str, text: str):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_damaged_city_files_are_refused_naming_the_file_and_the_object(tmp_path):
    frame = _frame()
    good = write_cityjson(tmp_path / "good.city.json", BUILDINGS, COMPOUND, translate=(*SITE, 0.0))
    text = good.read_text()
    cases = [
        (_broken(tmp_path, "cut.city.json", text[: len(text) // 2]), "broken JSON"),
        (_broken(tmp_path, "crs.city.json", text.replace("32632", "999999")), "unknown CRS"),
        (
            _broken(tmp_path, "nocrs.city.json", text.replace('"referenceSystem"', '"x"')),
            "names no CRS",
        ),
        (
            _broken(
                tmp_path,
                "empty.city.json",
                json.dumps(
                    {"type": "CityJSON", "version": "2.0", "CityObjects": {}, "vertices": []}
                ),
            ),
            "no object",
        ),
        (
            _broken(tmp_path, "v.city.json", json.dumps({**json.loads(text), "version": "3.7"})),
            "version",
        ),
        (
            _broken(
                tmp_path,
                "cut.gml",
                write_citygml(tmp_path / "g.gml", BUILDINGS, "EPSG:32632").read_text()[:3000],
            ),
            "broken XML",
        ),
        (_broken(tmp_path, "notgml.gml", "<html><body/></html>"), "CityModel"),
    ]
    doc = json.loads(text)
    doc["CityObjects"]["B"]["geometry"][0]["boundaries"][0][0][0][1] = 999
    cases.append(
        (_broken(tmp_path, "index.city.json", json.dumps(doc)), "vertex index 999 out of range")
    )
    for path, what in cases:
        with pytest.raises(SceneError, match=what) as info:
            read_city(path, frame)
        assert path.name in str(info.value)
    with pytest.raises(SceneError, match="CityObjects.B.geometry") as info:
        read_city(cases[-1][0], frame)
    far = np.array([_geodetic(SITE[0] + 50_000, SITE[1])])
    with pytest.raises(SceneError, match="none of its 2 objects lies within"):
        read_city(good, frame, far)


def test_city_layers_by_name_and_content(city_files, tmp_path):
    assert layer_kind(city_files["cityjson"]) == "city"
    assert layer_kind(city_files["zip"]) == "city"
    renamed = tmp_path / "buildings.json"  # a CityJSON without its .city.json name
    renamed.write_bytes(city_files["cityjson"].read_bytes())
    assert layer_kind(renamed) == "city"
    tileset = tmp_path / "tileset.json"
    tileset.write_text(json.dumps({"asset": {"version": "1.1"}, "geometricError": 1, "root": {}}))
    assert layer_kind(tileset) == "tileset"
    frame = _frame()
    loaded = load_layers([Layer.of(city_files["citygml2"], vertical="ellipsoid")], frame)
    assert loaded.mesh.features[0].ids == ["A", "B"]
    assert any("heights above ellipsoid" in m for m in loaded.notes.items)


def test_a_mark_keeps_the_city_object_it_was_drawn_on(tmp_path):
    """A mark on a roof keeps the object's id, surface and attributes in flat GeoJSON
    properties, and reads back the same."""
    from app.locate.marks import Mark, read_marks, write_marks

    frame = _frame()
    obj = {
        "layer": "two.city.json",
        "id": "A",
        "type": "Building",
        "surface": "roof",
        "parent": None,
        "attributes": {"function": "residential", "measuredHeight": 12.0},
    }
    mark = Mark("point", "chimney", "clip.mp4", 3, 0.1, np.array([[20.0, 27.0, 12.0]]), obj)
    path = tmp_path / "m.geojson"
    with path.open("w") as f:
        write_marks([mark], frame, f, ".geojson", "m")
    props = json.loads(path.read_text())["features"][0]["properties"]
    assert (props["object_id"], props["object_surface"]) == ("A", "roof")
    (back,) = read_marks(path, frame)
    assert back.city_object == obj


def test_the_sample_sites_city_model_lands_on_the_sample_model(tmp_path):
    """`geofuse simulate city` writes the sample site as a city publishes it (UTM zone 49 +
    EGM2008, a TINRelief ground): read back, the hall stands where the sample model's does,
    to the centimetre, and the ground is terrain."""
    from app.cli import main
    from app.simulate.sample import SAMPLE_ORIGIN
    from app.simulate.stadium import HALL_MAX, HALL_MIN

    out = tmp_path / "site.city.json"
    assert main(["simulate", "city", "--out", str(out)]) == 0
    city = read_city(out, LocalFrame(*SAMPLE_ORIGIN))
    table = city.mesh.features[0]
    hall = table.ids.index("hall")
    tris = table.triangles[table.starts[hall] : table.starts[hall + 1]].reshape(-1, 3)
    assert tris.min(axis=0) == pytest.approx(HALL_MIN, abs=0.01)
    assert tris.max(axis=0) == pytest.approx(HALL_MAX, abs=0.01)
    ground = table.ids.index("ground")
    assert table.types[ground] == "TINRelief"
    assert set(table.kinds[table.starts[ground] : table.starts[ground + 1]]) == {
        KIND_CODE["terrain"]
    }


def test_a_citygml_relief_states_its_lod_in_an_element(tmp_path):
    gml = tmp_path / "relief.gml"
    gml.write_text(
        '<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" '
        'xmlns:dem="http://www.opengis.net/citygml/relief/2.0" xmlns:gml="http://www.opengis.net/gml">'
        '<gml:boundedBy><gml:Envelope srsName="EPSG:32632+3855"/></gml:boundedBy>'
        '<core:cityObjectMember><dem:ReliefFeature gml:id="terrain"><dem:lod>1</dem:lod>'
        "<dem:reliefComponent><dem:TINRelief><dem:tin><gml:TriangulatedSurface><gml:trianglePatches>"
        "<gml:Triangle><gml:exterior><gml:LinearRing><gml:posList>"
        "480000 5550000 100 480050 5550000 100 480050 5550050 100 480000 5550000 100"
        "</gml:posList></gml:LinearRing></gml:exterior></gml:Triangle>"
        "</gml:trianglePatches></gml:TriangulatedSurface></dem:tin></dem:TINRelief></dem:reliefComponent>"
        "</dem:ReliefFeature></core:cityObjectMember></core:CityModel>"
    )
    city = read_city(gml, _frame())
    table = city.mesh.features[0]
    assert table.ids == ["terrain"] and list(table.kinds) == [KIND_CODE["terrain"]]


def _quadrant_image(folder) -> None:
    """appearances/wall.png: 64 x 64, red upper left, green upper right, blue lower left,
    yellow lower right."""
    from PIL import Image

    quads = np.zeros((64, 64, 3), np.uint8)  # row 0 = the image's top
    quads[:32, :32] = (220, 30, 30)
    quads[:32, 32:] = (30, 200, 30)
    quads[32:, :32] = (30, 30, 220)
    quads[32:, 32:] = (230, 220, 30)
    (folder / "appearances").mkdir(exist_ok=True)
    Image.fromarray(quads).save(folder / "appearances" / "wall.png")


def _check_wall_quadrants(city, frame, gl_ctx) -> None:
    """Seen from the south, A's south wall shows the quadrant image the right way up: its
    upper-left quarter red, upper-right green, lower-left blue, lower-right yellow; locate
    still names the wall."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera, look_at_quat

    assert sum(p.textured for p in city.mesh.primitives) == 1
    (x0, y0), _, (x1, _), _ = BUILDINGS[0].footprint
    wall = _expected_enu(frame, (x0 + x1) / 2, y0, 106.0)
    eye = wall + [0.0, -30.0, 0.0]
    camera = Camera.create(
        Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0), eye, look_at_quat(eye, wall), far=2000.0
    )
    image = _render(gl_ctx, city.mesh, camera).astype(int)

    def at(x, z):
        uv, _ = camera.project(_expected_enu(frame, x, y0, z)[None])
        return image[int(uv[0, 1]), int(uv[0, 0])]

    west, east = x0 + 0.25 * (x1 - x0), x0 + 0.75 * (x1 - x0)
    upper, lower = 100.0 + 0.75 * 12.0, 100.0 + 0.25 * 12.0
    for (x, z), channel in (((west, upper), 0), ((east, upper), 1), ((west, lower), 2)):
        px = at(x, z)
        assert px[channel] > 1.5 * max(np.delete(px, channel)), (x, z, px)
    yellow = at(east, lower)
    assert yellow[0] > 2 * yellow[2] and yellow[1] > 2 * yellow[2]
    feature = city.mesh.feature_at(_expected_enu(frame, west, y0, upper))
    assert feature is not None and (feature.id, feature.surface) == ("A", "wall")


def test_a_textured_wall_shows_its_image_the_right_way_up(tmp_path, gl_ctx):
    """CityJSON appearances: A's south wall carries a four-colour image (texture coordinates
    (0, 0) at its lower-left corner, as CityJSON has them), drawn the right way up; the other
    surfaces keep their kind's colour. A missing image is said and drawn by kind; a texture
    the file does not have is refused naming the object."""
    from app.simulate.city import cityjson

    _quadrant_image(tmp_path)
    doc = cityjson(BUILDINGS, COMPOUND, translate=(*SITE, 0.0))
    doc["appearance"] = {
        "textures": [{"type": "PNG", "image": "appearances/wall.png"}],
        "vertices-texture": [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
    }
    solid = doc["CityObjects"]["A"]["geometry"][0]
    # faces as app.simulate.city.FACES: the third is the south wall (corners 0, 1, 5, 4)
    values = [[None] for _ in solid["boundaries"][0]]
    values[2] = [[0, 0, 1, 2, 3]]
    solid["texture"] = {"winter": {"values": [values]}}
    path = tmp_path / "textured.city.json"
    path.write_text(json.dumps(doc))
    frame = _frame()
    _check_wall_quadrants(read_city(path, frame), frame, gl_ctx)
    # a texture image that is missing is said, and its surfaces are drawn by kind
    (tmp_path / "appearances" / "wall.png").unlink()
    city = read_city(path, frame)
    assert not any(p.textured for p in city.mesh.primitives)
    assert any("wall.png: texture not drawn" in m for m in city.notes.items)
    # a surface naming a texture the file does not have is refused, naming the object
    values[2] = [[5, 0, 1, 2, 3]]
    path.write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=r"CityObjects.A.geometry\[0\].texture.*texture 5"):
        read_city(path, frame)


def test_a_citygml_texture_kept_apart_from_its_building_is_drawn(tmp_path, gl_ctx):
    """CityGML appearances: a ParameterizedTexture in an appearanceMember after the buildings
    (as many exports keep them), aimed at the south wall's ring by its gml:id: drawn the right
    way up as the CityJSON one."""
    _quadrant_image(tmp_path)
    path = write_citygml(tmp_path / "textured.gml", BUILDINGS, "EPSG:32632+3855")
    appearance = (
        '<app:appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0">'
        "<app:Appearance><app:theme>rgbTexture</app:theme><app:surfaceDataMember>"
        "<app:ParameterizedTexture><app:imageURI>appearances/wall.png</app:imageURI>"
        '<app:target uri="#A_p2"><app:TexCoordList>'
        '<app:textureCoordinates ring="#A_p2_r0">0 0 1 0 1 1 0 1 0 0</app:textureCoordinates>'
        "</app:TexCoordList></app:target></app:ParameterizedTexture>"
        "</app:surfaceDataMember></app:Appearance></app:appearanceMember>"
    )
    text = path.read_text().replace("</core:CityModel>", appearance + "</core:CityModel>")
    path.write_text(text)
    frame = _frame()
    _check_wall_quadrants(read_city(path, frame), frame, gl_ctx)


def _check_red_wall(city, frame, gl_ctx) -> None:
    """A's south wall drawn in its material's red; its other walls in the wall kind's colour."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera, look_at_quat

    (x0, y0), _, (x1, _), _ = BUILDINGS[0].footprint
    wall = _expected_enu(frame, (x0 + x1) / 2, y0, 106.0)
    eye = wall + [-20.0, -30.0, 0.0]  # south-west: the south wall and the west one
    camera = Camera.create(
        Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0), eye, look_at_quat(eye, wall), far=2000.0
    )
    image = _render(gl_ctx, city.mesh, camera).astype(int)

    def at(p):
        uv, _ = camera.project(np.asarray(p)[None])
        return image[int(uv[0, 1]), int(uv[0, 0])]

    south = at(wall)
    west = at(_expected_enu(frame, x0, y0 + 2.0, 106.0))
    assert south[0] > 2 * south[1] and south[0] > 2 * south[2], south
    assert min(west) > 120 and max(west) - min(west) < 60, west  # off-white, shaded


def test_material_colours_are_drawn_where_a_surface_has_no_texture(tmp_path, gl_ctx):
    """CityJSON materials (a theme's values per surface, or one value for all) and CityGML
    X3DMaterials (aimed at a polygon by its gml:id, kept apart from the buildings): the
    surface is drawn in its diffuse colour, the others by kind."""
    from app.simulate.city import cityjson

    doc = cityjson(BUILDINGS, COMPOUND, translate=(*SITE, 0.0))
    doc["appearance"] = {
        "materials": [
            {"name": "red", "diffuseColor": [0.9, 0.1, 0.1]},
            {"name": "blue", "diffuseColor": [0.1, 0.1, 0.9]},
            {"name": "none"},
        ]  # fmt: skip
    }
    solid = doc["CityObjects"]["A"]["geometry"][0]
    values = [None for _ in solid["boundaries"][0]]
    values[2] = 0  # the south wall (app.simulate.city.FACES)
    values[3] = 2  # a material without a colour: drawn by kind
    solid["material"] = {"paint": {"values": [values]}}
    doc["CityObjects"]["B"]["geometry"][0]["material"] = {"paint": {"value": 1}}
    path = tmp_path / "materials.city.json"
    path.write_text(json.dumps(doc))
    frame = _frame()
    city = read_city(path, frame)
    _check_red_wall(city, frame, gl_ctx)
    colours = city.mesh.primitives[0].colors[:, :3]
    assert np.any(np.all(np.abs(colours - [0.1, 0.1, 0.9]) < 0.01, axis=1))  # B, all of it

    gml = write_citygml(tmp_path / "materials.gml", BUILDINGS, "EPSG:32632+3855")
    appearance = (
        '<app:appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0">'
        "<app:Appearance><app:surfaceDataMember><app:X3DMaterial>"
        "<app:diffuseColor>0.9 0.1 0.1</app:diffuseColor><app:target>#A_p2</app:target>"
        "</app:X3DMaterial></app:surfaceDataMember></app:Appearance></app:appearanceMember>"
    )
    gml.write_text(gml.read_text().replace("</core:CityModel>", appearance + "</core:CityModel>"))
    _check_red_wall(read_city(gml, frame), frame, gl_ctx)


def test_a_layer_reads_the_level_of_detail_asked_for(tmp_path):
    """A building with an LoD 1 geometry (two of its faces) beside its LoD 2.2 one: each
    object's highest by default, the LoD 1 one when the layer asks for lod = 1.2; a manifest's
    `lod` reaches the layer, and is refused on a layer that is no city model."""

    from app.core.errors import ManifestError
    from app.session.config import read_config
    from app.simulate.city import cityjson

    doc = cityjson(BUILDINGS, COMPOUND, translate=(*SITE, 0.0))
    solid = doc["CityObjects"]["A"]["geometry"][0]
    lod1 = {"type": "MultiSurface", "lod": "1", "boundaries": solid["boundaries"][0][:2]}
    doc["CityObjects"]["A"]["geometry"].insert(0, lod1)
    path = tmp_path / "lods.city.json"
    path.write_text(json.dumps(doc))

    def a_triangles(**options):
        table = read_city(path, _frame(), **options).mesh.features[0]
        a = table.ids.index("A")
        return int(table.starts[a + 1] - table.starts[a])

    assert a_triangles() > 4 and a_triangles(max_lod=1.2) == 4
    text = sample_manifest_text()
    manifest = tmp_path / "session.toml"
    manifest.write_text(text + f'\n[[layers]]\npath = "{path}"\nlod = 1.2\n')
    (layer,) = [x for x in read_config(manifest).layers if x.kind == "city"]
    assert layer.lod == 1.2
    manifest.write_text(text.replace('up_axis = "Y"', 'up_axis = "Y"\nlod = 2'))
    with pytest.raises(ManifestError, match=r"scene.lod.*city model's key"):
        read_config(manifest)
