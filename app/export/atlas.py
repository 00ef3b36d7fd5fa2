"""A texture atlas over a scene's triangles, for painting what the video saw onto every surface:
facades as well as roofs and ground. Pure numpy.

Each triangle gets a chart of its own, laid flat in its plane (its first edge along x) at one
texel size for the whole scene, with a texel of margin; the charts are packed in shelves into
one image. The texel size is the smallest that keeps the atlas within `max_texels` (so memory is
bounded whatever the scene), and is reported. Every texel whose centre lies within one texel of
its triangle is a surface sample: its point (the centre, pulled onto the triangle) and the
triangle's normal, in the scene's ENU frame; its base colour is the model's own (its texture
through its uvs, else its vertex colour), which a painted model keeps where the video saw
nothing. Atlas pixels: x right, y up from the bottom row (OpenGL's and trimesh's uv), stored
top row first in `image`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import distance_transform_edt

from app.scene.mesh import MeshData, Primitive

MAX_SIDE = 16384  # an atlas is at most this many texels wide


@dataclass
class Atlas:
    """texel_m: metres a texel; size: (width, height) texels; triangles (T, 3, 3) float64 ENU;
    uvs (T, 3, 2) of their corners in [0, 1] (v up); samples: pixels (N, 2) int (x, y up),
    points (N, 3) and normals (N, 3) float32 ENU, base (N, 3) uint8 the model's colour, and
    triangle (N,) int the triangle (of `triangles`) each sample lies on; corners (T, 2) and
    sizes (T, 2) int each triangle's chart (lower-left texel, width and height, margins in)."""

    texel_m: float
    size: tuple[int, int]
    triangles: np.ndarray
    uvs: np.ndarray
    pixels: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    base: np.ndarray
    triangle: np.ndarray
    corners: np.ndarray
    sizes: np.ndarray
    _nearest: np.ndarray | None = field(default=None, init=False, repr=False)

    def image(self, rgb: np.ndarray, seen: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8, top row first: the samples' painted colour where seen, else their
        base colour (texels that are no sample: their nearest sample's, see texture)."""
        return np.flipud(self.texture(np.where(seen[:, None], rgb, self.base))[..., :3])

    def texture(self, colours: np.ndarray) -> np.ndarray:
        """(H, W, 4) uint8 RGBA, bottom row first (as the uvs and app.scene.mesh.Primitive
        read it): the samples' colours (N, 3) uint8, opaque; a texel that is no sample takes
        its nearest sample's colour (so that filtering and mipmaps never blend in a colour
        from between the charts)."""
        w, h = self.size
        out = np.empty((h, w, 4), np.uint8)
        out[..., 3] = 255
        out[..., :3] = colours[self.nearest_sample()]
        return out

    def nearest_sample(self) -> np.ndarray:
        """(H, W) int: the sample nearest each texel (itself where it is one), computed once."""
        if self._nearest is None:
            w, h = self.size
            index = np.full((h, w), -1, np.int64)
            index[self.pixels[:, 1], self.pixels[:, 0]] = np.arange(len(self.pixels))
            rows, cols = distance_transform_edt(
                index < 0, return_distances=False, return_indices=True
            )
            self._nearest = index[rows, cols]
        return self._nearest

    def primitive(self, colours: np.ndarray, name: str = "memory") -> Primitive:
        """The atlas's triangles as one textured primitive (ENU m), textured by `colours`."""
        n = 3 * len(self.triangles)
        return Primitive(
            positions=self.triangles.reshape(-1, 3).astype(np.float32),
            colors=np.ones((n, 4), np.float32),
            indices=np.arange(n, dtype=np.uint32).reshape(-1, 3),
            uvs=self.uvs.reshape(-1, 2).astype(np.float32),
            texture=self.texture(colours),
            name=name,
        )


def _frames(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle: e1, e2 (in-plane axes), unit normal, and the corners' 2D coordinates
    (T, 3, 2) in that frame (A at the origin, B on +x, C above)."""
    ab, ac = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(ab, ac)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    e1 = ab / np.maximum(np.linalg.norm(ab, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(n, e1)
    flat = np.stack(
        [np.zeros((len(tri), 2)), np.column_stack([np.einsum("ij,ij->i", ab, e1), np.zeros(len(tri))]),
         np.column_stack([np.einsum("ij,ij->i", ac, e1), np.einsum("ij,ij->i", ac, e2)])],
        axis=1,
    )  # fmt: skip
    return e1, e2, n, flat


def pack(sizes: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Shelf packing of (T, 2) chart sizes (w, h) texels: (T, 2) corners, width, height."""
    area = float(np.sum(sizes[:, 0] * sizes[:, 1]))
    width = int(min(MAX_SIDE, max(int(sizes[:, 0].max()), np.ceil(np.sqrt(area) * 1.05))))
    order = np.argsort(-sizes[:, 1], kind="stable")
    corners = np.zeros_like(sizes)
    x = y = shelf = 0
    for t in order:
        w, h = sizes[t]
        if x + w > width:
            x, y, shelf = 0, y + shelf, 0
        corners[t] = (x, y)
        x += w
        shelf = max(shelf, h)
    return corners, width, int(y + shelf)


def _base_colours(mesh: MeshData, owner: np.ndarray, bary: np.ndarray, tri_index: np.ndarray):
    """The model's own colour (N, 3) uint8 at samples: owner primitive, its triangle, and the
    sample's barycentric weights (N, 3)."""
    out = np.zeros((len(owner), 3), np.uint8)
    for k, prim in enumerate(mesh.primitives):
        sel = np.flatnonzero(owner == k)
        if not len(sel):
            continue
        corners = prim.indices[tri_index[sel]]  # (n, 3) vertex indices
        if prim.textured:
            uv = np.einsum("ij,ijk->ik", bary[sel], prim.uvs[corners])
            th, tw = prim.texture.shape[:2]
            col = np.clip((np.mod(uv[:, 0], 1.0) * tw).astype(int), 0, tw - 1)
            row = np.clip((np.mod(uv[:, 1], 1.0) * th).astype(int), 0, th - 1)
            rgb = prim.texture[row, col, :3].astype(np.float32)  # bottom row first, as uv's v
            rgb *= np.einsum("ij,ijk->ik", bary[sel], prim.colors[corners][..., :3])
        else:
            rgb = 255.0 * np.einsum("ij,ijk->ik", bary[sel], prim.colors[corners][..., :3])
        out[sel] = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
    return out


def layout(mesh: MeshData, max_texels: int = 4_000_000) -> Atlas:
    """The atlas of every static triangle of the scene (see the module docstring). Raises
    ValueError for a scene without triangles."""
    parts = [(k, p.positions.astype(np.float64)[p.indices]) for k, p in enumerate(mesh.primitives)]
    parts = [(k, t) for k, t in parts if len(t)]
    if not parts:
        raise ValueError("the scene has no triangles to paint (streamed 3D Tiles are not)")
    tri = np.concatenate([t for _, t in parts])
    owner = np.concatenate([np.full(len(t), k) for k, t in parts])
    tri_index = np.concatenate([np.arange(len(t)) for _, t in parts])
    e1, e2, n, flat = _frames(tri)
    lo = flat.min(axis=1)
    extent = flat.max(axis=1) - lo
    texel = float(np.sqrt(np.sum((extent[:, 0] + 1e-3) * (extent[:, 1] + 1e-3)) / max_texels))
    while True:
        sizes = (np.ceil(extent / texel) + 2).astype(np.int64)
        corners, width, height = pack(sizes)
        if width * height <= max_texels and height <= MAX_SIDE:
            break
        texel *= 1.1
    pixels, points, normals, owners, bary_all, tris, on = [], [], [], [], [], [], []
    uvs = np.zeros((len(tri), 3, 2))
    for t in range(len(tri)):
        w, h = sizes[t]
        px, py = np.meshgrid(np.arange(w), np.arange(h))
        x2 = lo[t, 0] + (px.ravel() - 1 + 0.5) * texel
        y2 = lo[t, 1] + (py.ravel() - 1 + 0.5) * texel
        (ax, ay), (bx, by), (cx, cy) = flat[t]
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if abs(det) < 1e-12:
            continue
        w0 = ((by - cy) * (x2 - cx) + (cx - bx) * (y2 - cy)) / det
        w1 = ((cy - ay) * (x2 - cx) + (ax - cx) * (y2 - cy)) / det
        bary = np.column_stack([w0, w1, 1.0 - w0 - w1])
        clamped = np.clip(bary, 0.0, None)
        clamped /= clamped.sum(axis=1, keepdims=True)
        q2 = clamped @ flat[t]
        near = np.hypot(q2[:, 0] - x2, q2[:, 1] - y2) <= texel
        pixels.append(
            np.column_stack([corners[t, 0] + px.ravel()[near], corners[t, 1] + py.ravel()[near]])
        )
        points.append(tri[t, 0] + q2[near, :1] * e1[t] + q2[near, 1:] * e2[t])
        normals.append(np.repeat(n[t][None], int(near.sum()), axis=0))
        owners.append(np.full(int(near.sum()), owner[t]))
        tris.append(np.full(int(near.sum()), tri_index[t]))
        on.append(np.full(int(near.sum()), t))
        bary_all.append(clamped[near])
        uvs[t] = (corners[t] + (flat[t] - lo[t]) / texel + 1.0) / [width, height]
    owner_s, bary_s, tri_s = np.concatenate(owners), np.concatenate(bary_all), np.concatenate(tris)
    return Atlas(
        texel,
        (width, height),
        tri,
        uvs,
        np.concatenate(pixels).astype(np.int64),
        np.concatenate(points).astype(np.float32),
        np.concatenate(normals).astype(np.float32),
        _base_colours(mesh, owner_s, bary_s, tri_s),
        np.concatenate(on),
        corners,
        sizes,
    )
