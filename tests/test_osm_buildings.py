"""Buildings from OpenStreetMap footprints extruded to LoD1 (issue 48): small .osm files
written here by hand, read as a city layer on an assumed flat ground and on a sloped DEM, the
same from PBF and GeoParquet, and a drone clip opened with --buildings draped on them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import geopandas
import numpy as np
import osmium
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from shapely.geometry import Polygon

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.cli import main
from app.core.errors import SceneError
from app.core.settings import ProjectionSettings
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.render.offscreen import render_to_array
from app.render.renderer import FusionRenderer
from app.scene.city.footprints import parse_length, parse_levels, vertical_extent
from app.scene.city.model import KIND_CODE
from app.scene.city.osm import join_rings
from app.scene.ground import ground_heights
from app.scene.layers import Layer, layer_kind, load_layers
from app.scene.mesh import MeshData, Primitive
from app.session.config import read_config
from app.simulate.phone import write_video
from app.simulate.terrain import write_geotiff
from tests.test_city import sample_manifest_text

LAT0, LON0, H0 = 46.0, 7.0, 500.0  # the frame's origin: ellipsoidal height of the flat ground
FRAME = LocalFrame(LAT0, LON0, H0)

# Footprints in ENU metres (x east, y north) of FRAME; ways list node ids.
NODES = {
    # A: 20 x 10 m, height=12
    1: (0, 0), 2: (20, 0), 3: (20, 10), 4: (0, 10),
    # B: building:levels=4
    5: (40, 0), 6: (55, 0), 7: (55, 12), 8: (40, 12),
    # C: neither height nor levels
    9: (0, 30), 10: (10, 30), 11: (10, 40), 12: (0, 40),
    # D: the courtyard: outer 60..100 x 30..70 in two open ways, inner 70..90 x 40..60
    20: (60, 30), 21: (100, 30), 22: (100, 70), 23: (60, 70),
    24: (70, 40), 25: (90, 40), 26: (90, 60), 27: (70, 60),
    # E: a way with a node missing (30, 31, 32 and 9999 absent)
    30: (0, 60), 31: (10, 60), 32: (10, 70),
    # F: far from the track (5 km east)
    40: (5000, 0), 41: (5010, 0), 42: (5010, 10), 43: (5000, 10),
    # G: not closed
    50: (20, 80), 51: (30, 80), 52: (30, 90),
    # H: a bow-tie (its ring crosses itself)
    60: (40, 30), 61: (50, 40), 62: (50, 30), 63: (40, 40),
    # I: height "tall" (unreadable) and building:levels=2
    70: (20, 30), 71: (30, 30), 72: (30, 38), 73: (20, 38),
}  # fmt: skip
WAYS = [
    (100, [1, 2, 3, 4, 1], {"building": "yes", "height": "12", "name": "Hall A"}),
    (101, [5, 6, 7, 8, 5], {"building": "office", "building:levels": "4"}),
    (102, [9, 10, 11, 12, 9], {"building": "shed"}),
    (110, [20, 21, 22], {}),
    (111, [22, 23, 20], {}),
    (112, [24, 25, 26, 27, 24], {}),
    (103, [30, 31, 32, 9999, 30], {"building": "yes"}),
    (104, [40, 41, 42, 43, 40], {"building": "yes", "height": "20"}),
    (105, [50, 51, 52], {"building": "yes"}),
    (106, [60, 61, 62, 63, 60], {"building": "yes"}),
    (107, [70, 71, 72, 73, 70], {"building": "yes", "height": "tall", "building:levels": "2"}),
]
RELATIONS = [
    (
        200,
        [(110, "outer"), (111, "outer"), (112, "inner")],
        {"type": "multipolygon", "building": "yes", "height": "15 m", "name": "Court"},
    )
]
TRACK_ENU = np.array([[-20.0, -20.0], [50.0, 20.0], [110.0, 80.0]])  # the clip's path, m


def _ll(frame: LocalFrame, xy: np.ndarray | tuple, h: float = 0.0) -> np.ndarray:
    """(N, 3) lat, lon, h of ENU points (x, y) at ENU height h."""
    xy = np.atleast_2d(np.asarray(xy, np.float64))
    return frame.enu_to_geodetic(np.column_stack([xy, np.full(len(xy), h)]))


TRACK_LL = _ll(FRAME, TRACK_ENU)[:, :2]


def write_osm(
    path: Path, frame: LocalFrame = FRAME, nodes=NODES, ways=WAYS, relations=RELATIONS
) -> Path:
    """An OSM XML file as JOSM writes one: nodes at the ENU points of `nodes` in `frame`."""
    lines = ["<?xml version='1.0' encoding='UTF-8'?>", "<osm version='0.6' generator='JOSM'>"]
    for nid, xy in nodes.items():
        lat, lon, _ = _ll(frame, xy)[0]
        lines.append(f"  <node id='{nid}' version='1' lat='{lat:.9f}' lon='{lon:.9f}' />")

    def tags(t: dict) -> list[str]:
        return [f"    <tag k='{k}' v='{v}' />" for k, v in t.items()]

    for wid, refs, t in ways:
        lines += [f"  <way id='{wid}' version='1'>", *(f"    <nd ref='{r}' />" for r in refs)]
        lines += [*tags(t), "  </way>"]
    for rid, members, t in relations:
        lines.append(f"  <relation id='{rid}' version='1'>")
        lines += [f"    <member type='way' ref='{m}' role='{role}' />" for m, role in members]
        lines += [*tags(t), "  </relation>"]
    path.write_text("\n".join([*lines, "</osm>"]) + "\n", encoding="utf-8")
    return path


def _object(mesh: MeshData, oid: str) -> tuple[np.ndarray, np.ndarray]:
    """(triangles (T, 3, 3) ENU m, kind codes (T,)) of one city object."""
    (table,) = mesh.features
    i = table.ids.index(oid)
    s, e = table.starts[i], table.starts[i + 1]
    return table.triangles[s:e].astype(np.float64), table.kinds[s:e]


def _surface(triangles: np.ndarray) -> MeshData:
    """Triangles (T, 3, 3) ENU as a scene (for ground_heights: the surface under a point)."""
    pos = np.ascontiguousarray(triangles.reshape(-1, 3), np.float32)
    idx = np.arange(len(pos), dtype=np.uint32).reshape(-1, 3)
    return MeshData([Primitive(pos, np.ones((len(pos), 4), np.float32), idx)])


def _roof_and_floor(mesh: MeshData, oid: str) -> tuple[float, float]:
    tris, kinds = _object(mesh, oid)
    roof = tris[kinds == KIND_CODE["roof"]][..., 2]
    floor = tris[np.isin(kinds, [KIND_CODE["ground"], KIND_CODE["floor"]])][..., 2]
    assert np.ptp(roof) < 1e-3 and np.ptp(floor) < 1e-3  # flat, in ENU, over 100 m
    return float(roof.mean()), float(floor.mean())


@pytest.fixture(scope="module")
def flat(tmp_path_factory):
    """The file's buildings on a clip's assumed flat ground 2 m under the frame's origin."""
    path = write_osm(tmp_path_factory.mktemp("osm") / "city.osm")
    loaded = load_layers([Layer.of(path)], FRAME, TRACK_LL, ground_h=H0 - 2.0, margin_m=50.0)
    return path, loaded


