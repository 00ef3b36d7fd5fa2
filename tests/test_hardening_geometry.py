"""Issue 51's damaged places, archives and manifests, each written here: a search polygon or an
`export ortho --area` that is no polygon (a Point, a LineString, empty, crossing itself, NaN or
infinite corners, a feature without geometry, not JSON), archive geometry that is not WKB or not
finite, `geofuse index` of folders where nothing can be indexed, a manifest's [[clips]] with an
unknown pose source, and a manifest naming more clips than the renderer draws at once. Each is
one line naming the file and the field (exit 2) or a warning, never a traceback; no input is
written."""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import shapely

from app.archive.clips import ClipResult
from app.archive.store import read_footprints, write_archive
from app.cli import main
from app.core.errors import DataFormatError, ManifestError
from app.io.area import read_area
from app.render.passes import MAX_EXTRA
from app.render.renderer import nearest_in_time
from app.session.config import ATTITUDE_SOURCES, read_config
from app.simulate.sample import SAMPLE_DIR
from tests.test_projectors import _pixel_of, _ring, _ring_still

SITE = (34.7997, 113.5299)  # lat, lon: the synthetic archive's footprints lie around it
SQUARE = [[113.5298, 34.7996], [113.5300, 34.7996], [113.5300, 34.7998], [113.5298, 34.7998]]


def _ring_of(corners: list) -> list:
    return [*corners, corners[0]]


POLYGON = {"type": "Polygon", "coordinates": [_ring_of(SQUARE)]}

# name -> (the file's text, what the one-line error says, the field it names)
BAD_AREAS = {
    "point": (
        json.dumps({"type": "Point", "coordinates": SQUARE[0]}),
        "got a Point, expected a Polygon or MultiPolygon",
        "type",
    ),
    "linestring feature": (
        json.dumps({"type": "Feature", "geometry": {"type": "LineString", "coordinates": SQUARE}}),
        "got a LineString, expected a Polygon or MultiPolygon",
        "geometry",
    ),
    "nan corner": (
        json.dumps(
            {
                "type": "Polygon",
                "coordinates": [_ring_of([SQUARE[0], [math.nan, 34.7996], *SQUARE[2:]])],
            }
        ),
        "NaN or infinite",
        "coordinates",
    ),  # fmt: skip
    "infinite corner": (
        '{"type": "Polygon", "coordinates": [[[113.5298, 34.7996], [1e999, 34.7996], '
        "[113.53, 34.7998], [113.5298, 34.7996]]]}",
        "NaN or infinite",
        "coordinates",
    ),
    "empty polygon": (
        json.dumps({"type": "Polygon", "coordinates": []}),
        "an empty Polygon",
        "coordinates",
    ),
    "self-intersecting": (
        json.dumps(
            {
                "type": "Polygon",
                "coordinates": [_ring_of([SQUARE[0], SQUARE[2], SQUARE[1], SQUARE[3]])],
            }
        ),
        "Self-intersection",
        "coordinates",
    ),  # fmt: skip
    "feature without geometry": (
        json.dumps({"type": "Feature", "properties": {}, "geometry": None}),
        "no geometry",
        "geometry",
    ),
    "collection, second feature a point": (
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [
                    {"type": "Feature", "geometry": POLYGON},
                    {"type": "Feature", "geometry": {"type": "Point", "coordinates": SQUARE[0]}},
                ],
            }
        ),
        "got a Point",
        "features[1].geometry",
    ),
    "features not a list": (
        json.dumps({"type": "FeatureCollection", "features": {"a": 1}}),
        "expected a non-empty list of features",
        "features",
    ),
    "latitude and longitude swapped": (
        json.dumps({"type": "Polygon", "coordinates": [_ring_of([[y, x] for x, y in SQUARE])]}),
        "latitudes 113.53 to 113.53",
        "coordinates",
    ),
    "polygon of strings": (
        json.dumps({"type": "Polygon", "coordinates": [[["a", "b"], ["c", "d"]]]}),
        "not a GeoJSON geometry",
        "type",
    ),
    "not json": ("{this is not json", "not JSON", None),
    "a json array": ("[1, 2, 3]", "expected a GeoJSON object", None),
}


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / f"{name.replace(' ', '_').replace(',', '')}.geojson"
    path.write_text(text, encoding="utf-8")
    return path


def _said(err: str, *parts: str) -> None:
    """One line of error on stderr, with every part, and no traceback."""
    assert "Traceback" not in err, err
    lines = [x for x in err.splitlines() if x.startswith("geofuse: error:")]
    assert len(lines) == 1, err
    for part in parts:
        assert part in lines[0], (part, lines[0])


