"""The scene as plain arrays: what the renderer uploads. No GL here.

Positions are float32 metres in the session's ENU frame relative to its origin (float32-safe
for scenes a few kilometres across); texture images are uint8 RGBA stored bottom row first, so
that uv = (0, 0) is the image's bottom-left corner, as OpenGL samples it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt


@dataclass
class Primitive:
    """One draw call's worth of triangles sharing a material.

    positions: (N, 3) float32 ENU m; uvs: (N, 2) float32 or None; colors: (N, 4) float32 in
    [0, 1] (vertex colour times base colour); indices: (M, 3) uint32; texture: (H, W, 4) uint8,
    bottom row first, or None. Normals are not stored: the shaders derive each face's normal
    from screen-space derivatives, which is exact for flat faces and costs no memory. cut: its
    outline is where its data was cut (a terrain read over a window, the assumed ground), not
    an edge of anything in the world, which goes on beyond it.
    """

    positions: npt.NDArray[np.float32]
    colors: npt.NDArray[np.float32]
    indices: npt.NDArray[np.uint32]
    uvs: npt.NDArray[np.float32] | None = None
    texture: npt.NDArray[np.uint8] | None = None
    name: str = ""
    cut: bool = False

    def __post_init__(self) -> None:
        n = len(self.positions)
        if self.colors.shape != (n, 4):
            raise ValueError(
                f"primitive {self.name!r}: colors shape {self.colors.shape}, expected ({n}, 4)"
            )
        if self.uvs is not None and self.uvs.shape != (n, 2):
            raise ValueError(
                f"primitive {self.name!r}: uvs shape {self.uvs.shape}, expected ({n}, 2)"
            )
        if self.indices.ndim != 2 or self.indices.shape[1] != 3:
            raise ValueError(
                f"primitive {self.name!r}: indices shape {self.indices.shape}, expected (M, 3)"
            )
        if len(self.indices) and int(self.indices.max()) >= n:
            raise ValueError(
                f"primitive {self.name!r}: index {int(self.indices.max())} >= {n} vertices"
            )

    @property
    def textured(self) -> bool:
        return self.texture is not None and self.uvs is not None


@dataclass
class MeshData:
    """A whole scene in the session ENU frame: static primitives (model files, terrain, the
    assumed ground), streamed 3D Tiles layers (app.scene.tiles.Tileset), whose tiles the
    renderer loads as cameras need them, and the feature tables of city layers
    (app.scene.city.model.FeatureTable), which name the object each of their triangles is."""

    primitives: list[Primitive] = field(default_factory=list)
    tilesets: list = field(default_factory=list)
    features: list = field(default_factory=list)

    def merged(self, other: MeshData) -> MeshData:
        """Both scenes' layers in one."""
        return MeshData(
            self.primitives + other.primitives,
            self.tilesets + other.tilesets,
            self.features + other.features,
        )

    def feature_at(self, point_enu: npt.ArrayLike, tolerance_m: float = 0.25):
        """The city object (app.scene.city.model.Feature) whose surface lies nearest the ENU
        point (m) within tolerance_m, None where no city layer has one."""
        found = [f for t in self.features if (f := t.at(point_enu, tolerance_m)) is not None]
        return min(found, key=lambda f: f.distance_m, default=None)

    @property
    def triangle_count(self) -> int:
        return sum(len(p.indices) for p in self.primitives)

    @property
    def vertex_count(self) -> int:
        return sum(len(p.positions) for p in self.primitives)

    def bounds(self) -> npt.NDArray[np.float64]:
        """(2, 3) min and max corner in ENU metres (a tileset's by its root volume)."""
        boxes = [
            np.stack([p.positions.min(axis=0), p.positions.max(axis=0)])
            for p in self.primitives
            if len(p.positions)
        ]
        boxes += [np.asarray(t.bounds(), np.float64) for t in self.tilesets]
        if not boxes:
            return np.zeros((2, 3))
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        return np.stack([lo, hi]).astype(np.float64)

    def horizontal_distance(self, points_enu: npt.ArrayLike) -> float:
        """The horizontal distance (m) from the nearest of the points (N, 3 or 2; ENU) to the
        scene's bounding box: 0 when a point lies over the scene."""
        p = np.atleast_2d(np.asarray(points_enu, np.float64))[:, :2]
        lo, hi = self.bounds()[:, :2]
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return float(np.hypot(gap[:, 0], gap[:, 1]).min()) if len(p) else 0.0


def merge_untextured(prims: list[Primitive], name: str = "untextured") -> list[Primitive]:
    """Every untextured primitive concatenated into one draw call (named `name`); textured ones
    stay apart, first."""
    flat = [p for p in prims if not p.textured]
    if len(flat) <= 1:
        return prims
    offsets = np.cumsum([0] + [len(p.positions) for p in flat[:-1]])
    merged = Primitive(
        positions=np.concatenate([p.positions for p in flat]),
        colors=np.concatenate([p.colors for p in flat]),
        indices=np.concatenate(
            [p.indices + np.uint32(o) for p, o in zip(flat, offsets, strict=True)]
        ),
        name=name,
    )
    return [p for p in prims if p.textured] + [merged]