def test_heights_are_parsed_from_tags():
    assert parse_length("12") == 12.0 and parse_length("12 m") == 12.0
    assert parse_length("12.5m") == 12.5 and parse_length("12,5") == 12.5
    assert parse_length("40'") == pytest.approx(12.192) and parse_length("40 ft") == pytest.approx(
        12.192
    )
    assert parse_length("12'6\"") == pytest.approx(12 * 0.3048 + 6 * 0.0254)
    assert parse_length(7) == 7.0 and parse_length(float("nan")) is None
    for bad in ("tall", "12;15", "-3", "", "1e9", True):
        assert parse_length(bad) is None
    assert parse_levels("4") == 4.0 and parse_levels("many") is None
    assert vertical_extent({"height": "12"}).top_m == 12.0
    e = vertical_extent({"building:levels": "4", "roof:levels": "1", "building:min_level": "1"})
    assert (e.bottom_m, e.top_m, e.rule) == (3.0, 15.0, "building:levels")
    e = vertical_extent({"height": "tall", "min_height": "30"})
    assert (e.bottom_m, e.top_m, e.rule) == (0.0, 9.0, "default")
    assert [k for k, _ in e.faults] == ["unreadable", "bottom above top"]
    rings, left = join_rings([np.array([1, 2, 3]), np.array([1, 4, 3]), np.array([7, 8])])
    assert len(rings) == 1 and left == 1  # 7-8 left open
    assert rings[0][0] == rings[0][-1] and sorted(rings[0][:-1].tolist()) == [1, 2, 3, 4]


