import numpy as np
import pytest
import trimesh
from PIL import Image

from app.core.errors import SceneError
from app.geodesy.enu import LocalFrame
from app.scene import Placement, load_scene

ORIGIN = (34.80, 113.53, 110.0)
FRAME = LocalFrame(*ORIGIN)


def textured_square_glb(path, y_up_vertices):
    """A 2x2 m square with a 4x2 texture whose top-left texel is red, written as GLB."""
    tex = np.zeros((2, 4, 3), np.uint8)
    tex[0, 0] = (255, 0, 0)  # image top-left
    tex[1, 3] = (0, 0, 255)  # image bottom-right
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    mesh = trimesh.Trimesh(
        vertices=y_up_vertices,
        faces=[[0, 1, 2], [0, 2, 3]],
        visual=trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(tex)),
        process=False,
    )
    scene = trimesh.Scene()
    scene.add_geometry(mesh, transform=trimesh.transformations.translation_matrix([10.0, 0.0, 0.0]))
    scene.export(path)
    return tex


def test_glb_y_up_with_node_transform_and_texture(tmp_path):
    path = tmp_path / "square.glb"
    # In glTF Y-up coordinates: a square lying on the ground (y = 0) spanning x 0..2, z 0..-2
    # (glTF -z is north).
    tex = textured_square_glb(path, [[0, 0, 0], [2, 0, 0], [2, 0, -2], [0, 0, -2]])
    mesh = load_scene(path, FRAME)
    assert len(mesh.primitives) == 1
    prim = mesh.primitives[0]
    # Node translation +10 along glTF x (east); -z becomes north; all at height 0.
    np.testing.assert_allclose(mesh.bounds(), [[10, 0, 0], [12, 2, 0]], atol=1e-5)
    assert prim.textured
    # Stored bottom row first: uv (0, 0) is the image's bottom-left texel.
    np.testing.assert_array_equal(prim.texture[-1, 0, :3], tex[0, 0])
    np.testing.assert_array_equal(prim.texture[0, 3, :3], tex[1, 3])
    # trimesh's glTF loader keeps uv with v up; our uv of the (0,0) vertex stays (0,0).
    i = int(np.argmin(np.linalg.norm(prim.positions - [10, 0, 0], axis=1)))
    np.testing.assert_allclose(prim.uvs[i], [0, 0], atol=1e-6)


def test_heading_scale_and_model_origin(tmp_path):
    path = tmp_path / "stick.ply"
    trimesh.Trimesh(vertices=[[0, 0, 0], [0, 1, 0], [0, 1, 1]], faces=[[0, 1, 2]]).export(path)
    # Z-up model, 10 m per unit, rotated 90 deg clockwise: model north (0, 1) points east.
    mesh = load_scene(path, FRAME, Placement(up_axis="Z", heading_deg=90.0, scale=10.0))
    pts = mesh.primitives[0].positions
    np.testing.assert_allclose(pts[1], [10, 0, 0], atol=1e-5)
    np.testing.assert_allclose(pts[2], [10, 0, 10], atol=1e-5)
    # The same model anchored 0.001 deg east of the session origin lands ~91.4 m east.
    elsewhere = (ORIGIN[0], ORIGIN[1] + 0.001, ORIGIN[2])
    mesh = load_scene(path, FRAME, Placement(origin=elsewhere, up_axis="Z"))
    expected = FRAME.geodetic_to_enu(*elsewhere)
    np.testing.assert_allclose(mesh.primitives[0].positions[0], expected, atol=1e-3)
    assert expected[0] == pytest.approx(91.4, abs=0.2)


def test_ecef_model_goes_to_session_enu(tmp_path):
    enu = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 5.0]])
    ecef = FRAME.enu_to_ecef(enu)
    path = tmp_path / "tile.obj"  # OBJ is text: full float64 precision (a float32 PLY loses ~0.2 m)
    trimesh.Trimesh(vertices=ecef, faces=[[0, 1, 2]], process=False).export(path, digits=6)
    mesh = load_scene(path, FRAME)
    np.testing.assert_allclose(mesh.primitives[0].positions, enu, atol=1e-3)


def test_obj_with_vertex_colours_is_merged_into_one_draw(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    a.visual.vertex_colors = [255, 0, 0, 255]
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation([3, 0, 0])
    b.visual.vertex_colors = [0, 255, 0, 255]
    path = tmp_path / "boxes.obj"
    trimesh.Scene([a, b]).export(path)
    mesh = load_scene(path, FRAME)
    assert mesh.triangle_count == 24
    assert len(mesh.primitives) == 1


def test_clear_errors(tmp_path):
    with pytest.raises(SceneError, match="does not exist") as err:
        load_scene(tmp_path / "nope.glb", FRAME)
    assert "nope.glb" in str(err.value)
    bad = tmp_path / "scene.fbx"
    bad.write_text("x")
    with pytest.raises(SceneError, match="unknown scene format"):
        load_scene(bad, FRAME)
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(10, 3))).export(cloud)
    with pytest.raises(SceneError, match="no mesh with faces"):
        load_scene(cloud, FRAME)
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(SceneError, match="broken.glb"):
        load_scene(broken, FRAME)
