"""Exports for GIS tools (issue 14): footprints checked by hand and against the truth, GeoJSON by
RFC 7946's rules, KLV through an independent decoder (klvdata), the fused video by its frame
count, size, rate and content."""

from __future__ import annotations

import csv
import json
import math
import re
import zipfile

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.cli import main
from app.export.gis import FMV_FIELDS, FMV_HEADER, counter_clockwise_ring
from app.export.records import FootprintCaster, frame_records
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.misb import camera_orientation
from app.io.misb import parse as parse_klv
from app.scene.ground_plane import ground_plane
from app.simulate.sample import SAMPLE_DIR
from app.solve.accuracy import true_track
from app.solve.track import solve_frames

pytestmark = pytest.mark.gl
SAMPLE = SAMPLE_DIR / "session.toml"


@pytest.fixture(scope="module")
def sample():
    from app.session import open_session

    return open_session(SAMPLE)


def test_a_nadir_frame_lands_where_the_hand_worked_corners_are():
    """A camera 50 m above flat ground, looking straight down with the image's top to the north,
    60 deg across and 36.9 deg down: its corners lie at +-50 tan 30 = 28.87 m east-west and
    +-50 tan 18.43 = 16.67 m north-south of the point below it."""
    frame = LocalFrame(46.05, 14.5, 300.0)
    intr = Intrinsics.from_fov(960, 540, 60.0)
    cam = Camera.create(intr, [10.0, 20.0, 50.0], rotations.camera_quat_from_hpr(0.0, -90.0, 0.0))
    caster = FootprintCaster(ground_plane(np.zeros(2), 0.0, 500.0), frame, intr)
    try:
        r = caster.record(cam)
    finally:
        caster.release()
    hw, hh = 50.0 * math.tan(math.radians(30.0)), 50.0 * 270.0 / intr.fy
    expected = frame.enu_to_geodetic(
        np.array(
            [
                [10 - hw, 20 + hh, 0],
                [10 + hw, 20 + hh, 0],
                [10 + hw, 20 - hh, 0],
                [10 - hw, 20 - hh, 0],
            ]
        )
    )
    enu = frame.geodetic_to_enu(r.corners[:, 0], r.corners[:, 1], r.corners[:, 2])
    np.testing.assert_allclose(
        enu[:, :2],
        frame.geodetic_to_enu(expected[:, 0], expected[:, 1], expected[:, 2])[:, :2],
        atol=0.05,
    )
    np.testing.assert_allclose(
        frame.geodetic_to_enu(*np.array(r.centre))[:2], [10.0, 20.0], atol=0.05
    )
    assert r.slant_m == pytest.approx(50.0, abs=0.01) and not r.clipped
    assert r.hpr[1] == pytest.approx(-90.0, abs=1e-6)


def test_footprints_follow_the_truth(sample):
    """The sample's footprints under gd-ahrs against those of the true poses at the frames' true
    times: each border point misses its true place by no more than the pose explains (the
    sensor's position error, plus the range times the tangent of the attitude error and half a
    degree), median over the border, on every frame whose border stays on the model."""
    every = 200
    est = list(frame_records(sample, "gd-ahrs", every))
    truth = list(
        frame_records(
            sample,
            "truth",
            every,
            track=true_track(sample),
        )
    )
    enu = lambda g: sample.frame.geodetic_to_enu(*np.asarray(g, float).T)  # noqa: E731
    checked = 0
    for a, b in zip(est, truth, strict=True):
        if a.clipped or b.clipped:
            continue
        angle = np.degrees(
            rotations.angle_between(
                rotations.camera_quat_from_hpr(*a.hpr), rotations.camera_quat_from_hpr(*b.hpr)
            )
        )
        miss = np.linalg.norm(enu(a.footprint) - enu(b.footprint), axis=1)
        reach = np.linalg.norm(enu(b.footprint) - enu(b.sensor), axis=1)
        allowed = (
            np.linalg.norm(enu(a.sensor) - enu(b.sensor))
            + reach * np.tan(np.radians(angle + 0.5))
            + 0.5
        )
        assert np.median(miss - allowed) <= 0.0, (a.index, np.median(miss), np.median(allowed))
        checked += 1
    assert checked >= 5