def test_roofs_stand_at_their_height_over_the_flat_ground_drawn_under_them(flat):
    """A (height=12), B (4 levels: 12 m), C (9 m assumed), the courtyard (15 m), the levels of
    I (its height unreadable: 6 m) each from the assumed ground 2 m under the origin, within
    1 cm; the ground is drawn between them and under the track; the far building is not read,
    and every rule and fault is counted in the notes."""
    _, loaded = flat
    mesh = loaded.mesh
    ground_z = float(FRAME.geodetic_to_enu(*TRACK_LL[0], H0 - 2.0)[2])
    for oid, height in (("way/100", 12.0), ("way/101", 12.0), ("way/102", 9.0),
                        ("relation/200", 15.0), ("way/107", 6.0)):  # fmt: skip
        roof, floor = _roof_and_floor(mesh, oid)
        assert floor == pytest.approx(ground_z, abs=0.01), oid
        assert roof - floor == pytest.approx(height, abs=0.01), oid
    between = ground_heights(mesh, [[30.0, 5.0], [-15.0, -15.0]])  # between A and B; the track
    np.testing.assert_allclose(between, ground_z, atol=0.01)
    assert any(p.name == "assumed ground" for p in mesh.primitives)
    (table,) = mesh.features
    assert "way/104" not in table.ids and "way/103" not in table.ids
    assert sorted(table.ids) == sorted(
        ["way/100", "way/101", "way/102", "relation/200", "way/106", "way/107"]
    )
    notes = "\n".join(loaded.notes.items)
    assert "2 from height, 2 from building:levels at 3 m a level, 2 assumed 9 m" in notes
    assert "meets an assumed flat ground at 498.00 m (ellipsoidal), drawn under them" in notes
    assert "6 of 9 objects within 1000 m of the track (LoD 1)" in notes
    assert "do not end where they start (not rings): 1 (first way/105), skipped" in notes
    assert "nodes missing from the file (an extract cut at its edge): 1 (first way/103)" in notes
    assert (
        "not valid polygons" in notes and "(first way/106 (Self-intersection)), repaired" in notes
    )
    assert "not a length: 1 (first way/107 height='tall'), the next rule taken" in notes
    assert not any("Traceback" in n for n in loaded.notes.items)


def test_the_courtyard_has_no_roof_over_its_hole_and_its_walls_face_into_it(flat):
    _, loaded = flat
    tris, kinds = _object(loaded.mesh, "relation/200")
    roof = _surface(tris[kinds == KIND_CODE["roof"]])
    hole, body = [80.0, 50.0], [65.0, 50.0]
    assert np.isnan(ground_heights(roof, [hole])[0])  # a ray down through the hole: no roof
    assert np.isfinite(ground_heights(roof, [body])[0])
    ground_z = float(FRAME.geodetic_to_enu(*TRACK_LL[0], H0 - 2.0)[2])
    assert ground_heights(loaded.mesh, [hole])[0] == pytest.approx(ground_z, abs=0.01)
    walls = tris[kinds == KIND_CODE["wall"]]
    centre = walls.mean(axis=1)
    inner = (np.abs(centre[:, 0] - 80) <= 10.01) & (np.abs(centre[:, 1] - 50) <= 10.01)
    normal = np.cross(walls[:, 1] - walls[:, 0], walls[:, 2] - walls[:, 0])
    to_hole = np.array([80.0, 50.0, 0.0]) - centre
    assert inner.sum() == 8  # four quads, two triangles each
    assert np.all(np.einsum("ij,ij->i", normal[inner], to_hole[inner]) > 0)
    assert np.all(np.einsum("ij,ij->i", normal[~inner], to_hole[~inner]) < 0)  # outer: away


