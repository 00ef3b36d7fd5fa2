"""Damaged inputs of issue 51, each written here: control-point CSVs (bytes that are not UTF-8,
empty, wrong columns, inf, absurd heights and frames, pixels outside the image, model points
behind the camera, one pair repeated), marks GeoJSON (features not a list, frames out of range,
NaN coordinates) and CityJSON/CityGML (vertices as strings, texture paths leaving the model's
folder). Each is refused in one line naming the file and the line or field (exit status 2 from
the CLI, no traceback) or loaded with what was wrong said; no input file is ever written."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.core.errors import DataFormatError, GeofuseError, SceneError
from app.geodesy.enu import LocalFrame
from app.locate.marks import Mark, marks_geojson, read_marks
from app.register.points import ControlPoints, read_points, solve_control, write_points
from app.scene.city.read import read_city
from app.session import open_session
from app.session.camera_track import camera_track
from app.simulate.city import Building, cityjson, write_citygml

HEADER = "frame,x,y,latitude,longitude,height\n"
GOOD_ROWS = [
    "10,100.5,80.25,46.05,14.5,300.0",
    "60,200.0,90.0,46.0501,14.5002,301.0",
    "120,300.0,100.0,46.0502,14.5001,302.5",
    "170,400.0,110.0,46.0503,14.5003,299.0",
]


def _csv(folder: Path, name: str, data: str | bytes) -> Path:
    p = folder / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return p


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out.out, out.err


def _refused_by_cli(argv: list[str], capsys, *says: str) -> str:
    """Exit status 2, one line on stderr saying each of `says`."""
    code, _, err = _cli(argv, capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("geofuse: error: "), err
    for s in says:
        assert s in lines[0], lines[0]
    return lines[0]


# --- control points: the file ----------------------------------------------------------------


@pytest.mark.parametrize(
    "name, data, says",
    [
        (
            "latin1.csv",
            (HEADER + "\n".join(GOOD_ROWS[:2]) + "\n# Stra\xdfe\n").encode("latin-1"),
            ["latin1.csv:4", "byte 0xdf", "not UTF-8"],
        ),
        (
            "bom.csv",
            b"\xef\xbb\xbf" + HEADER.encode() + b"\xff\n",
            ["bom.csv:2", "byte 0xff at offset 39", "not UTF-8"],
        ),
        ("binary.csv", bytes(range(256)), ["binary.csv:2", "byte 0x80 at offset 128", "not UTF-8"]),
        ("empty.csv", b"", ["empty.csv:1", "empty", "frame,x,y,latitude,longitude,height"]),
        ("blank.csv", b"\n\n  \n", ["blank.csv:1", "empty"]),
        ("header.csv", HEADER.encode(), ["header.csv", "0 control points", "at least 4"]),
        (
            "columns.csv",
            b"frame,u,v,lat,lon,alt\n1,2,3,46,14,300\n",
            ["columns.csv:1", "missing columns x, y, latitude, longitude, height"],
        ),
        (
            "short.csv",
            (HEADER + GOOD_ROWS[0] + "\n10,100,80\n").encode(),
            ["short.csv:3 field 'latitude'", "missing"],
        ),
        (
            "inf.csv",
            (HEADER + GOOD_ROWS[0] + "\n10,100,80,46.05,14.5,inf\n").encode(),
            ["inf.csv:3 field 'height'", "not a finite number"],
        ),
        (
            "high.csv",
            (HEADER + GOOD_ROWS[0] + "\n10,100,80,46.05,14.5,1e30\n").encode(),
            ["high.csv:3 field 'height'", "1e30", "no height of a point on Earth"],
        ),
        (
            "deep.csv",
            (HEADER + "10,100,80,46.05,14.5,-50000\n").encode(),
            ["deep.csv:2 field 'height'", "metres above the ellipsoid"],
        ),
        (
            "frame.csv",
            (HEADER + "1e30,100,80,46.05,14.5,300\n").encode(),
            ["frame.csv:2 field 'frame'", "not a frame index"],
        ),
        (
            "lat.csv",
            (HEADER + "1,100,80,95,14.5,300\n").encode(),
            ["lat.csv:2 field 'latitude'", "[-90, 90]"],
        ),
        (
            "word.csv",
            (HEADER + "1,left,80,46,14.5,300\n").encode(),
            ["word.csv:2 field 'x'", "'left' is not a number"],
        ),
        (
            "nul.csv",
            (HEADER + GOOD_ROWS[0] + "\n1,2\x00,3,46,14,300\n").encode(),
            ["nul.csv:3 field 'x'", "is not a number"],
        ),
        (
            "huge.csv",
            (HEADER + GOOD_ROWS[0] + '\n1,"' + "9" * 200_000 + '",3,46,14,300\n').encode(),
            ["huge.csv:3", "not CSV", "field larger than field limit"],
        ),
        (
            "repeated.csv",
            (HEADER + "\n".join([GOOD_ROWS[0]] * 6) + "\n").encode(),
            ["repeated.csv", "1 distinct control points", "5 repeated pairs dropped", "at least 4"],
        ),
    ],
)
def test_a_damaged_control_point_file_is_refused_in_one_line(tmp_path, capsys, name, data, says):
    p = _csv(tmp_path, name, data)
    before = _digest(p)
    with pytest.raises(DataFormatError) as info:
        read_points(p)
    for s in says:
        assert s in str(info.value), str(info.value)
    assert "\n" not in str(info.value)
    # the CLI reads the points before the session: any input name will do
    _refused_by_cli(["register", str(tmp_path / "clip.mp4"), "--points", str(p)], capsys, *says)
    assert _digest(p) == before


def test_a_byte_order_mark_and_crlf_line_ends_are_read(tmp_path):
    p = _csv(tmp_path, "bom.csv", ("\ufeff" + HEADER + "\n".join(GOOD_ROWS) + "\n").encode())
    p.write_bytes(p.read_bytes().replace(b"\n", b"\r\n"))
    points = read_points(p)
    assert len(points) == 4 and points.lines == (2, 3, 4, 5) and not points.notes


def test_a_pair_repeated_is_dropped_and_said(tmp_path):
    rows = GOOD_ROWS[:1] * 6 + GOOD_ROWS[1:]
    p = _csv(tmp_path, "sixfold.csv", HEADER + "\n".join(rows) + "\n")
    points = read_points(p)
    assert len(points) == 4 and points.lines == (2, 8, 9, 10)
    (note,) = points.notes
    assert "sixfold.csv" in note and "5 pairs repeat" in note and "line 3" in note
    assert "4 distinct pairs left" in note


# --- control points against a track ------------------------------------------------------------


@pytest.fixture(scope="module")
def short_session(short_walk):
    return open_session(short_walk)  # conftest's 6 s walk, simulated once for the session


@pytest.fixture(scope="module")
def exact_pairs(short_session) -> ControlPoints:
    """Twelve pairs the true track sees exactly: three pixels on each of four frames."""
    track = camera_track(short_session, "truth")
    rng = np.random.default_rng(7)
    frames, pixels, points = [], [], []
    for k in (10, 60, 120, 170):
        cam = track.frame_camera(k)
        uv = np.column_stack([rng.uniform(40, 600, 3), rng.uniform(40, 320, 3)])
        x = np.asarray(cam.position) + cam.pixel_rays(uv) * rng.uniform(25, 80, (3, 1))
        frames += [k] * 3
        pixels.append(uv)
        points.append(short_session.frame.enu_to_geodetic(x))
    return ControlPoints(np.array(frames), np.concatenate(pixels), np.concatenate(points))


def _register(short_session, pairs: ControlPoints, folder: Path, capsys) -> tuple[int, str, str]:
    path = write_points(folder / "pairs.csv", pairs)
    manifest = short_session.path
    before = _digest(manifest)
    argv = ["register", str(manifest), "--points", str(path), "--source", "truth"]
    try:
        return _cli(argv, capsys)
    finally:
        assert _digest(manifest) == before


def test_pixels_outside_the_image_are_refused_naming_the_line(
    short_session, exact_pairs, tmp_path, capsys
):
    pixel = exact_pairs.pixel.copy()
    pixel[4] = [5000.0, 100.0]
    code, _, err = _register(short_session, replace(exact_pairs, pixel=pixel), tmp_path, capsys)
    assert code == 2 and "pairs.csv:6 field 'x'" in err and "outside the video's" in err, err
    pixel = exact_pairs.pixel.copy()
    pixel[0] = [100.0, -300.0]
    with pytest.raises(GeofuseError, match=r"control pair 1: pixel y = -300"):
        solve_control(camera_track(short_session, "truth"), replace(exact_pairs, pixel=pixel))


def test_model_points_all_behind_the_camera_are_refused(
    short_session, exact_pairs, tmp_path, capsys
):
    track = camera_track(short_session, "truth")
    frame = short_session.frame
    x = frame.geodetic_to_enu(*exact_pairs.geodetic.T)
    centres = np.array([track.frame_camera(int(k)).position for k in exact_pairs.frame])
    behind = frame.enu_to_geodetic(2 * centres - x)  # each point mirrored through its camera
    code, _, err = _register(short_session, replace(exact_pairs, geodetic=behind), tmp_path, capsys)
    assert code == 2 and "pairs.csv" in err and "all 12 model points lie behind" in err, err
    # one of twelve behind: solved, and said naming its line
    some = exact_pairs.geodetic.copy()
    some[3] = behind[3]
    code, out, err = _register(short_session, replace(exact_pairs, geodetic=some), tmp_path, capsys)
    assert code == 0 and "boresight" in out, err
    assert "warning:" in err and "line 5 lies behind the camera" in err, err


def test_a_pair_repeated_six_times_is_dropped_and_said_by_the_cli(
    short_session, exact_pairs, tmp_path, capsys
):
    keep = np.array([0, 0, 0, 0, 0, 0, 3, 6, 9])
    code, out, err = _register(short_session, exact_pairs.subset(keep), tmp_path, capsys)
    assert code == 0 and "4 control points against truth" in out, err
    assert "warning:" in err and "5 pairs repeat an earlier one" in err, err
    # picked in the viewer (no file): the same, naming the pairs
    track = camera_track(short_session, "truth")
    sol = solve_control(track, replace(exact_pairs.subset(keep), path=None, lines=()))
    assert len(sol.residual_px) == 4 and any("pair 2" in n for n in sol.notes)
    with pytest.raises(GeofuseError, match="2 distinct control points.*need at least 4"):
        solve_control(track, replace(exact_pairs.subset(np.array([0, 0, 0, 3])), lines=()))


# --- marks -------------------------------------------------------------------------------------

FRAME = LocalFrame(46.05, 14.5, 300.0)


def _marks_doc() -> dict:
    line = Mark("line", "fence", "clip.mp4", 30, 1.0, np.array([[0, 0, 0], [5, 0, 0.0]]))
    point = Mark("point", "car", "clip.mp4", 31, 1.03, np.array([[2, 3, 0.5]]))
    square = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0.0]])
    field = Mark("polygon", "field", "clip.mp4", 32, 1.06, square)
    return marks_geojson([line, point, field], FRAME)


def _write(folder: Path, name: str, doc: object) -> Path:
    p = folder / name
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))  # NaN written as JSON does
    return p


@pytest.mark.parametrize(
    "name, change, says",
    [
        ("notjson.marks.geojson", "{features: [", "not a marks file"),
        ("list.marks.geojson", [], "expected a GeoJSON FeatureCollection"),
        (
            "dict.marks.geojson",
            {"type": "FeatureCollection", "features": {"a": 1}},
            "field 'features'",
        ),
        (
            "int.marks.geojson",
            {"type": "FeatureCollection", "features": 7},
            r"a int \(expected a list",
        ),
        (
            "str.marks.geojson",
            {"type": "FeatureCollection", "features": "abc"},
            r"a str \(expected a list",
        ),
    ],
)
def test_a_marks_file_that_is_no_marks_is_refused_naming_the_file(tmp_path, name, change, says):
    p = _write(tmp_path, name, change)
    with pytest.raises(DataFormatError, match=says) as info:
        read_marks(p, FRAME, skip=lambda e: pytest.fail(str(e)))
    assert name in str(info.value)


def test_bytes_that_are_not_utf8_in_a_marks_file_are_refused(tmp_path):
    p = tmp_path / "latin.marks.geojson"
    p.write_bytes(json.dumps(_marks_doc()).replace("fence", "Stra\\u00dfe").encode() + b"\xdf")
    with pytest.raises(DataFormatError, match="latin.marks.geojson: not a marks file"):
        read_marks(p, FRAME)


def _damage(doc: dict, what: str) -> dict:
    doc = json.loads(json.dumps(doc))
    f = doc["features"][1]  # the point
    if what == "nan":
        f["geometry"]["coordinates"][0] = float("nan")
    elif what == "inf":
        f["geometry"]["coordinates"][2] = float("inf")
    elif what == "off globe":
        f["geometry"]["coordinates"][1] = 123.0
    elif what == "frame huge":
        f["properties"]["frame"] = 1e300
    elif what == "frame overflow":
        f["properties"]["frame"] = 10**40
    elif what == "frame negative":
        f["properties"]["frame"] = -3
    elif what == "frame text":
        f["properties"]["frame"] = "31"
    elif what == "time nan":
        f["properties"]["media_time_s"] = float("nan")
    elif what == "kind":
        f["properties"]["kind"] = "circle"
    elif what == "no geometry":
        f["geometry"] = None
    elif what == "2d":
        f["geometry"]["coordinates"] = f["geometry"]["coordinates"][:2]
    elif what == "strings":
        f["geometry"]["coordinates"] = ["14.5", "46.05", "300"]
    elif what == "not a feature":
        doc["features"][1] = 5
    elif what == "attributes":
        f["properties"]["object_id"] = "B1"
        f["properties"]["object_attributes"] = "{broken"
    return doc


@pytest.mark.parametrize(
    "what, says",
    [
        ("nan", "not finite"),
        ("inf", "not finite"),
        ("off globe", "latitude beyond"),
        ("frame huge", "frame 1e+300"),
        ("frame overflow", "frame 1000000000000000000000000000000000000000"),
        ("frame negative", "frame -3"),
        ("frame text", "frame '31'"),
        ("time nan", "media_time_s nan"),
        ("kind", "kind 'circle'"),
        ("no geometry", "geometry is not an object"),
        ("2d", "not [lon, lat, h] positions"),
        ("strings", "coordinates that are not numbers"),
        ("not a feature", "not a GeoJSON Feature"),
        ("attributes", "object_attributes"),
    ],
)
def test_a_damaged_mark_is_left_out_naming_its_feature(tmp_path, what, says):
    p = _write(tmp_path, "walk.marks.geojson", _damage(_marks_doc(), what))
    before = _digest(p)
    skipped: list[DataFormatError] = []
    marks = read_marks(p, FRAME, skipped.append)
    assert [m.label for m in marks] == ["fence", "field"]
    (error,) = skipped
    text = str(error)
    assert "walk.marks.geojson field 'features[1]'" in text and says in text, text
    if what != "not a feature":
        assert "'car'" in text  # the mark's label
    assert "\n" not in text
    with pytest.raises(DataFormatError, match=r"features\[1\]"):
        read_marks(p, FRAME)  # without `skip`: refused whole
    assert _digest(p) == before


def test_a_sound_marks_file_reads_back_whole(tmp_path):
    p = _write(tmp_path, "walk.marks.geojson", _marks_doc())
    marks = read_marks(p, FRAME, skip=lambda e: pytest.fail(str(e)))
    assert [m.kind for m in marks] == ["line", "point", "polygon"]
    np.testing.assert_allclose(marks[1].points, [[2, 3, 0.5]], atol=1e-6)
    assert len(marks[2].points) == 4


# --- CityJSON and CityGML ----------------------------------------------------------------------

COMPOUND = (
    "https://www.opengis.net/def/crs-compound?"
    "1=https://www.opengis.net/def/crs/EPSG/0/32632&2=https://www.opengis.net/def/crs/EPSG/0/3855"
)
SITE = (480_000.0, 5_550_000.0)
BUILDING = Building.box("A", (480_010.0, 5_550_020.0, 480_030.0, 5_550_035.0), 100.0, 112.0, {})


def _city_frame() -> LocalFrame:
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(32632, 4326, always_xy=True).transform(*SITE)
    return LocalFrame(lat, lon, 150.0)


def _doc() -> dict:
    return cityjson([BUILDING], COMPOUND, translate=(*SITE, 0.0))


@pytest.mark.parametrize(
    "what, field, says",
    [
        ("strings", "vertices", "item 0 is ['"),
        ("one string", "vertices", "item 3 is"),
        ("null", "vertices", "None"),
        ("two numbers", "vertices", "(expected 3 numbers)"),
        ("not a list", "vertices", "item 0 is 7"),
        ("scale", "transform", "3 numbers in scale"),
        ("zero scale", "transform", "no zero scale"),
        ("templates", "geometry-templates.vertices-templates", "item 0"),
    ],
)
def test_cityjson_numbers_that_are_not_numbers_are_refused_naming_the_field(
    tmp_path, what, field, says
):
    doc = _doc()
    if what == "strings":
        doc["vertices"] = [[str(c) for c in v] for v in doc["vertices"]]
    elif what == "one string":
        doc["vertices"][3][1] = "12"
    elif what == "null":
        doc["vertices"][2][2] = None
    elif what == "two numbers":
        doc["vertices"][0] = doc["vertices"][0][:2]
    elif what == "not a list":
        doc["vertices"][0] = 7
    elif what == "scale":
        doc["transform"]["scale"] = ["0.001", "0.001", "0.001"]
    elif what == "zero scale":
        doc["transform"]["scale"] = [0, 0, 0]
    elif what == "templates":
        doc["geometry-templates"] = {"templates": [], "vertices-templates": [["0", "0", "0"]]}
    p = tmp_path / "bad.city.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(SceneError) as info:
        read_city(p, _city_frame())
    text = str(info.value)
    assert "bad.city.json" in text and f"field {field!r}" in text and says in text, text


def test_cityjson_sequence_vertices_as_strings_are_refused_naming_the_line(tmp_path):
    doc = _doc()
    header = {k: v for k, v in doc.items() if k not in ("CityObjects", "vertices")}
    header["vertices"] = []
    feature = {
        "type": "CityJSONFeature",
        "id": "A",
        "CityObjects": doc["CityObjects"],
        "vertices": [[str(c) for c in v] for v in doc["vertices"]],
    }
    p = tmp_path / "seq.city.jsonl"
    p.write_text(json.dumps(header) + "\n" + json.dumps(feature) + "\n")
    with pytest.raises(SceneError, match=r"seq.city.jsonl:2 field 'vertices': item 0 is"):
        read_city(p, _city_frame())


def _image(path: Path) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(path)
    return path


def _opened(monkeypatch) -> list[Path]:
    """The images the city readers open from now on (PIL), recorded."""
    from PIL import Image

    opened: list[Path] = []
    real = Image.open

    def spy(fp, *args, **kwargs):
        opened.append(Path(fp).resolve())
        return real(fp, *args, **kwargs)

    monkeypatch.setattr(Image, "open", spy)
    return opened


@pytest.mark.parametrize("how", ["dotdot", "absolute", "link", "inside"])
def test_a_cityjson_texture_outside_the_models_folder_is_not_read(tmp_path, monkeypatch, how):
    model = tmp_path / "model"
    model.mkdir()
    secret = _image(tmp_path / "secret" / "wall.png")
    uri = {
        "dotdot": "../secret/wall.png",
        "absolute": str(secret),
        "link": "linked.png",
        "inside": "tex/wall.png",
    }[how]
    if how == "link":
        (model / "linked.png").symlink_to(secret)
    if how == "inside":
        _image(model / "tex" / "wall.png")
    doc = _doc()
    doc["appearance"] = {
        "textures": [{"type": "PNG", "image": uri}],
        "vertices-texture": [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
    }
    solid = doc["CityObjects"]["A"]["geometry"][0]
    values = [[None] for _ in solid["boundaries"][0]]
    values[2] = [[0, 0, 1, 2, 3]]
    solid["texture"] = {"winter": {"values": [values]}}
    p = model / "textured.city.json"
    p.write_text(json.dumps(doc))
    opened = _opened(monkeypatch)
    city = read_city(p, _city_frame())
    textured = sum(pr.textured for pr in city.mesh.primitives)
    if how == "inside":
        assert textured == 1 and opened == [(model / "tex" / "wall.png").resolve()]
        return
    assert textured == 0 and city.mesh.primitives  # the model still loads, drawn by kind
    assert secret.resolve() not in opened
    said = [m for m in city.notes.items if "outside the model's folder" in m]
    assert len(said) == 1 and "textured.city.json" in said[0] and repr(uri) in said[0], said


@pytest.mark.parametrize("uri", ["../secret/wall.png", "ABSOLUTE"])
def test_a_citygml_texture_outside_the_models_folder_is_not_read(tmp_path, monkeypatch, uri):
    model = tmp_path / "model"
    model.mkdir()
    secret = _image(tmp_path / "secret" / "wall.png")
    uri = str(secret) if uri == "ABSOLUTE" else uri
    path = write_citygml(model / "textured.gml", [BUILDING], "EPSG:32632+3855")
    appearance = (
        '<app:appearanceMember xmlns:app="http://www.opengis.net/citygml/appearance/2.0">'
        "<app:Appearance><app:theme>rgbTexture</app:theme>"
        "<app:surfaceDataMember><app:ParameterizedTexture>"
        f"<app:imageURI>{uri}</app:imageURI>"
        '<app:target uri="#A_p2"><app:TexCoordList>'
        '<app:textureCoordinates ring="#A_p2_r0">0 0 1 0 1 1 0 1 0 0</app:textureCoordinates>'
        "</app:TexCoordList></app:target></app:ParameterizedTexture></app:surfaceDataMember>"
        "<app:surfaceDataMember><app:GeoreferencedTexture>"
        f"<app:imageURI>{uri}</app:imageURI><app:target>#A_p0</app:target>"
        "</app:GeoreferencedTexture></app:surfaceDataMember>"
        "</app:Appearance></app:appearanceMember>"
    )
    path.write_text(path.read_text().replace("</core:CityModel>", appearance + "</core:CityModel>"))
    secret.with_suffix(".pgw").write_text("1 0 0 -1 480010 5550035")  # a world file
    opened = _opened(monkeypatch)
    city = read_city(path, _city_frame())
    assert not any(pr.textured for pr in city.mesh.primitives) and city.mesh.primitives
    assert not opened
    said = [m for m in city.notes.items if "outside the model's folder" in m]
    assert said and all(repr(uri) in m and "textured.gml" in m for m in said), city.notes.items
