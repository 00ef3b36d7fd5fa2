"""GIS outputs checked against their standards by independent readers, on files written here:
GEOS (shapely) for footprint validity, an XML parser for KML altitudes, klvdata for MISB ST
0601 tags, Esri's Video Multiplexer headings; the camera's UTC clock; DJI subtitles as DJI
writes them (focal length units, millisecond times, 1 Hz dates)."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from datetime import UTC, datetime
from pathlib import Path

import av
import klvdata
import numpy as np
import pytest
from PIL import Image
from shapely.geometry import shape

from app.cli import main
from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.export.gis import FMV_FIELDS
from app.footage.clips import open_clip
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.dji_srt import read_srt, srt_fixes
from app.scene.tiles import fetch
from app.scene.tiles import write as tjw
from app.scene.tiles.tileset import Tileset
from app.simulate import drone
from app.simulate import tileset as tw
from app.simulate.phone import write_video
from app.simulate.sample import SAMPLE_DIR

SAMPLE = SAMPLE_DIR / "session.toml"
KML = {"k": "http://www.opengis.net/kml/2.2"}


@pytest.fixture(scope="module")
def drone_clip(tmp_path_factory) -> Path:
    """A 6 s, 30 fps clip with the subtitle a DJI Air 2S writes beside it: one entry per frame
    with millisecond-rounded times (00:00:00,033 --> 00:00:00,067) and dated entries."""
    folder = tmp_path_factory.mktemp("drone")
    video = write_video(folder / "DJI_0001.MP4", np.arange(180) / 30.0, (96, 54), 0)
    (folder / "DJI_0001.SRT").write_text(drone.srt_text(6.0, 0.0), encoding="utf-8")
    return video


def _footprints(path: Path) -> list[dict]:
    return json.loads(path.read_text())["features"]


# --- footprints: valid simple features -----------------------------------------------------------


@pytest.mark.parametrize("every", [30])
def test_every_footprint_of_the_sample_is_valid(tmp_path, every):
    """The sample walk along the hall's facade: the image border runs up the walls, so its plan
    view folds back; the plan-view footprints are valid all the same (79 of 80 were not)."""
    out = tmp_path / "fp.geojson"
    assert (
        main(["export", "footprints", str(SAMPLE), "--out", str(out), "--every", str(every)]) == 0
    )
    features = _footprints(out)
    assert len(features) == 80
    shapes = [shape(f["geometry"]) for f in features]
    assert all(s.is_valid and s.area > 0 for s in shapes)
    assert {f["geometry"]["type"] for f in features} <= {"Polygon", "MultiPolygon"}


@pytest.mark.shared_data
def test_gopro_walk_footprints_utc_and_sea_level_heights(shared_data, tmp_path):
    """The GoPro MAX clip: its GPS time (GPSU 2019-11-18 23:45:14 UTC) in every export; valid
    footprints; KML heights above sea level, GeoJSON above the ellipsoid. Every 5th of its 315
    frames (what is checked holds frame by frame; each frame exported renders the scene)."""
    clip = shared_data / "real" / "gopro" / "max-heromode.mp4"
    out = tmp_path / "walk.geojson"
    every = ["--every", "5"]
    assert main(["export", "footprints", str(clip), "--out", str(out), *every]) == 0
    features = _footprints(out)
    assert 50 < len(features) <= 63  # of frames 0, 5, ..., 310
    assert all(shape(f["geometry"]).is_valid for f in features)
    first = datetime.fromisoformat(features[0]["properties"]["utc"].replace("Z", "+00:00"))
    assert first.date().isoformat() == "2019-11-18" and first.hour == 23 and first.minute == 45
    t = [f["properties"]["time_s"] for f in features]
    utc = [
        datetime.fromisoformat(f["properties"]["utc"].replace("Z", "+00:00")).timestamp()
        for f in features
    ]
    np.testing.assert_allclose(np.diff(utc), np.diff(t), atol=1e-5)  # one clock, advancing
    # The camera track: KML absolute (sea level) = GeoJSON's ellipsoidal height - N (EGM2008).
    kml = tmp_path / "walk.kml"
    assert main(["export", "footprints", str(clip), "--out", str(kml), *every]) == 0
    root = ET.parse(kml).getroot()
    folders = {f.findtext("k:name", namespaces=KML): f for f in root.iter(f"{{{KML['k']}}}Folder")}
    assert set(folders) == {"footprints", "footprint borders (3D)", "camera track"}
    line = folders["camera track"].find(".//k:LineString", KML)
    assert line.findtext("k:altitudeMode", namespaces=KML) == "absolute"
    kml_track = np.array(
        [
            [float(v) for v in p.split(",")]
            for p in line.findtext("k:coordinates", namespaces=KML).split()
        ]
    )
    (track,) = _footprints(tmp_path / "walk_track.geojson")
    ellipsoidal = np.array(track["geometry"]["coordinates"])
    n = undulation(ellipsoidal[:, 1], ellipsoidal[:, 0])
    assert np.all(np.abs(n) > 1.0)  # the datums differ here, so the check can fail
    np.testing.assert_allclose(kml_track[:, 2], ellipsoidal[:, 2] - n, atol=2e-3)
    polygons = folders["footprints"].findall(".//k:Polygon", KML)
    assert polygons and all(
        p.findtext("k:altitudeMode", namespaces=KML) == "clampToGround" for p in polygons
    )
    # The FMV CSV's time stamps are the same UTC microseconds.
    fmv = tmp_path / "walk.csv"
    assert main(["export", "fmv-csv", str(clip), "--out", str(fmv), *every]) == 0
    with fmv.open() as f:
        rows = list(csv.DictReader(f))
    assert int(rows[0]["UNIX Time Stamp"]) == pytest.approx(utc[0] * 1e6, abs=1)


# --- the FMV CSV: Esri's headings, sea-level altitudes, offset corners ---------------------------


def test_fmv_csv_follows_the_multiplexer_template(tmp_path):
    out = tmp_path / "fmv.csv"
    assert main(["export", "fmv-csv", str(SAMPLE), "--out", str(out), "--every", "200"]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    for name in (
        "Sensor True Altitude",
        "Sensor Ellipsoid Height",
        "Frame Center Elevation",
        "Frame Center Height Above Ellipsoid",
        *(f"Offset Corner {c} Point {k}" for k in range(1, 5) for c in ("Latitude", "Longitude")),
    ):
        assert name in rows[0], name
    assert not any(h.startswith("Corner ") for h in FMV_FIELDS)  # absolute corners are not Esri's
    checked = 0
    for r in rows:
        lat, lon = float(r["Sensor Latitude"]), float(r["Sensor Longitude"])
        n = float(undulation(lat, lon))
        assert float(r["Sensor True Altitude"]) == pytest.approx(
            float(r["Sensor Ellipsoid Height"]) - n, abs=1e-6
        )
        if r["Frame Center Latitude"] and r["Offset Corner Latitude Point 1"]:
            offset = np.array(
                [float(r[f"Offset Corner {c} Point 1"]) for c in ("Latitude", "Longitude")]
            )
            # degrees from the centre (within the 2 km clip), not absolute ones
            assert np.all(np.abs(offset) < 0.03) and np.any(offset != 0.0)
            checked += 1
    assert checked >= 3


# --- KLV: tags 15/25/75/78 and one local set per frame --------------------------------------------


def _klv_sets(path: Path) -> tuple[int, list[dict]]:
    frames, sets = 0, []
    with av.open(str(path)) as c:
        streams = [c.streams.video[0], next(s for s in c.streams if s.type == "data")]
        for p in c.demux(*streams):
            if p.size and p.stream.type == "data":
                (ls,) = list(klvdata.StreamParser(bytes(p)))
                sets.append({k: v[3] for k, v in ls.MetadataList().items()})
            elif p.size:
                frames += 1
    return frames, sets


def test_dji_klv_has_a_local_set_per_frame_with_millisecond_subtitle_times(drone_clip, tmp_path):
    """DJI subtitle times are whole milliseconds; the KLV still has one local set per video
    frame, its Precision Time Stamp the subtitle's date (taken as UTC), heights on both datums."""
    out = tmp_path / "d.ts"
    assert main(["export", "klv", str(drone_clip), "--out", str(out)]) == 0
    frames, sets = _klv_sets(out)
    assert frames == 180 and len(sets) == 180
    first = datetime.fromisoformat(sets[0][2])  # klvdata: '2025-11-15 09:46:40.000000+00:00'
    assert abs((first - drone.START.replace(tzinfo=UTC)).total_seconds()) < 0.05
    lat, lon = float(sets[0][13]), float(sets[0][14])
    n = float(undulation(lat, lon))
    assert float(sets[0][15]) == pytest.approx(float(sets[0][75]) - n, abs=0.65)
    with_centre = [s for s in sets if 25 in s and 78 in s]
    assert with_centre
    for s in with_centre:
        nc = float(undulation(float(s[23]), float(s[24])))
        assert float(s[25]) == pytest.approx(float(s[78]) - nc, abs=0.65)


