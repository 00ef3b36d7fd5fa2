"""Measure and mark (app.locate.marks, app.ui.measure): figures worked out by hand, marks as valid
GeoJSON and KML read by independent parsers, kept beside the input and read back; and in the
viewer under Xvfb, a polygon marked on the draped video that lies on the model."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from shapely.geometry import shape

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.locate.marks import Mark, marks_geojson, marks_kml, marks_path, measure, read_marks
from app.render.probe import SurfaceProbe
from app.session import open_session
from app.simulate.sample import SAMPLE_DIR
from tests.conftest import run_viewer

FRAME = LocalFrame(46.05, 14.5, 300.0)


def test_measure_by_hand():
    """A 3-4-5 leg, then a 12 m climb: 17 m straight, 5 m along the ground, 12 m up."""
    pts = [[0, 0, 0], [3, 4, 0], [3, 4, 12]]
    m = measure(pts)
    assert m.straight_m == pytest.approx(5.0 + 12.0)
    assert m.ground_m == pytest.approx(5.0)  # the climb is no distance seen from above
    assert m.height_m == pytest.approx(12.0)
    square = measure([[0, 0, 1], [10, 0, 2], [10, 10, 3], [0, 10, 4]])
    assert square.area_m2 == pytest.approx(100.0)  # seen from above, whatever the heights
    assert measure([[0, 0, 0], [1, 1, 1]]).area_m2 is None


def test_marks_are_valid_geojson_and_kml_and_read_back(tmp_path):
    # a bow tie as clicked (its outline crosses itself): written valid, as two triangles
    bow = Mark(
        "polygon",
        "field",
        "clip.mp4",
        12,
        0.4,
        np.array([[0, 0, 1], [10, 10, 1], [10, 0, 1], [0, 10, 1.0]]),
    )
    line = Mark("line", "fence", "clip.mp4", 30, 1.0, np.array([[0, 0, 0], [5, 0, 0.0]]))
    point = Mark("point", "car", "clip.mp4", 31, 1.03, np.array([[2, 3, 0.5]]))
    doc = marks_geojson([bow, line, point], FRAME)
    polygon = shape(doc["features"][0]["geometry"])
    assert polygon.is_valid and polygon.geom_type == "MultiPolygon" and len(polygon.geoms) == 2
    assert doc["features"][1]["properties"]["length_m"] == pytest.approx(5.0)
    lat, lon, h = FRAME.enu_to_geodetic(np.array([[2.0, 3.0, 0.5]]))[0]
    np.testing.assert_allclose(doc["features"][2]["geometry"]["coordinates"], [lon, lat, h])
    kml = ET.fromstring(marks_kml([point], FRAME, "marks"))
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    text = kml.find(".//k:Point/k:coordinates", ns).text.split(",")
    assert float(text[2]) == pytest.approx(h - float(undulation(lat, lon)), abs=1e-3)  # sea level
    path = tmp_path / "walk.marks.geojson"
    path.write_text(json.dumps(marks_geojson([line, point], FRAME)))
    back = read_marks(path, FRAME)
    assert [m.label for m in back] == ["fence", "car"] and back[1].frame == 31
    np.testing.assert_allclose(back[1].points, point.points, atol=1e-6)
    assert marks_path(tmp_path / "walk.MP4") == tmp_path / "walk.marks.geojson"


@pytest.mark.gl
def test_a_polygon_marked_on_the_draped_video_lies_on_the_model(display, tmp_path):
    """In the viewer, riding the video's camera at 20 s of a copy of the sample: four picks on
    the draped video (L), kept as a mark; the marks file beside the copied manifest (the sample
    itself untouched) holds a valid polygon whose every vertex a separate probe, looking from
    the camera at it, finds on the model's surface."""
    folder = tmp_path / "sample"
    shutil.copytree(SAMPLE_DIR, folder)
    state, shot = tmp_path / "s.json", tmp_path / "m.png"
    script = tmp_path / "s.txt"
    picks = "".join(
        f"0.2 measure pick {x},{y}\n" for x, y in ((0.3, 0.8), (0.7, 0.8), (0.7, 0.95), (0.3, 0.95))
    )
    script.write_text(
        f"0 clock 0.05\n0 wait solved\n0 seek 20\n0 pause\n0 view phone\n0.2 measure polygon\n{picks}"
        f"0.25 state {state}\n0.3 measure mark field\n0.35 screenshot {shot}\n0.4 quit\n"
    )
    result = run_viewer(
        display, str(folder / "session.toml"), "--script", str(script), "--size", "1280x720"
    )
    assert result.returncode == 0, result.stderr[-2000:]
    s = json.loads(state.read_text())
    assert s["errors"] == []
    m = s["measure"]
    assert len(m["picks"]) == 4 and all(p["location"] is not None for p in m["picks"])
    assert m["area_m2"] > 10.0
    marks = json.loads((folder / "session.marks.geojson").read_text())
    assert not (SAMPLE_DIR / "session.marks.geojson").exists()
    (feature,) = marks["features"]
    assert feature["properties"]["label"] == "field" and shape(feature["geometry"]).is_valid
    session = open_session(folder / "session.toml")
    ring = np.array(feature["geometry"]["coordinates"][0])[:-1]
    enu = session.frame.geodetic_to_enu(ring[:, 1], ring[:, 0], ring[:, 2])
    eye = np.array(s["projector"]["position"])
    probe = SurfaceProbe(session.scene())
    try:
        for p in enu:
            cam = Camera.create(
                Intrinsics.from_fov(9, 9, 0.5), eye, look_at_quat(eye, p), 0.05, 5000.0
            )
            hit = probe.points(cam)[4, 4]
            assert np.linalg.norm(hit - p) < 0.05 + 0.002 * np.linalg.norm(p - eye)
    finally:
        probe.release()


def test_the_hover_readout_follows_the_cursor_at_most_five_times_a_second(monkeypatch):
    """The point under a moving cursor is read when the cursor has moved and 0.2 s have passed
    on the viewer's clock; never over the panels."""
    from types import SimpleNamespace

    from app.ui import measure as ui_measure

    reads = []
    monkeypatch.setattr(ui_measure, "locate_at", lambda v, xy: reads.append(xy) or xy)
    v = SimpleNamespace(ui=SimpleNamespace(measure=ui_measure.MeasureState()), loaded=object())
    cursor = [(0.5, 0.5)]
    v.cursor_in_view = lambda: cursor[0]
    ui_measure.hover(v, 0.0, False)
    ui_measure.hover(v, 1.0, False)  # not moved: not read again
    cursor[0] = (0.6, 0.5)
    ui_measure.hover(v, 1.05, False)  # moved: read
    cursor[0] = (0.7, 0.5)
    ui_measure.hover(v, 1.15, False)  # moved again 0.1 s later: not yet
    assert reads == [(0.5, 0.5), (0.6, 0.5)]
    ui_measure.hover(v, 1.3, False)
    assert reads[-1] == (0.7, 0.5) and v.ui.measure.hover == (0.7, 0.5)
    ui_measure.hover(v, 2.0, True)  # over a panel
    assert v.ui.measure.hover is None
