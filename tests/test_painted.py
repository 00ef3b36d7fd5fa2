"""The scene painted by a clip (app.export.atlas, app.export.painted, `geofuse export model`): an
atlas whose texels lie on their triangles, a facade painted by the frame that saw it and the
unseen roof keeping the model's colour, read back from the GLB by geofuse's own loader."""

from __future__ import annotations

import json
import struct
import subprocess
import sys

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.export.atlas import layout
from app.export.memory import SurfaceMemory
from app.export.painted import atlas_part, painted_glb
from app.export.painting import distances
from app.geodesy.enu import LocalFrame
from app.render.views import ModelViews
from app.scene import shapes
from app.scene.loader import Placement, load_scene
from app.scene.mesh import MeshData

ORIGIN = (50.1, 8.7, 120.0)
BOX = ((20.0, 20.0, 0.0), (30.0, 30.0, 5.0))


def _scene() -> MeshData:
    ground = shapes.quad([-50.0, -50.0, 0.0], [120.0, 0, 0], [0, 120.0, 0])
    return MeshData(
        [ground.primitive((0.3, 0.6, 0.3, 1.0)), shapes.box(*BOX).primitive((0.8, 0.8, 0.8, 1.0))]
    )


def test_the_atlas_samples_lie_on_their_triangles_and_keep_the_models_colour():
    atlas = layout(_scene(), max_texels=200_000)
    w, h = atlas.size
    assert w * h <= 200_000
    # every sample lies on the scene's surfaces: the ground, the box's faces
    p = atlas.points.astype(float)
    on_ground = np.abs(p[:, 2]) < 1e-3
    (x0, y0, _), (x1, y1, z1) = BOX
    tol = 1.01 * atlas.texel_m
    on_box = (
        (p[:, 0] > x0 - tol) & (p[:, 0] < x1 + tol) & (p[:, 1] > y0 - tol) & (p[:, 1] < y1 + tol)
        & (p[:, 2] > -1e-3) & (p[:, 2] < z1 + 1e-3)
    )  # fmt: skip
    assert np.all(on_ground | on_box)
    # as many samples as the surfaces' area takes (texel^2 each), plus their margins
    area = 120.0**2 + 4 * 10.0 * 5.0 + 10.0 * 10.0
    assert area / atlas.texel_m**2 < len(p) < 1.6 * area / atlas.texel_m**2
    # the base colours are the model's: green ground, grey box
    assert np.all(np.abs(atlas.base[on_ground & ~on_box].astype(int) - [76, 153, 76]) <= 1)
    # a triangle's uv corners are where its samples are in the atlas
    uv_px = atlas.uvs.reshape(-1, 2) * [w, h]
    assert uv_px.min() >= 0.9 and np.all(uv_px.max(axis=0) <= [w - 0.9, h - 0.9])
    # fewer texels: a coarser texel, never more memory
    coarse = layout(_scene(), max_texels=20_000)
    assert coarse.texel_m > 2.5 * atlas.texel_m and coarse.size[0] * coarse.size[1] <= 20_000


def _glb_json(data: bytes) -> dict:
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length])


def test_a_facade_is_painted_by_the_frame_that_saw_it(gl_ctx, tmp_path):
    """A camera south of the box sees its south wall: painted red, the wall keeps it in the
    GLB, read back by geofuse's loader and rendered from elsewhere; the roof, which that camera
    cannot see, keeps the model's grey; the GLB says its origin."""
    from app.core.settings import OverlaySettings, ProjectionSettings
    from app.render.offscreen import render_to_array
    from app.render.renderer import FusionRenderer

    scene = _scene()
    atlas = layout(scene, max_texels=400_000)
    memory = SurfaceMemory(atlas.points, atlas.normals)
    eye = np.array([25.0, 5.0, 2.5])
    cam = Camera.create(
        Intrinsics(320, 240, 200.0, 200.0, 160.0, 120.0), eye, look_at_quat(eye, [25.0, 20.0, 2.5])
    )
    views = ModelViews(scene, gl_ctx)
    try:
        memory.paint(
            np.full((240, 320, 3), (220, 20, 20), np.uint8), cam, distances(views, cam), 3.0
        )
    finally:
        views.release()
    p = atlas.points
    wall = (
        (np.abs(p[:, 1] - 20.0) < 1e-3)
        & (p[:, 2] > 0.5)
        & (p[:, 2] < 4.5)
        & (np.abs(p[:, 0] - 25) < 4)
    )
    n = atlas.normals
    roof = (np.abs(p[:, 2] - 5.0) < 1e-3) & (np.abs(n[:, 2]) > 0.99)  # not the walls' top rows
    north = (np.abs(p[:, 1] - 30.0) < 1e-3) & (np.abs(n[:, 1]) > 0.99)
    assert memory.seen[wall].all() and not memory.seen[roof].any() and not memory.seen[north].any()
    data = painted_glb([atlas_part(atlas, memory)], ORIGIN)
    assert _glb_json(data)["scenes"][0]["extras"]["geofuse_origin"] == list(ORIGIN)
    (tmp_path / "painted.glb").write_bytes(data)
    back = load_scene(tmp_path / "painted.glb", LocalFrame(*ORIGIN), Placement(ORIGIN, "Y"))
    eye2 = np.array([10.0, 0.0, 12.0])
    view = Camera.create(
        Intrinsics(320, 240, 200.0, 200.0, 160.0, 120.0),
        eye2,
        look_at_quat(eye2, [25.0, 25.0, 3.0]),
    )
    renderer = FusionRenderer(gl_ctx, back)
    try:
        image = render_to_array(
            renderer, view, ProjectionSettings(), OverlaySettings(frustum=False, trajectory=False)
        ).astype(int)
    finally:
        renderer.release()
    uv, _ = view.project(np.array([[25.0, 20.0, 2.5], [25.0, 25.0, 5.0]]))
    wall_px, roof_px = (image[int(v), int(u)] for u, v in uv)
    assert wall_px[0] > 2 * wall_px[1] and wall_px[0] > 2 * wall_px[2]  # red
    assert abs(roof_px[0] - roof_px[1]) < 20 and roof_px[1] > 100  # the model's grey