def test_footprints_of_close_poses_overlap():
    """Two poses half a degree apart, 80 m over flat ground looking 40 deg down: footprint
    polygons (in plan, RFC 7946 rings) overlap by more than 90 %."""
    from shapely.geometry import Polygon

    frame = LocalFrame(46.05, 14.5, 300.0)
    intr = Intrinsics.from_fov(960, 540, 60.0)
    caster = FootprintCaster(ground_plane(np.zeros(2), 0.0, 2000.0), frame, intr)
    try:
        a = caster.record(
            Camera.create(intr, [0.0, 0.0, 80.0], rotations.camera_quat_from_hpr(30.0, -40.0, 0.0))
        )
        b = caster.record(
            Camera.create(intr, [0.0, 0.0, 80.0], rotations.camera_quat_from_hpr(30.3, -40.4, 0.2))
        )
    finally:
        caster.release()
    pa, pb = (Polygon(counter_clockwise_ring(r.footprint)[:, :2]) for r in (a, b))
    assert pa.is_valid and pb.is_valid and not a.clipped
    assert pa.intersection(pb).area / pa.union(pb).area > 0.9


def _signed_area(ring: list[list[float]]) -> float:
    """Twice the shoelace area, about the first point (no cancellation at 113 degrees)."""
    x0, y0 = ring[0][0], ring[0][1]
    pts = [(x - x0, y - y0) for x, y, *_ in ring]
    return sum(xa * yb - xb * ya for (xa, ya), (xb, yb) in zip(pts, pts[1:], strict=False))


def test_geojson_follows_rfc_7946(tmp_path, capsys):
    """The footprints file holds polygons only, each valid (GEOS) with counter-clockwise
    exteriors, longitude first; the borders and the track are in their own files."""
    from shapely.geometry import shape

    out = tmp_path / "fp.geojson"
    assert main(["export", "footprints", str(SAMPLE), "--out", str(out), "--every", "200"]) == 0
    doc = json.loads(out.read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 12
    for f in doc["features"]:
        assert f["geometry"]["type"] in ("Polygon", "MultiPolygon")
        geometry = shape(f["geometry"])
        assert geometry.is_valid and geometry.area > 0
        polygons = f["geometry"]["coordinates"]
        for polygon in polygons if f["geometry"]["type"] == "MultiPolygon" else [polygons]:
            ring = polygon[0]
            assert ring[0] == ring[-1] and len(ring) >= 4  # closed
            assert _signed_area(ring) > 0  # exterior ring counter-clockwise
            lon, lat = np.array(ring)[:, 0], np.array(ring)[:, 1]
            assert np.all(np.abs(lon - 113.53) < 0.05) and np.all(
                np.abs(lat - 34.80) < 0.05
            )  # longitude first
        p = f["properties"]
        assert (
            p["utc"].endswith("Z")
            and p["utc"].startswith("2025-11-15T")
            and -180 <= p["heading_deg"] <= 360
        )
    (track,) = json.loads((tmp_path / "fp_track.geojson").read_text())["features"]
    assert track["geometry"]["type"] == "LineString"
    assert len(track["geometry"]["coordinates"]) == 12
    borders = json.loads((tmp_path / "fp_borders.geojson").read_text())["features"]
    assert [b["properties"]["frame"] for b in borders] == [
        f["properties"]["frame"] for f in doc["features"]
    ]
    for b in borders:
        line = b["geometry"]["coordinates"]
        assert b["geometry"]["type"] == "LineString" and line[0] == line[-1] and len(line[0]) == 3


def test_counter_clockwise_ring_turns_a_clockwise_one():
    cw = np.array(
        [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]]
    )  # lat, lon: clockwise in (lon, lat)
    ring = counter_clockwise_ring(cw)
    assert _signed_area(ring.tolist()) > 0 and np.array_equal(ring[0], ring[-1])


