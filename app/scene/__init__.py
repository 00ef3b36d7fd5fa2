"""Scene loading and placement: trimesh -> origin-relative ENU arrays (MeshData) for the renderer."""

from app.scene.loader import Placement, load_scene
from app.scene.mesh import MeshData, Primitive

__all__ = ["MeshData", "Placement", "Primitive", "load_scene"]
