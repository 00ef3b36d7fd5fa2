"""`geofuse index` and `geofuse find` on a LocalCluster of 2 workers: a folder with the sample
session, a GoPro clip, a DJI clip written here, a damaged file and a duplicate; the GeoParquet
read back by geopandas with its CRS; `find` against the footprints computed directly; an
incremental re-run."""

from __future__ import annotations

import json
import shutil

import duckdb
import geopandas as gpd
import numpy as np
import pyarrow.parquet as pq
import pytest
import shapely

from app.archive import find, index_clip, place_of, read_clips
from app.archive.store import write_archive
from app.camera.frame_time import frame_at
from app.cli import main
from app.export.footprint import plan_footprint
from app.export.records import frame_records
from app.session import open_session
from app.simulate import drone
from app.simulate.phone import write_video
from app.simulate.sample import SAMPLE_DIR
from tests.conftest import run_viewer

pytestmark = pytest.mark.shared_data

FACADE = (34.79963493, 113.52984563)  # where the sample's centre pixel meets the hall at 20 s


@pytest.fixture(scope="module")
def archive(shared_data, tmp_path_factory):
    root = tmp_path_factory.mktemp("archive")
    clips = root / "clips"
    shutil.copytree(SAMPLE_DIR, clips / "walk")
    shutil.copy(shared_data / "real" / "gopro" / "max-heromode.mp4", clips / "GOPRO.MP4")
    dji = clips / "drone"
    dji.mkdir()
    write_video(dji / "DJI_0001.MP4", np.arange(180) / 30.0, (96, 54), 0)
    (dji / "DJI_0001.SRT").write_text(drone.srt_text(6.0, 0.0), encoding="utf-8")
    shutil.copy(dji / "DJI_0001.MP4", dji / "DJI_0002.MP4")  # the same clip stored twice
    shutil.copy(dji / "DJI_0001.SRT", dji / "DJI_0002.SRT")
    data = (clips / "GOPRO.MP4").read_bytes()
    (clips / "damaged.mp4").write_bytes(data[: len(data) // 20])
    out = root / "archive.parquet"
    code = main(["index", str(clips), "--out", str(out), "--workers", "2", "--every-s", "1"])
    return code, out, clips


def test_the_archive_holds_every_clip_and_says_what_failed(archive, capsys):
    code, out, clips = archive
    assert code == 0
    table = read_clips(out).set_index("path")
    status = table["status"].to_dict()
    assert status[str((clips / "walk" / "session.toml").resolve())] == "indexed"
    assert status[str((clips / "GOPRO.MP4").resolve())] == "indexed"
    dji = [status[str((clips / "drone" / f"DJI_000{k}.MP4").resolve())] for k in (1, 2)]
    assert sorted(dji) == ["duplicate", "indexed"]
    damaged = table.loc[str((clips / "damaged.mp4").resolve())]
    assert damaged["status"] == "failed" and "damaged.mp4" in damaged["error"]
    assert len(status) == 5  # the manifest's clip.mp4 is indexed through the manifest only
    walk = table.loc[str((clips / "walk" / "session.toml").resolve())]
    assert walk["utc_start"].year == 2025 and walk["footprints"] == 80
    assert table.loc[str((clips / "GOPRO.MP4").resolve()), "camera"] == "GoPro Max"


def test_geoparquet_reads_back_with_its_crs(archive):
    _, out, _ = archive
    frame = gpd.read_parquet(out)
    assert frame.crs.to_epsg() == 4326
    assert frame.geometry.is_valid.all() and len(frame) > 80
    meta = json.loads(pq.read_schema(out).metadata[b"geo"])
    assert meta["primary_column"] == "geometry" and meta["version"].startswith("1.")
    gopro = frame[frame["clip"].str.endswith("GOPRO.MP4")]
    assert gopro["utc"].min().year == 2019  # the camera's own GPS time


def test_find_gives_the_span_the_footprints_give(archive, capsys):
    """The facade point's spans against the sample's footprints computed here, frame by frame
    at the same spacing: the span around 20 s starts and ends where they do."""
    _, out, clips = archive
    place = place_of(FACADE, 2.0)
    hits = [h for h in find(out, place) if h.clip.endswith("session.toml")]
    span = next(h for h in hits if h.start_s <= 20.0 <= h.end_s)
    assert span.frame_s == pytest.approx(20.0, abs=1.01) and span.off_axis_deg < 5.0
    session = open_session(clips / "walk" / "session.toml")
    seen = [
        r.media_s
        for r in frame_records(session, session.sources[0], 30)
        if (s := plan_footprint(r.ground)) is not None and s.intersects(place)
    ]
    t = np.array(seen)
    around = t[(t >= span.start_s - 0.1) & (t <= span.end_s + 0.1)]
    assert around[0] == pytest.approx(span.start_s, abs=0.01)
    assert around[-1] == pytest.approx(span.end_s, abs=0.01)
    assert (
        main(["find", str(out), "--point", f"{FACADE[0]},{FACADE[1]}", "--radius", "2", "--json"])
        == 0
    )
    rows = json.loads(capsys.readouterr().out)
    assert {"clip", "start_utc", "end_utc", "start_s", "end_s"} <= set(rows[0])
    assert rows[0]["start_utc"].endswith("Z")
    far = shapely.Point(FACADE[1] + 1.0, FACADE[0]).buffer(0.001)
    assert find(out, far) == []


def test_an_incremental_run_indexes_nothing_new(archive, capsys):
    _, out, clips = archive
    before = gpd.read_parquet(out)
    assert main(["index", str(clips), "--out", str(out), "--workers", "2"]) == 0
    line = capsys.readouterr().out
    assert "0 indexed, 0 failed, 0 duplicates, 5 unchanged" in line
    assert len(gpd.read_parquet(out)) == len(before)


def test_the_viewer_opens_an_archive_and_the_clip_that_saw_a_point(display, tmp_path):
    """`geofuse view ARCHIVE.parquet` opens its clip and draws its footprints; G over the scene
    (`archive open X,Y`) seeks to the moment the archive says saw that point most head-on."""
    folder = tmp_path / "walk"
    shutil.copytree(SAMPLE_DIR, folder)
    manifest = folder / "session.toml"
    out = tmp_path / "walk.parquet"
    write_archive(out, [index_clip(str(manifest.resolve()), 1.0)])
    state, script = tmp_path / "s.json", tmp_path / "s.txt"
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0 pause\n0 view phone\n0.2 archive open 0.5,0.6\n"
        f"0.3 state {state}\n0.35 quit\n"
    )
    result = run_viewer(display, str(out), "--script", str(script), "--size", "960x540")
    assert result.returncode == 0, result.stderr[-2000:]
    s = json.loads(state.read_text())
    assert s["errors"] == [], s["errors"]
    a = s["archive"]
    assert a["footprints"] == 80 and a["clips"] == 1 and a["opened"] == str(manifest.resolve())
    best = find(out, place_of(tuple(a["picked"]), 1.0))
    assert best and a["opened_s"] == pytest.approx(best[0].frame_s, abs=0.05)
    pts = open_session(manifest).video.pts_s
    assert s["frame"] == frame_at(pts, a["opened_s"])


def test_duckdb_reads_the_archive(archive):
    """An independent Parquet reader (DuckDB): the footprints' WKB and covering bounding boxes
    as the GeoParquet metadata says, the same rows geopandas reads."""
    _, out, _ = archive
    con = duckdb.connect()
    rows = con.execute(
        f"select bbox.xmin, bbox.ymin, bbox.xmax, bbox.ymax, geometry from read_parquet('{out}')"
    ).fetchall()
    assert len(rows) == len(gpd.read_parquet(out))
    for xmin, ymin, xmax, ymax, blob in rows[::7]:
        shape_ = shapely.from_wkb(bytes(blob))
        assert shape_.is_valid
        np.testing.assert_allclose(shape_.bounds, (xmin, ymin, xmax, ymax), atol=1e-5)


def test_bad_archives_and_options_are_one_line_errors(tmp_path, capsys):
    other = tmp_path / "other.parquet"
    gpd.GeoDataFrame({"a": [1]}, geometry=[shapely.Point(0, 0)], crs=4326).to_parquet(other)
    assert main(["find", str(other), "--point", "1,1"]) == 2
    assert "not an archive written by `geofuse index`" in capsys.readouterr().err
    assert main(["find", str(tmp_path / "none.parquet"), "--point", "1,1"]) == 2
    assert "archive does not exist" in capsys.readouterr().err
    assert main(["index", str(tmp_path), "--out", str(tmp_path / "a.csv")]) == 2
    assert "expected a file ending in .parquet" in capsys.readouterr().err
    assert main(["find", str(other), "--point", "91,1"]) == 2  # latitude out of range