def test_the_feature_table_names_the_building_on_its_wall(flat):
    _, loaded = flat
    ground_z = float(FRAME.geodetic_to_enu(*TRACK_LL[0], H0 - 2.0)[2])
    f = loaded.mesh.feature_at([10.0, 0.0, ground_z + 6.0])  # A's south wall, half way up
    assert (f.id, f.type, f.surface) == ("way/100", "Building", "wall")
    assert f.attributes == {
        "building": "yes",
        "height": "12",
        "name": "Hall A",
        "osm_id": "way/100",
    }
    assert "Hall A" in f.line() and "height 12" in f.line()
    court = loaded.mesh.feature_at([80.0, 40.0, ground_z + 3.0])  # the courtyard's inner wall
    assert court.id == "relation/200" and court.attributes["name"] == "Court"


def test_buildings_stand_on_a_sloped_dem_at_their_lowest_corner(tmp_path):
    """A DEM rising 10 cm a metre eastwards (ellipsoidal heights): each building's floor lies at
    the DEM's height under its lowest (westmost) corner, its roof its height above that."""
    osm = write_osm(tmp_path / "city.osm")
    west, north = _ll(FRAME, (-100.0, 200.0))[0, 1], _ll(FRAME, (-100.0, 200.0))[0, 0]
    east, south = _ll(FRAME, (200.0, -100.0))[0, 1], _ll(FRAME, (200.0, -100.0))[0, 0]
    n = 61
    step_x, step_y = (east - west) / n, (north - south) / n
    lon = west + (np.arange(n) + 0.5) * step_x
    metres_per_deg = (_ll(FRAME, (1.0, 0.0))[0, 1] - LON0) ** -1

    def ramp(lon_deg: np.ndarray) -> np.ndarray:
        return 300.0 + 0.1 * (np.asarray(lon_deg) - LON0) * metres_per_deg

    dem = write_geotiff(tmp_path / "dem.tif", np.tile(ramp(lon), (n, 1)), "EPSG:4326",
                        west, north, step_x, step_y)  # fmt: skip
    layers = [Layer.of(osm), Layer.of(dem, vertical="ellipsoid")]  # buildings first: read last
    loaded = load_layers(layers, FRAME, TRACK_LL, ground_h=H0)
    for oid, corners, height in (("way/100", [1, 2, 3, 4], 12.0), ("way/101", [5, 6, 7, 8], 12.0),
                                 ("relation/200", [20, 21, 22, 23], 15.0)):  # fmt: skip
        ll = _ll(FRAME, [NODES[c] for c in corners])
        base = float(ramp(ll[:, 1]).min())
        tris, kinds = _object(loaded.mesh, oid)
        roof = FRAME.enu_to_geodetic(tris[kinds == KIND_CODE["roof"]].reshape(-1, 3))[:, 2]
        floor = FRAME.enu_to_geodetic(tris[kinds == KIND_CODE["ground"]].reshape(-1, 3))[:, 2]
        np.testing.assert_allclose(floor, base, atol=0.01, err_msg=oid)
        np.testing.assert_allclose(roof, base + height, atol=0.01, err_msg=oid)
    assert not any(p.name == "assumed ground" for p in loaded.mesh.primitives)
    assert "lowest corner meets the ground of dem.tif" in "\n".join(loaded.notes.items)