def test_kml_kmz_and_fmv_csv(sample, tmp_path):
    kmz = tmp_path / "fp.kmz"
    assert main(["export", "footprints", str(SAMPLE), "--out", str(kmz), "--every", "400"]) == 0
    with zipfile.ZipFile(kmz) as z:
        text = z.read("doc.kml").decode()
    footprints = text.split("<name>footprints</name>")[1].split("</Folder>")[0]
    assert (
        footprints.count("<Placemark>") == 6
        and "<altitudeMode>clampToGround</altitudeMode>" in footprints
        and "<LineString>" in text
        and "<altitudeMode>absolute</altitudeMode>" in text
    )
    fmv = tmp_path / "fmv.csv"
    assert main(["export", "fmv-csv", str(SAMPLE), "--out", str(fmv), "--every", "400"]) == 0
    with fmv.open() as f:
        rows = list(csv.reader(f))
    # the MISB fields first, in their order, then geofuse's own (the GNSS status)
    assert tuple(rows[0]) == FMV_HEADER and rows[0][: len(FMV_FIELDS)] == list(FMV_FIELDS)
    assert len(rows) == 7 and {r[-1] for r in rows[1:]} == {"used"}
    t = [int(r[0]) for r in rows[1:]]
    assert t[0] > 1.7e15 and np.all(np.diff(t) > 0)  # microseconds since the Unix epoch
    # The coordinates themselves: each row's sensor position is the solved camera's at its
    # frame (every 400th), and each KML ring lies around the site, longitude first.
    poses = solve_frames(sample, sample.sources[0])
    lat = [float(r[FMV_FIELDS.index("Sensor Latitude")]) for r in rows[1:]]
    lon = [float(r[FMV_FIELDS.index("Sensor Longitude")]) for r in rows[1:]]
    np.testing.assert_allclose(lat, poses.geodetic[::400, 0], atol=1e-7)
    np.testing.assert_allclose(lon, poses.geodetic[::400, 1], atol=1e-7)
    rings = re.findall(r"<outerBoundaryIs>.*?<coordinates>(.*?)</coordinates>", footprints, re.S)
    assert len(rings) >= 6
    for ring in rings:
        pts = np.array([[float(v) for v in p.split(",")] for p in ring.split()])
        # within the 2 km the footprints reach (0.03 deg: 2.7 km of longitude, 3.3 km of latitude)
        assert np.all(np.abs(pts[:, 0] - 113.53) < 0.03) and np.all(
            np.abs(pts[:, 1] - 34.80) < 0.03
        )
        assert np.array_equal(pts[0], pts[-1])  # closed