@pytest.mark.parametrize("name", list(BAD_AREAS))
def test_a_bad_area_is_one_error_naming_the_file_and_field(name, tmp_path):
    text, says, field = BAD_AREAS[name]
    path = _write(tmp_path, name, text)
    with pytest.raises(DataFormatError) as caught:
        read_area(path, "--area")
    assert caught.value.path == path and says in caught.value.detail, caught.value
    assert caught.value.field == field
    assert "\n" not in str(caught.value)


def test_a_good_area_and_a_collection_of_two(tmp_path):
    one = read_area(_write(tmp_path, "one", json.dumps(POLYGON)), "--polygon")
    assert one.geom_type == "Polygon" and one.bounds == pytest.approx((*SQUARE[0], *SQUARE[2]))
    east = [[x + 0.001, y] for x, y in SQUARE]
    two = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "geometry": POLYGON},
            {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [_ring_of(east)]}},
        ],
    }
    both = read_area(_write(tmp_path, "two", json.dumps(two)), "--polygon")
    assert both.geom_type == "MultiPolygon" and both.bounds[2] == pytest.approx(east[1][0])
    data = _write(tmp_path, "bytes", "")
    data.write_bytes(b'{"type": "Polygon", "coordinates": [[[\xff\xfe]]]}')
    with pytest.raises(DataFormatError, match="not UTF-8"):
        read_area(data, "--polygon")


def _row(frame: int) -> dict:
    """One footprint row as index_clip writes it (a square around SITE)."""
    return {
        "clip": "/clips/walk.mp4",
        "frame": frame,
        "clip_s": float(frame),
        "utc": None,
        "sensor_lat": SITE[0],
        "sensor_lon": SITE[1],
        "sensor_h": 120.0,
        "heading_deg": 0.0,
        "pitch_deg": -40.0,
        "roll_deg": 0.0,
        "axis_e": 0.0,
        "axis_n": 0.77,
        "axis_u": -0.64,
        "hfov_deg": 60.0,
        "centre_h": 110.0,
        "geometry": shapely.to_wkb(shapely.Polygon(SQUARE)),
    }


@pytest.fixture
def archive(tmp_path) -> Path:
    """A small archive of one clip's three footprints, written as `geofuse index` writes one."""
    out = tmp_path / "archive.parquet"
    rows = [_row(k) for k in range(3)]
    write_archive(out, [ClipResult("/clips/walk.mp4", 10, 1, "fp", "indexed", rows=rows)])
    return out


@pytest.mark.parametrize(
    "name", ["point", "nan corner", "self-intersecting", "feature without geometry"]
)
def test_find_with_a_bad_polygon_says_so(name, archive, tmp_path, capsys):
    text, says, field = BAD_AREAS[name]
    path = _write(tmp_path, name, text)
    before = path.read_bytes()
    assert main(["find", str(archive), "--polygon", str(path)]) == 2
    _said(capsys.readouterr().err, str(path), f"field '{field}'", says, "--polygon")
    assert path.read_bytes() == before


def test_find_with_a_good_polygon_finds_the_clip(archive, tmp_path, capsys):
    path = _write(tmp_path, "good", json.dumps({"type": "Feature", "geometry": POLYGON}))
    assert main(["find", str(archive), "--polygon", str(path), "--json"]) == 0
    hits = json.loads(capsys.readouterr().out)
    assert [h["clip"] for h in hits] == ["/clips/walk.mp4"]


def _damaged(archive: Path, blob: bytes) -> Path:
    """A copy of the archive whose first footprint's geometry bytes are `blob`."""
    table = pq.read_table(archive)
    i = table.schema.get_field_index("geometry")
    column = table.column("geometry").to_pylist()
    column[0] = blob
    out = archive.with_name("damaged.parquet")
    field = table.schema.field(i)
    pq.write_table(table.set_column(i, field, pa.array(column, type=field.type)), out)
    return out


NAN_SQUARE = [SQUARE[0], [math.nan, SQUARE[1][1]], *SQUARE[2:]]