def test_export_model_writes_a_glb_any_viewer_opens(tmp_path):
    """`geofuse export model` on the sample (2 s of it): a GLB with one textured mesh, in a
    process of its own (its GL context)."""
    import trimesh

    out = tmp_path / "painted.glb"
    args = [sys.executable, "-m", "app", "export", "model", "assets/sample/session.toml"]
    args += ["--out", str(out), "--source", "truth", "--every-s", "2", "--max-texels", "200000"]
    done = subprocess.run(args, capture_output=True, text=True, check=True)
    assert "% of the surface seen" in done.stdout
    loaded = trimesh.load(out, force="scene")
    (mesh,) = loaded.geometry.values()
    assert mesh.visual.kind == "texture" and mesh.visual.material.baseColorTexture is not None
    assert len(mesh.faces) == 62


def test_the_painted_scene_as_3d_tiles_reads_back_in_place_with_its_texels(tmp_path):
    """The painted scene split into tiles of at most 3 triangles: geofuse's own 3D Tiles reader
    puts every triangle back where the scene has it (1 cm, through ECEF) and each tile's own
    atlas shows, at each triangle's middle, that triangle's painted colour."""
    from app.export.painted_tiles import atlas_tiles, tile_groups, write_painted_tiles
    from app.scene.tiles.stream import decode_tile
    from app.scene.tiles.tileset import Tileset

    scene = _scene()
    atlas = layout(scene, max_texels=100_000)
    memory = SurfaceMemory(atlas.points, atlas.normals)
    t = len(atlas.triangles)
    palette = np.stack([np.arange(t) * 37 % 256, np.arange(t) * 91 % 256, 255 - np.arange(t) * 13 % 256], axis=1)  # fmt: skip
    memory.rgb[:] = palette[atlas.triangle].astype(np.uint8)
    memory.seen[:] = True
    assert all(len(g) <= 3 for g in tile_groups(atlas.triangles, 3))
    frame = LocalFrame(*ORIGIN)
    out, tiles = write_painted_tiles(
        atlas_tiles(atlas, memory, 3), frame, tmp_path / "tiles" / "tileset.json", []
    )
    assert tiles == len(tile_groups(atlas.triangles, 3)) > 1
    ts = Tileset(str(out), frame)
    ts.expand(ts.root)
    centres = atlas.triangles.mean(axis=1)
    found = 0
    for tile in ts.root.children:
        for prim in decode_tile(ts, tile, None).primitives:
            tri = prim.positions[prim.indices].astype(np.float64)  # (n, 3, 3) ENU
            uv = prim.uvs[prim.indices].mean(axis=1)  # the middle's uv (v up, as Primitive)
            h, w = prim.texture.shape[:2]
            for k in range(len(tri)):
                j = int(np.argmin(np.linalg.norm(centres - tri[k].mean(axis=0), axis=1)))
                assert (
                    np.abs(np.sort(tri[k], axis=0) - np.sort(atlas.triangles[j], axis=0)).max()
                    < 0.01
                )
                texel = prim.texture[int(uv[k, 1] * h), int(uv[k, 0] * w), :3]
                assert np.abs(texel.astype(int) - palette[j]).max() <= 1, (j, texel, palette[j])
                found += 1
    assert found == t
