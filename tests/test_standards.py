"""GIS outputs checked against their standards by independent readers, on files written here:
GEOS (shapely) for footprint validity, an XML parser for KML altitudes, klvdata for MISB ST
0601 tags, Esri's Video Multiplexer headings; the camera's UTC clock; DJI subtitles as DJI
writes them (focal length units, millisecond times, 1 Hz dates)."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path

import av
import klvdata
import numpy as np
import pytest
from shapely.geometry import shape

from app.cli import main
from app.clips import open_clip
from app.demo import SAMPLE_DIR
from app.export.gis import FMV_FIELDS
from app.geoid import undulation
from app.io.dji_srt import read_srt, srt_fixes
from app.messages import Messages
from app.simulate import drone
from app.simulate.phone import write_video

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
    footprints; KML heights above sea level, GeoJSON above the ellipsoid."""
    clip = shared_data / "real" / "gopro" / "max-heromode.mp4"
    out = tmp_path / "walk.geojson"
    assert main(["export", "footprints", str(clip), "--out", str(out)]) == 0
    features = _footprints(out)
    assert len(features) > 50
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
    assert main(["export", "footprints", str(clip), "--out", str(kml)]) == 0
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
    assert main(["export", "fmv-csv", str(clip), "--out", str(fmv)]) == 0
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
    assert abs((first - drone.START.replace(tzinfo=timezone.utc)).total_seconds()) < 0.05
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