def test_an_outline_with_parts_is_drawn_by_its_parts(tmp_path):
    """A tower's outline (height 30) holding a 20 m podium part and a part raised from 20 to
    30 m: the parts are drawn, the outline not (not doubled), the raised one with a floor."""
    nodes = {1: (0, 0), 2: (20, 0), 3: (20, 20), 4: (0, 20), 5: (10, 0), 6: (10, 20)}
    ways = [
        (1, [1, 2, 3, 4, 1], {"building": "yes", "height": "30", "name": "Tower"}),
        (2, [1, 5, 6, 4, 1], {"building:part": "yes", "height": "20"}),
        (3, [5, 2, 3, 6, 5], {"building:part": "yes", "height": "30", "min_height": "20"}),
    ]
    osm = write_osm(tmp_path / "tower.osm", nodes=nodes, ways=ways, relations=[])
    loaded = load_layers([Layer.of(osm)], FRAME, TRACK_LL, ground_h=H0)
    (table,) = loaded.mesh.features
    assert sorted(table.ids) == ["way/2", "way/3"]
    assert table.parents == ["way/1", "way/1"] and set(table.types) == {"BuildingPart"}
    assert table.attributes[0]["name"] == "Tower" and table.attributes[0]["height"] in ("20", "30")
    tris, kinds = _object(loaded.mesh, "way/3")
    assert KIND_CODE["floor"] in kinds and KIND_CODE["ground"] not in kinds
    z = tris[..., 2]
    assert (z.min(), z.max()) == (pytest.approx(20.0, abs=0.01), pytest.approx(30.0, abs=0.01))
    assert "1 outlines drawn by their 2 parts" in "\n".join(loaded.notes.items)


def test_a_file_without_buildings_and_a_damaged_one_are_named(tmp_path):
    empty = write_osm(
        tmp_path / "empty.osm", ways=[(1, [1, 2, 3, 1], {"highway": "path"})], relations=[]
    )
    with pytest.raises(SceneError, match=r"empty.osm: no building in it"):
        load_layers([Layer.of(empty)], FRAME, TRACK_LL)
    bad = tmp_path / "bad.osm"
    bad.write_text(
        "<?xml version='1.0'?>\n<osm version='0.6'>\n <node id='1' lat='46' lon='7'>\n <way id='2'/>\n</osm>\n"
    )
    with pytest.raises(SceneError, match=r"bad.osm:5: not well-formed XML"):
        load_layers([Layer.of(bad)], FRAME, TRACK_LL)
    other = tmp_path / "other.osm"
    other.write_text("<?xml version='1.0'?>\n<gpx/>\n")
    with pytest.raises(SceneError, match=r"other.osm:2: not OpenStreetMap XML"):
        load_layers([Layer.of(other)], FRAME, TRACK_LL)
    nodes = {k: v for k, v in NODES.items() if k < 5}  # only A, and its node 4 missing
    cut = write_osm(tmp_path / "cut.osm", nodes={k: v for k, v in nodes.items() if k != 4},
                    ways=WAYS[:1], relations=[])  # fmt: skip
    with pytest.raises(
        SceneError,
        match=r"cut.osm: none of its buildings near the track could be drawn \(1 skipped",
    ):
        load_layers([Layer.of(cut)], FRAME, TRACK_LL)
    assert {layer_kind(f"x{s}") for s in (".osm", ".osm.pbf", ".parquet", ".OSM")} == {"city"}


def test_a_manifest_names_buildings_as_a_layer(tmp_path):
    osm = write_osm(tmp_path / "city.osm")
    manifest = tmp_path / "session.toml"
    manifest.write_text(sample_manifest_text() + f'\n[[layers]]\npath = "{osm}"\n')
    layer = read_config(manifest).layers[-1]
    assert (layer.kind, Path(layer.location).name) == ("city", "city.osm")


def test_pbf_reads_as_the_xml_does(tmp_path, flat):
    xml, loaded = flat
    pbf = tmp_path / "city.osm.pbf"
    writer = osmium.SimpleWriter(str(pbf))
    for obj in osmium.FileProcessor(str(xml)):
        {"n": writer.add_node, "w": writer.add_way, "r": writer.add_relation}[obj.type_str()](obj)
    writer.close()
    again = load_layers([Layer.of(pbf)], FRAME, TRACK_LL, ground_h=H0 - 2.0, margin_m=50.0)
    (a,), (b,) = loaded.mesh.features, again.mesh.features
    assert sorted(a.ids) == sorted(b.ids)
    for oid in a.ids:
        np.testing.assert_allclose(
            _roof_and_floor(loaded.mesh, oid), _roof_and_floor(again.mesh, oid), atol=1e-3
        )
    notes = "\n".join(again.notes.items)
    assert "OpenStreetMap PBF in WGS 84, 6 of 9 objects" in notes and "way/103" in notes