def test_klv_round_trips_through_an_independent_decoder(sample, tmp_path):
    import av
    import klvdata

    out = tmp_path / "k.ts"
    assert main(["export", "klv", str(SAMPLE), "--out", str(out), "--every", "100"]) == 0
    records = {r.index: r for r in frame_records(sample, "gd-ahrs", 100)}
    with av.open(str(out)) as c:
        video = c.streams.video[0]
        data = next(s for s in c.streams if s.type == "data")
        assert video.codec_context.name == "h264"
        packets, frames = [], 0
        for p in c.demux(video, data):  # every video packet copied, and the KLV ones
            if p.size and p.stream.type == "data":
                packets.append(bytes(p))
            elif p.size:
                frames += 1
    assert frames == len(sample.video.pts_s)
    assert len(packets) == len(records)
    for raw, r in zip(packets, records.values(), strict=True):
        words = raw[:-2] + (b"\x00" if len(raw[:-2]) % 2 else b"")
        assert sum(
            int.from_bytes(words[i : i + 2], "big") for i in range(0, len(words), 2)
        ) & 0xFFFF == int.from_bytes(raw[-2:], "big")
        (ls,) = list(klvdata.StreamParser(raw))
        m = {k: float(v[3]) if k not in (2, 1) else v[3] for k, v in ls.MetadataList().items()}
        # Our own reader (app.io.misb) agrees, down to the camera the set describes: 0.0055 deg
        # is the heading's step over 16 bits.
        ours = parse_klv(raw)
        t = r.utc_s if r.utc_s is not None else r.session_s
        assert ours.time_us == round(t * 1e6) and ours.version == 17
        assert ours.get("sensor_latitude_deg") == pytest.approx(m[13], abs=1e-9)
        q = camera_orientation(ours)
        assert q is not None
        assert np.degrees(rotations.angle_between(q, rotations.camera_quat_from_hpr(*r.hpr))) < 0.01
        assert m[13] == pytest.approx(r.sensor[0], abs=1e-7) and m[14] == pytest.approx(
            r.sensor[1], abs=1e-7
        )
        # Heights: above mean sea level in tags 15 and 25, above the ellipsoid in 75 and 78
        # (19900 m over 16 bits); the sample's geoid lies 19.5 m below the ellipsoid (EGM2008).
        n = float(undulation(r.sensor[0], r.sensor[1]))
        assert -20.0 < n < -19.0
        assert m[15] == pytest.approx(r.sensor[2] - n, abs=0.31)
        assert m[75] == pytest.approx(r.sensor[2], abs=0.31)
        assert m[5] == pytest.approx(r.hpr[0] % 360, abs=0.006)
        assert m[19] == pytest.approx(r.hpr[1], abs=1e-6) and m[16] == pytest.approx(
            r.hfov_deg, abs=0.003
        )
        if math.isfinite(r.slant_m):
            assert m[21] == pytest.approx(r.slant_m, abs=0.01)
            nc = float(undulation(r.centre[0], r.centre[1]))
            assert m[25] == pytest.approx(r.centre[2] - nc, abs=0.31)
            assert m[78] == pytest.approx(r.centre[2], abs=0.31)
            assert m[23] == pytest.approx(r.centre[0], abs=1e-7) and m[24] == pytest.approx(
                r.centre[1], abs=1e-7
            )
            for k in range(4):
                offset = r.corners[k, 0] - r.centre[0]
                if abs(offset) <= 0.075:
                    assert m[26 + 2 * k] == pytest.approx(offset, abs=3e-6)


def test_the_fused_video_has_every_frame_and_matches_an_offscreen_render(sample, tmp_path, gl_ctx):
    import av

    from app.camera.frame_time import frame_at
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.export.video import EXPORT_ALPHA, view_camera
    from app.io.video import read_frame
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer
    from app.session.camera_track import camera_track

    out = tmp_path / "fused.mp4"
    assert (
        main(
            [
                "export",
                "video",
                str(SAMPLE),
                "--out",
                str(out),
                "--from",
                "10",
                "--to",
                "11",
                "--size",
                "320x180",
                "--view",
                "ride",
            ]
        )
        == 0
    )
    pts = sample.video.pts_s
    # The frames on screen from 10 s to 11 s, as the viewer shows them (app.io.video.frame_at).
    first, last = frame_at(pts, 10.0), frame_at(pts, 11.0)
    assert pts[first] <= 10.0 < pts[first + 1] and pts[last] <= 11.0 < pts[last + 1]
    with av.open(str(out)) as c:
        s = c.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(s)]
        assert (s.codec_context.width, s.codec_context.height) == (320, 180)
        assert float(s.average_rate) == pytest.approx(30.0, rel=0.05)
    assert len(frames) == last - first + 1
    k = first + 10
    track = camera_track(sample, "gd-ahrs")
    renderer = FusionRenderer(gl_ctx, sample.scene())
    try:
        renderer.set_video_frame(read_frame(sample.video.path, k, sample.video))
        projector = track.frame_camera(k)
        renderer.set_projector(projector)
        expected = render_to_array(
            renderer,
            view_camera("ride", projector, (320, 180), sample.scene().bounds(), 0.0),
            ProjectionSettings(alpha=EXPORT_ALPHA),
            OverlaySettings(frustum=False, trajectory=False),
        )
    finally:
        renderer.release()
    diff = np.abs(frames[10].astype(int) - expected.astype(int)).max(axis=2)
    assert np.median(diff) <= 8 and np.mean(diff <= 24) > 0.95  # H.264 at crf 20 on a 320x180 frame