@pytest.mark.parametrize(
    "blob, says",
    [
        (b"these bytes are no WKB", "bytes that are not WKB"),
        (b"\x01\x03\x00\x00\x00", "bytes that are not WKB"),  # cut short
        (shapely.to_wkb(shapely.Polygon(NAN_SQUARE)), "NaN or infinite coordinates"),
        (
            shapely.to_wkb(shapely.Polygon([SQUARE[0], [math.inf, 34.7996], *SQUARE[2:]])),
            "NaN or infinite coordinates",
        ),
    ],
    ids=["not wkb", "wkb cut short", "nan", "inf"],
)
def test_archive_geometry_that_is_not_wkb_or_not_finite_is_one_error(blob, says, archive, capsys):
    damaged = _damaged(archive, blob)
    digest = hashlib.sha256(damaged.read_bytes()).hexdigest()
    with pytest.raises(DataFormatError) as caught:
        read_footprints(damaged)
    assert caught.value.field == "geometry" and says in caught.value.detail
    point = f"{SITE[0]},{SITE[1]}"
    assert main(["find", str(damaged), "--point", point, "--radius", "5"]) == 2
    _said(capsys.readouterr().err, str(damaged), "field 'geometry'", says)
    assert hashlib.sha256(damaged.read_bytes()).hexdigest() == digest


def test_a_damaged_clips_table_is_one_error(archive, tmp_path, capsys):
    """An incremental `index` into an archive whose clips table is not Parquet."""
    archive.with_name("archive.clips.parquet").write_bytes(b"PAR1 and then nothing")
    empty = tmp_path / "none"
    empty.mkdir()
    assert main(["index", str(empty), "--out", str(archive)]) == 2
    _said(capsys.readouterr().err, "archive.clips.parquet", "not Parquet")


@pytest.mark.gl
@pytest.mark.parametrize("name", ["point", "nan corner", "infinite corner", "empty polygon"])
def test_export_ortho_with_a_bad_area_says_so(name, tmp_path, capsys):
    session = tmp_path / "walk"
    shutil.copytree(SAMPLE_DIR, session)
    text, says, field = BAD_AREAS[name]
    area = _write(tmp_path, name, text)
    out = tmp_path / "ortho.tif"
    argv = ["export", "ortho", str(session / "session.toml"), "--area", str(area)]
    assert main([*argv, "--out", str(out)]) == 2
    _said(capsys.readouterr().err, str(area), f"field '{field}'", says, "--area")
    assert not out.exists()


def test_index_of_an_empty_folder_says_nothing_was_indexed(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "a.parquet"
    assert main(["index", str(empty), "--out", str(out)]) == 2
    _said(capsys.readouterr().err, str(empty), "nothing indexed", "no clip found", "not written")
    assert not out.exists()


def test_index_of_a_folder_without_clips_says_what_it_skipped(tmp_path, capsys):
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "readme.txt").write_text("no clips here\n")
    (folder / "photo.jpg").write_bytes(b"\xff\xd8\xff")
    (folder / "settings.toml").write_text('[video]\ntitle = "not a manifest"\n')
    out = tmp_path / "a.parquet"
    assert main(["index", str(folder), "--out", str(out)]) == 2
    _said(
        capsys.readouterr().err,
        "no clip found",
        "2 file(s) skipped: not a clip",
        "1 file(s) skipped: a .toml that is not a session manifest",
    )
    assert not out.exists()