def test_geoparquet_footprints_take_overtures_heights(tmp_path):
    def square(x0: float, y0: float, size: float) -> Polygon:
        ll = _ll(FRAME, [(x0, y0), (x0 + size, y0), (x0 + size, y0 + size), (x0, y0 + size)])
        return Polygon(ll[:, [1, 0]])

    rows = geopandas.GeoDataFrame(
        {"id": ["b1", "b2", "b3"], "height": [12.0, None, None], "num_floors": [None, 5, None],
         "subtype": ["residential", None, None]},
        geometry=[square(0, 0, 10), square(30, 0, 10), square(0, 30, 10)], crs="OGC:CRS84",
    )  # fmt: skip
    rows.to_parquet(tmp_path / "buildings.parquet")
    loaded = load_layers([Layer.of(tmp_path / "buildings.parquet")], FRAME, TRACK_LL, ground_h=H0)
    for oid, height in (("b1", 12.0), ("b2", 15.0), ("b3", 9.0)):
        roof, floor = _roof_and_floor(loaded.mesh, oid)
        assert roof - floor == pytest.approx(height, abs=0.01)
    notes = "\n".join(loaded.notes.items)
    assert "1 from height, 1 from num_floors at 3 m a level, 1 assumed 9 m" in notes
    f = loaded.mesh.feature_at([5.0, 0.0, 3.0])
    assert f.id == "b1" and f.attributes["subtype"] == "residential"
    plain = pa.table({"id": ["p1"], "height": [7.0], "geometry": [square(0, 0, 10).wkb]})
    pq.write_table(plain, tmp_path / "plain.parquet")
    loaded = load_layers([Layer.of(tmp_path / "plain.parquet")], FRAME, TRACK_LL, ground_h=H0)
    roof, floor = _roof_and_floor(loaded.mesh, "p1")
    assert roof - floor == pytest.approx(7.0, abs=0.01)
    assert "no GeoParquet metadata" in "\n".join(loaded.notes.items)


@pytest.fixture
def drone_clip(tmp_path):
    """A 4 s DJI clip hovering 80 m over building A (heights above take-off), looking down."""

    folder = tmp_path / "clip"
    folder.mkdir()
    video = write_video(folder / "DJI_0001.MP4", np.arange(120) / 30.0, (96, 54), 0)
    lat, lon, _ = _ll(FRAME, (10.0, 5.0))[0]
    entries = [
        f"{i + 1}\n00:00:0{i},000 --> 00:00:0{i + 1},000\n"
        f"F/5.6, SS 400, ISO 100, EV 0, GPS ({lon:.8f}, {lat:.8f}, 15), HOME ({lon:.8f}, {lat:.8f}, 0.00m), "
        f"D 0.00m, H 80.00m, H.S 0.00m/s, V.S 0.00m/s, F.PRY (0.0°, 0.0°, 0.0°), G.PRY (-90.0°, 0.0°, 0.0°)"
        for i in range(4)
    ]
    (folder / "DJI_0001.SRT").write_text("\n\n".join(entries) + "\n", encoding="utf-8")
    return video


def test_a_clip_opened_with_buildings_drapes_on_their_roofs(tmp_path, drone_clip, capsys, gl_ctx):
    """`geofuse locate CLIP --buildings city.osm`: the centre of the frame, looking straight
    down from 80 m over A, lies on A's roof, 12 m over the take-off ground, and names it."""
    osm = write_osm(tmp_path / "city.osm")
    args = ["locate", str(drone_clip), "--time", "1.5", "--pixel", "48,27", "--json",
            "--buildings", str(osm)]  # fmt: skip
    assert main(args) == 0
    captured = capsys.readouterr()
    (loc,) = json.loads(captured.out)
    assert loc["object"]["id"] == "way/100" and loc["object"]["surface"] == "roof"
    assert loc["ellipsoid_height_m"] == pytest.approx(12.0, abs=0.05)
    assert loc["range_m"] == pytest.approx(68.0, abs=0.5)
    assert "drawn under them" in captured.err and "no scene given" not in captured.err
    assert math.isclose(loc["latitude"], _ll(FRAME, (10.0, 5.0))[0, 0], abs_tol=2e-6)