# --- clocks ---------------------------------------------------------------------------------------


def test_a_clip_without_a_clock_says_so(tmp_path, capsys):
    """A DJI clip whose subtitle has no dates: no UTC anywhere, and the export says why."""
    folder = tmp_path / "c"
    folder.mkdir()
    video = write_video(folder / "DJI_0002.MP4", np.arange(60) / 30.0, (96, 54), 0)
    text = drone.srt_text(2.0, 0.0)
    undated = "\n".join(
        line for line in text.split("\n") if not line[:4].isdigit() or "-" not in line[:8]
    )
    (folder / "DJI_0002.SRT").write_text(undated, encoding="utf-8")
    out = tmp_path / "fp.geojson"
    assert main(["export", "footprints", str(video), "--out", str(out)]) == 0
    assert all(f["properties"]["utc"] is None for f in _footprints(out))
    assert "no UTC clock is known" in capsys.readouterr().err


def test_dji_dates_give_the_session_its_clock(drone_clip):
    session = open_clip(drone_clip)
    assert session.utc_of(0.0) == pytest.approx(drone.START.timestamp(), abs=1e-3)
    assert any("no time zone" in m.text for m in session.messages.since(0))


# --- DJI subtitles as DJI writes them ------------------------------------------------------------


def test_focal_length_in_each_layouts_unit(tmp_path):
    """`[focal_len: 24.00]` (Mavic 3: mm) and `[focal_len : 240]` (older: tenths) are both 24 mm,
    a 73.7 degree pinhole; 2.4 mm (a 164.8 degree pinhole) was the bug."""
    text = drone.srt_text(2.0, 0.0)
    assert "[focal_len : 240]" in text
    for name, body in (
        ("old", text),
        ("new", text.replace("[focal_len : 240]", "[focal_len: 24.00]")),
    ):
        folder = tmp_path / name
        folder.mkdir()
        video = write_video(folder / "DJI_0003.MP4", np.arange(60) / 30.0, (96, 54), 0)
        (folder / "DJI_0003.SRT").write_text(body, encoding="utf-8")
        assert np.nanmedian(read_srt(folder / "DJI_0003.SRT").focal_len) == pytest.approx(24.0)
        session = open_clip(video)
        hfov = np.degrees(2 * np.arctan(session.intrinsics.width / 2 / session.intrinsics.fx))
        assert hfov == pytest.approx(drone.HFOV_DEG, abs=0.05)