@pytest.mark.gl
def test_index_of_only_damaged_clips_says_why_each_failed(tmp_path, capsys):
    """Two damaged clips (bytes that are no MP4, a manifest whose video is no video) on a
    LocalCluster of one worker: exit 2, each reason said, no archive written."""
    folder = tmp_path / "clips"
    folder.mkdir()
    (folder / "broken.mp4").write_bytes(bytes(range(256)) * 64)
    walk = folder / "walk"
    shutil.copytree(SAMPLE_DIR, walk)
    (walk / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"\x00" * 4000)
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    out = tmp_path / "a.parquet"
    assert main(["index", str(folder), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    _said(err, "nothing indexed", "2 clip(s) found", "2 failed", "broken.mp4", "session.toml")
    assert not out.exists()
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before


def _manifest_with_clips(folder: Path, clips: list[str]) -> Path:
    """The sample session copied to `folder`, its manifest naming further clips ([[clips]]
    tables, each a TOML body) of a copy of itself."""
    shutil.copytree(SAMPLE_DIR, folder)
    manifest = folder / "session.toml"
    shutil.copy(manifest, folder / "other.toml")
    tables = "".join(f'\n[[clips]]\npath = "other.toml"\n{body}\n' for body in clips)
    manifest.write_text(manifest.read_text() + tables)
    return manifest


def test_an_unknown_clip_source_is_refused_naming_the_key_and_the_choices(tmp_path, capsys):
    manifest = _manifest_with_clips(tmp_path / "walk", ["", 'source = "bogus"'])
    with pytest.raises(ManifestError) as caught:
        read_config(manifest)
    assert caught.value.field == "clips[1].source"
    assert "'bogus'" in caught.value.detail and "'gd-ahrs'" in caught.value.detail
    out = tmp_path / "r.png"
    assert main(["render", "--session", str(manifest), "--time", "2", "--out", str(out)]) == 2
    _said(capsys.readouterr().err, "field 'clips[1].source'", "got 'bogus'", "'registered'")
    assert not out.exists()


def test_every_source_a_session_offers_is_a_name_a_manifest_takes():
    from app.session import FILTERS, open_session

    assert set(FILTERS) <= set(ATTITUDE_SOURCES)
    assert set(open_session(SAMPLE_DIR / "session.toml").sources) <= set(ATTITUDE_SOURCES)


@pytest.mark.gl
def test_a_known_source_the_clip_does_not_offer_is_refused_by_render(tmp_path, capsys):
    manifest = _manifest_with_clips(tmp_path / "walk", ['source = "camera"'])
    out = tmp_path / "r.png"
    argv = ["render", "--session", str(manifest), "--time", "2", "--source", "gd-ahrs"]
    assert main([*argv, "--size", "96x54", "--out", str(out)]) == 2
    _said(capsys.readouterr().err, str(manifest), "field 'clips[0].source'", "'camera'", "offers")


def test_the_projectors_nearest_in_time_are_kept():
    ages = [0.5, -0.01, 3.0, 0.02, -2.0, 0.0, 0.1, 0.2, 0.3, 0.03]
    kept = nearest_in_time(ages, [0.0] * len(ages))
    assert kept == [1, 3, 5, 6, 7, 8, 9] and len(kept) == MAX_EXTRA  # 0.5, 3 and -2 s out
    # a tie goes to the higher priority, then to the one offered first
    assert nearest_in_time([0.0] * 9, [0, 0, 0, 0, 0, 0, 0, 0, 1.0]) == [0, 1, 2, 3, 4, 5, 8]
    assert nearest_in_time([1.0, 2.0], [0.0, 0.0]) == [0, 1]


@pytest.mark.gl
def test_more_projectors_than_drawn_at_once_keep_the_nearest_in_time():
    """Eleven projectors on a ring (the first and ten further ones): the seven further ones
    whose frames are nearest the moment drawn show their colours, the three oldest do not, and
    the still says that three were left out."""
    colours = [
        (255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (255, 0, 255), (0, 255, 255),
        (255, 128, 0), (128, 0, 255), (0, 128, 255), (128, 255, 0), (255, 0, 128),
    ]  # fmt: skip
    views = _ring(colours)
    ages = [0.0, 0.1, 4.0, 0.2, 0.0, 6.0, 0.3, 0.0, 5.0, 0.1]
    still = _ring_still(views, [0.0, *ages])
    assert still.left_out is not None and still.left_out.startswith("3 further clip(s) left out")
    for (img, _, centre), age in zip(views, [0.0, *ages], strict=True):
        shown = np.abs(still.rgb[_pixel_of(centre)].astype(int) - img[0, 0]).max() <= 3
        assert shown == (age < 1.0), (centre, age)


@pytest.mark.gl
def test_render_of_a_manifest_naming_ten_clips_warns_once(tmp_path, capsys):
    """`geofuse render` of a manifest with ten [[clips]] (more than the renderer draws at once):
    the image is written, the clips left out said once as a warning, no traceback."""
    manifest = _manifest_with_clips(tmp_path / "walk", [f"offset_s = {k * 0.2}" for k in range(10)])
    digest = hashlib.sha256(manifest.read_bytes()).hexdigest()
    out = tmp_path / "r.png"
    argv = ["render", "--session", str(manifest), "--time", "4", "--source", "gd-ahrs"]
    assert main([*argv, "--size", "160x90", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and out.is_file()
    warned = [x for x in captured.err.splitlines() if "left out" in x]
    assert len(warned) == 1 and warned[0].startswith("warning: 3 further clip(s) left out"), warned
    assert "at most 8 projectors" in warned[0]
    assert captured.out.count("clip.mp4 frame") == 10
    assert hashlib.sha256(manifest.read_bytes()).hexdigest() == digest


@pytest.mark.gl
def test_export_video_takes_a_further_clips_source_from_its_table(tmp_path, capsys):
    """export video opens a manifest's further clips under their [[clips]] source as render does:
    one the clip does not offer is refused naming the table's key, before anything is drawn."""
    manifest = _manifest_with_clips(tmp_path / "walk", ['source = "camera"'])
    out = tmp_path / "v.mp4"
    argv = ["export", "video", str(manifest), "--source", "gd-ahrs", "--out", str(out)]
    assert main(argv) == 2
    _said(capsys.readouterr().err, str(manifest), "field 'clips[0].source'", "'camera'", "offers")
    assert not out.exists()
