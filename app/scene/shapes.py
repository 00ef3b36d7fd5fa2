"""Simple solids as arrays (vertices (N, 3) float64, faces (M, 3) int64, uvs (N, 2)), counter-
clockwise seen from outside. Used by the sample-scene generator and by the tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.scene.mesh import Primitive


@dataclass
class Shape:
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray

    @staticmethod
    def concat(shapes: list[Shape]) -> Shape:
        offsets = np.cumsum([0] + [len(s.vertices) for s in shapes[:-1]])
        return Shape(
            np.concatenate([s.vertices for s in shapes]),
            np.concatenate([s.faces + o for s, o in zip(shapes, offsets, strict=True)]),
            np.concatenate([s.uvs for s in shapes]),
        )

    def primitive(
        self,
        color: npt.ArrayLike = (0.75, 0.75, 0.72, 1.0),
        texture: np.ndarray | None = None,
        name: str = "",
    ) -> Primitive:
        """As a renderer primitive (positions already in ENU). `texture` is top row first."""
        n = len(self.vertices)
        return Primitive(
            positions=self.vertices.astype(np.float32),
            colors=np.tile(np.asarray(color, np.float32), (n, 1)),
            indices=self.faces.astype(np.uint32),
            uvs=self.uvs.astype(np.float32) if texture is not None else None,
            texture=None if texture is None else np.ascontiguousarray(texture[::-1]),
            name=name,
        )


def quad(
    origin: npt.ArrayLike,
    u_edge: npt.ArrayLike,
    v_edge: npt.ArrayLike,
    uv_rect: tuple[float, float, float, float] = (0, 0, 1, 1),
) -> Shape:
    """Parallelogram origin + s*u_edge + t*v_edge, s, t in [0, 1]; front face is u_edge x v_edge.

    uv_rect = (u0, v0, u1, v1): texture coordinates of the origin corner and of the opposite one.
    """
    o, u, v = (np.asarray(a, np.float64) for a in (origin, u_edge, v_edge))
    verts = np.array([o, o + u, o + u + v, o + v])
    u0, v0, u1, v1 = uv_rect
    uvs = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], np.float64)
    return Shape(verts, np.array([[0, 1, 2], [0, 2, 3]]), uvs)


def box(
    min_corner: npt.ArrayLike, max_corner: npt.ArrayLike, top: bool = True, bottom: bool = False
) -> Shape:
    """Axis-aligned box as separate faces (sides, optional top and bottom), uv (0..1) per face."""
    lo, hi = np.asarray(min_corner, np.float64), np.asarray(max_corner, np.float64)
    dx, dy, dz = hi - lo
    ex, ey, ez = np.eye(3)
    faces = [
        quad(lo, ex * dx, ez * dz),  # south side (normal -y)
        quad([hi[0], lo[1], lo[2]], ey * dy, ez * dz),  # east (+x)
        quad([hi[0], hi[1], lo[2]], -ex * dx, ez * dz),  # north (+y)
        quad([lo[0], hi[1], lo[2]], -ey * dy, ez * dz),  # west (-x)
    ]
    if top:
        faces.append(quad([lo[0], lo[1], hi[2]], ex * dx, ey * dy))
    if bottom:
        faces.append(quad([lo[0], hi[1], lo[2]], ex * dx, -ey * dy))
    return Shape.concat(faces)


def prism_sides(min_corner: npt.ArrayLike, max_corner: npt.ArrayLike) -> Shape:
    """The four walls of an axis-aligned block, textured as one strip wrapped around it.

    u runs along the perimeter (south wall west->east, then east, north, west walls) from 0 to 1;
    v runs from 0 at the base to 1 at the top. So one image of (perimeter x height) proportions
    paints every wall without seams or stretching.
    """
    lo, hi = np.asarray(min_corner, np.float64), np.asarray(max_corner, np.float64)
    dx, dy, dz = hi - lo
    perimeter = 2.0 * (dx + dy)
    ex, ey, ez = np.eye(3)
    walls = [
        ([lo[0], lo[1], lo[2]], ex * dx, dx),
        ([hi[0], lo[1], lo[2]], ey * dy, dy),
        ([hi[0], hi[1], lo[2]], -ex * dx, dx),
        ([lo[0], hi[1], lo[2]], -ey * dy, dy),
    ]
    out, start = [], 0.0
    for origin, edge, length in walls:
        u0, u1 = start / perimeter, (start + length) / perimeter
        out.append(quad(origin, edge, ez * dz, (u0, 0.0, u1, 1.0)))
        start += length
    return Shape.concat(out)


def wall_spans(
    min_corner: npt.ArrayLike, max_corner: npt.ArrayLike
) -> list[tuple[str, float, float]]:
    """(facing, start, end) of each wall along the prism_sides strip, in metres."""
    lo, hi = np.asarray(min_corner, np.float64), np.asarray(max_corner, np.float64)
    dx, dy = (hi - lo)[:2]
    return [
        ("S", 0.0, dx),
        ("E", dx, dx + dy),
        ("N", dx + dy, 2 * dx + dy),
        ("W", 2 * dx + dy, 2 * (dx + dy)),
    ]