def test_a_focal_length_no_camera_has_is_refused(tmp_path, capsys):
    video = write_video(tmp_path / "DJI_0004.MP4", np.arange(60) / 30.0, (96, 54), 0)
    body = drone.srt_text(2.0, 0.0).replace("[focal_len : 240]", "[focal_len: 2.40]")
    (tmp_path / "DJI_0004.SRT").write_text(body, encoding="utf-8")
    assert main(["solve", str(video), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "DJI_0004.SRT" in err and "focal_len" in err and "2.4 mm" in err


def test_one_hertz_dates_truncated_to_the_second_keep_every_fix(tmp_path):
    """Entries without timing lines, dated to the second, two per second (10 m apart each): every
    fix kept, half a second apart (they were dropped as jumps: two fixes at one time)."""
    lines = []
    for k in range(8):
        lines.append(
            f"{k + 1}\n2017.07.03 10:15:{3 + k // 2:02d}\n"
            f"GPS(-58.{456300 + 60 * k:06d},-34.738300,19) BAROMETER:20.{k}\n"
        )
    path = tmp_path / "dated.srt"
    path.write_text("\n".join(lines), encoding="utf-8")
    messages = Messages()
    fixes = srt_fixes(read_srt(path, messages), messages)
    assert len(fixes.t) == 8
    np.testing.assert_allclose(np.diff(fixes.t), 0.5, atol=1e-6)


def test_out_of_range_values_are_refused(tmp_path, capsys):
    assert (
        main(
            [
                "export",
                "footprints",
                str(SAMPLE),
                "--out",
                str(tmp_path / "f.geojson"),
                "--every",
                "0",
            ]
        )
        == 2
    )
    assert "--every" in capsys.readouterr().err


# --- 3D Tiles as the world publishes them ---------------------------------------------------------

ORIGIN = (46.05, 14.5, 300.0)
WALL_V = np.array([[-10.0, 20.0, 0.0], [10.0, 20.0, 0.0], [10.0, 20.0, 20.0], [-10.0, 20.0, 20.0]])
WALL_F = np.array([[0, 1, 2], [0, 2, 3]])


def _local_tileset(folder: Path, children: list[dict] | None = None) -> Path:
    """A tileset in its own coordinates (as the official 3D Tiles 1.1 samples are): a wall 20 m
    north of (0, 0, 0), 20 m wide and high; no georeference."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "wall.glb").write_bytes(tw.glb(WALL_V, WALL_F))
    root = {
        "boundingVolume": {"box": tjw.box_of([-12, -12, -1], [12, 22, 21])},
        "geometricError": 0.0,
        "refine": "ADD",
        "content": {"uri": "wall.glb"},
    }
    if children:
        root["children"] = children
    return tjw.write_json(
        folder / "tileset.json",
        {"asset": {"version": "1.1"}, "geometricError": 10.0, "root": root},
    )


def _render(tileset: Path, tmp_path: Path, heading: float, *extra: str) -> tuple[int, np.ndarray]:
    image = tmp_path / "white.png"
    Image.fromarray(np.full((48, 64, 3), 255, np.uint8)).save(image)
    out = tmp_path / f"r{heading:g}.png"
    lat, lon, h = ORIGIN
    code = main(
        [
            "render", "--scene", str(tileset), "--image", str(image),
            "--pose", f"{lat},{lon},{h + 10},{heading},0,0", "--fov", "60",
            "--view-from", "0,0,10", "--look-at", f"{20 * np.sin(np.radians(heading)):.3f},{20 * np.cos(np.radians(heading)):.3f},10",
            "--size", "64x48", "--out", str(out), *extra,
        ]
    )  # fmt: skip
    return code, (np.asarray(Image.open(out).convert("RGB")) if out.exists() else None)


def test_a_tileset_without_georeference_is_placed_at_the_origin(tmp_path, capsys):
    """The wall, 20 m north in the tileset's coordinates, turned 90 deg clockwise by
    --scene-heading, stands 20 m east of --origin: a camera there looking east sees it (the
    white image on it), one looking north sees nothing, and says so."""
    ts = _local_tileset(tmp_path / "local")
    lat, lon, h = ORIGIN
    origin = ["--origin", f"{lat},{lon},{h}", "--scene-heading", "90"]
    code, east = _render(ts, tmp_path, 90.0, *origin)
    assert code == 0, capsys.readouterr().err
    assert east[24, 32].min() > 240  # the white image draped on the wall, at the view's centre
    code, north = _render(ts, tmp_path, 0.0, *origin)
    assert code == 1 and "nothing of the scene was drawn" in capsys.readouterr().err
    assert np.abs(north[24, 32] - np.array([0.62, 0.74, 0.86]) * 255).max() < 3  # background
    code, _ = _render(ts, tmp_path, 90.0)  # no origin: not placed, and told how
    err = capsys.readouterr().err
    assert code == 2 and "not georeferenced" in err and "--origin" in err


def test_what_cannot_be_drawn_is_said_by_render(tmp_path, capsys):
    """An i3dm and a pnts tile (skipped kinds) and a missing b3dm (dragon_high.b3dm): one summary
    line with the counts and the missing tile named."""
    folder = tmp_path / "mixed"
    folder.mkdir()
    (folder / "trees.i3dm").write_bytes(tw.other_tile(b"i3dm"))
    (folder / "cloud.pnts").write_bytes(tw.other_tile(b"pnts"))
    box = {"box": tjw.box_of([-12, -12, -1], [12, 22, 21])}
    children = [
        {"boundingVolume": box, "geometricError": 0.0, "content": {"uri": name}}
        for name in ("trees.i3dm", "cloud.pnts", "dragon_high.b3dm")
    ]
    ts = _local_tileset(folder, children)
    lat, lon, h = ORIGIN
    code, _ = _render(ts, tmp_path, 90.0, "--origin", f"{lat},{lon},{h}", "--scene-heading", "90")
    err = capsys.readouterr().err
    (line,) = [x for x in err.splitlines() if x.startswith("warning: 3D Tiles")]
    assert "1 instanced models (i3dm)" in line and "1 point clouds (pnts)" in line
    assert "1 tile missing or damaged" in line
    assert "dragon_high.b3dm" in line and code == 0  # the wall itself was drawn


def test_geometric_error_scales_with_the_transform_and_request_volumes_hold(tmp_path):
    """A tile whose transform scales by 10 has ten times its geometric error (CesiumJS); a tile
    with a viewerRequestVolume is selected only from inside it."""
    folder = tmp_path / "scaled"
    folder.mkdir()
    (folder / "wall.glb").write_bytes(tw.glb(WALL_V, WALL_F))
    scale = np.diag([10.0, 10.0, 10.0, 1.0])
    child = {
        "boundingVolume": {"box": tjw.box_of([-1.2, -1.2, -0.1], [1.2, 2.2, 2.1])},
        "transform": tjw.column_major(scale),
        "geometricError": 0.5,
        "content": {"uri": "wall.glb"},
        "viewerRequestVolume": {"box": tjw.box_of([-5, -5, 0], [5, 5, 50])},
    }
    ts_path = _local_tileset(folder, [child])
    ts = Tileset(str(ts_path), LocalFrame(*ORIGIN), ORIGIN, 0.0, 1.0)
    (tile,) = ts.root.children
    assert tile.geometric_error == pytest.approx(5.0)
    assert tile.requested_from(np.array([0.0, 0.0, 10.0]))
    assert not tile.requested_from(np.array([0.0, -80.0, 10.0]))  # the volume scales too: 50 m


def test_urls_keep_their_double_slash_in_messages():
    err = DataFormatError("https://example.com/city/tileset.json", "not found")
    assert str(err).startswith("https://example.com/city/tileset.json: ")
    assert fetch.display_name("https://example.com/city/tileset.json").startswith("https://")


def test_a_far_scene_is_said_on_a_still(tmp_path, capsys):
    """render --scene with the camera 5 km from the placed tileset warns, as sessions do."""
    ts = _local_tileset(tmp_path / "far")
    lat, lon, h = ORIGIN
    image = tmp_path / "w.png"
    Image.fromarray(np.full((48, 64, 3), 255, np.uint8)).save(image)
    main(
        [
            "render", "--scene", str(ts), "--origin", f"{lat},{lon},{h}", "--image", str(image),
            "--pose", f"{lat + 0.045},{lon},{h + 10},0,0,0", "--fov", "60",
            "--size", "64x48", "--out", str(tmp_path / "far.png"),
        ]
    )  # fmt: skip
    assert "the scene lies 5.0 km from the camera" in capsys.readouterr().err