def test_roofs_show_the_orthophoto_under_them_and_walls_stay_grey(tmp_path, gl_ctx):
    """A flat DEM at the frame's height, draped with an orthophoto red west of x = 10 m and blue
    east of it (x = 10 m crosses Hall A, 0..20 x 0..10 m, 12 m high). Seen from 100 m straight
    above, a point of A's roof west of the line is drawn red and one east of it blue, as the
    ground beside A is: the roof shows the imagery under it, where the camera projects it.
    Without the orthophoto the roof keeps its own colour; A's wall, seen from the side, is drawn
    the same either way."""
    osm = write_osm(tmp_path / "city.osm")
    sw, ne = _ll(FRAME, (-150.0, -150.0))[0], _ll(FRAME, (150.0, 150.0))[0]
    n = 60
    dem = write_geotiff(tmp_path / "dem.tif", np.full((n, n), H0), "EPSG:4326", sw[1], ne[0],
                        (ne[1] - sw[1]) / n, (ne[0] - sw[0]) / n)  # fmt: skip
    cols = 600  # 0.5 m a pixel over the same 300 m
    x = -150.0 + (np.arange(cols) + 0.5) * 300.0 / cols
    rgb = np.zeros((3, cols, cols), np.uint8)
    rgb[0][:, x < 10.0] = 220  # red west of x = 10 m
    rgb[2][:, x >= 10.0] = 220  # blue east of it
    ortho = write_geotiff(tmp_path / "ortho.tif", rgb, "EPSG:4326", sw[1], ne[0],
                          (ne[1] - sw[1]) / cols, (ne[0] - sw[0]) / cols, nodata=None)  # fmt: skip
    draped = load_layers(
        [Layer.of(osm), Layer.of(dem, vertical="ellipsoid", ortho=ortho)], FRAME, TRACK_LL
    )
    plain = load_layers([Layer.of(osm), Layer.of(dem, vertical="ellipsoid")], FRAME, TRACK_LL)
    assert "roofs (" in "\n".join(draped.notes.items) and "draped with the imagery of dem.tif" in "\n".join(draped.notes.items)  # fmt: skip
    roof_z = 12.0

    def seen(mesh: MeshData, view: Camera, points: np.ndarray) -> np.ndarray:
        r = FusionRenderer(gl_ctx, mesh)
        try:
            out = render_to_array(r, view, ProjectionSettings(enabled=False)).astype(int)
        finally:
            r.release()
        uv, _ = view.project(points)
        return out[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]

    above = Camera.create(Intrinsics.from_fov(400, 400, 40), [10.0, 5.0, 100.0],
                          rotations.camera_quat_from_hpr(0.0, -90.0, 0.0), near=1.0, far=500.0)  # fmt: skip
    points = np.array([[3.0, 5.0, roof_z], [17.0, 5.0, roof_z], [-5.0, 5.0, 0.0], [25.0, 5.0, 0.0]])
    red_roof, blue_roof, red_ground, blue_ground = seen(draped.mesh, above, points)
    for red in (red_roof, red_ground):
        assert red[0] > 150 and red[2] < 60, red
    for blue in (blue_roof, blue_ground):
        assert blue[2] > 150 and blue[0] < 60, blue
    plain_roof = seen(plain.mesh, above, points[:2])  # without imagery: the roofs' own colour
    np.testing.assert_array_equal(plain_roof[0], plain_roof[1])
    assert np.abs(plain_roof[1] - blue_roof).max() > 60, plain_roof
    # A's south wall from the south, low: as without the orthophoto
    side = Camera.create(Intrinsics.from_fov(400, 300, 40), [10.0, -40.0, 6.0],
                         rotations.camera_quat_from_hpr(0.0, 0.0, 0.0), near=1.0, far=500.0)  # fmt: skip
    wall = np.array([[5.0, 0.0, 6.0], [15.0, 0.0, 6.0]])
    np.testing.assert_array_equal(seen(draped.mesh, side, wall), seen(plain.mesh, side, wall))
