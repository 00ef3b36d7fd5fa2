"""A texture atlas over a scene's triangles, for painting what the video saw onto every surface:
facades as well as roofs and ground. Pure numpy.

Each triangle gets a chart of its own, laid flat in its plane (its first edge along x) at a
texel size, with a texel of margin; the charts are packed in shelves into one image. The texel
size is one for the whole scene, the smallest that keeps the atlas within `max_texels` (so
memory is bounded whatever the scene); or each triangle's own, from what the video's pixels
cover there (app.export.sampling), scaled up alike only where the cap needs it; it is
reported. A paged memory (app.export.paged) lays out pages of triangles the same way. Every texel whose centre lies within one texel of
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
    """texel_m: metres a texel (the finest, where texels differ); size: (width, height) texels; triangles (T, 3, 3) float64 ENU;
    uvs (T, 3, 2) of their corners in [0, 1] (v up); samples: pixels (N, 2) int (x, y up),
    points (N, 3) and normals (N, 3) float32 ENU, base (N, 3) uint8 the model's colour, and
    triangle (N,) int the triangle (of `triangles`) each sample lies on; corners (T, 2) and
    sizes (T, 2) int each triangle's chart (lower-left texel, width and height, margins in);
    texels (T,) m each chart's texel size."""

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
    texels: np.ndarray | None = None
    _nearest: np.ndarray | None = field(default=None, init=False, repr=False)

    @property
    def nbytes(self) -> int:
        """Bytes its arrays hold (the nearest-sample index too, once computed)."""
        arrays = (self.triangles, self.uvs, self.pixels, self.points, self.normals, self.base)
        extra = (self.triangle, self.corners, self.sizes)
        near = 0 if self._nearest is None else self._nearest.nbytes
        return sum(a.nbytes for a in (*arrays, *extra)) + near

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


@dataclass(frozen=True)
class Triangles:
    """A scene's static triangles to lay out: corners (T, 3, 3) float64 ENU m; owner (T,) the
    primitive of the mesh each comes from and index (T,) its triangle there; within (T, 3, 3)
    each corner's barycentric weights in that source triangle (the identity, until split)."""

    corners: np.ndarray
    owner: np.ndarray
    index: np.ndarray
    within: np.ndarray

    def __len__(self) -> int:
        return len(self.corners)

    def subset(self, idx: np.ndarray) -> Triangles:
        return Triangles(self.corners[idx], self.owner[idx], self.index[idx], self.within[idx])

    def split(self, which: np.ndarray) -> tuple[Triangles, np.ndarray]:
        """Each triangle of `which` (bool (T,)) cut in two at the middle of its longest edge
        (same winding), the others kept: (the triangles, (T',) the old index of each)."""
        t = self.corners
        edge = np.stack([np.linalg.norm(t[:, (k + 1) % 3] - t[:, k], axis=1) for k in range(3)], 1)
        a = np.argmax(edge, axis=1)
        rows = np.arange(len(t))
        order = np.stack([a, (a + 1) % 3, (a + 2) % 3], axis=1)  # the longest edge first
        c = t[rows[:, None], order]
        w = self.within[rows[:, None], order]
        mid, wmid = (c[:, 0] + c[:, 1]) / 2, (w[:, 0] + w[:, 1]) / 2
        first = np.stack([c[:, 0], mid, c[:, 2]], axis=1)
        second = np.stack([mid, c[:, 1], c[:, 2]], axis=1)
        wfirst = np.stack([w[:, 0], wmid, w[:, 2]], axis=1)
        wsecond = np.stack([wmid, w[:, 1], w[:, 2]], axis=1)
        keep, cut = np.flatnonzero(~which), np.flatnonzero(which)
        old = np.concatenate([keep, cut, cut])
        return (
            Triangles(
                np.concatenate([t[keep], first[cut], second[cut]]),
                self.owner[old],
                self.index[old],
                np.concatenate([self.within[keep], wfirst[cut], wsecond[cut]]),
            ),
            old,
        )


def triangles_of(mesh: MeshData) -> Triangles:
    """Every static triangle of the scene. Raises ValueError for a scene without triangles."""
    parts = [(k, p.positions.astype(np.float64)[p.indices]) for k, p in enumerate(mesh.primitives)]
    parts = [(k, t) for k, t in parts if len(t)]
    if not parts:
        raise ValueError("the scene has no triangles to paint (streamed 3D Tiles are not)")
    tri = np.concatenate([t for _, t in parts])
    return Triangles(
        tri,
        np.concatenate([np.full(len(t), k) for k, t in parts]),
        np.concatenate([np.arange(len(t)) for _, t in parts]),
        np.broadcast_to(np.eye(3), tri.shape).copy(),
    )


def chart_sizes(triangles: Triangles, texels: np.ndarray) -> np.ndarray:
    """(T, 2) int each triangle's chart (w, h) texels at its texel size (T,) m, margins in."""
    return _sizes(_extent(triangles.corners), texels)


def _sizes(extent: np.ndarray, texels: np.ndarray) -> np.ndarray:
    return (np.ceil(extent / texels[:, None]) + 2).astype(np.int64)


def layout(mesh: MeshData, max_texels: int = 4_000_000, texels: np.ndarray | None = None) -> Atlas:
    """The atlas of every static triangle of the scene (see the module docstring): one texel
    size for all, the smallest within max_texels; or, given texels (T,) m per triangle of
    triangles_of(mesh) (app.export.sampling: what the video's pixels cover there), those,
    scaled up alike where they would exceed max_texels. Raises ValueError for a scene without
    triangles."""
    tris = triangles_of(mesh)
    extent = _extent(tris.corners)
    if texels is None:
        area = np.sum((extent[:, 0] + 1e-3) * (extent[:, 1] + 1e-3))
        texels = np.full(len(tris), float(np.sqrt(area / max_texels)))
    else:
        texels = np.asarray(texels, np.float64)
        need = np.sum((extent[:, 0] / texels + 2) * (extent[:, 1] / texels + 2))
        texels = texels * max(1.0, float(np.sqrt(need / max_texels)))
    while True:
        sizes = _sizes(extent, texels)  # the charts' extents computed once
        corners, width, height = pack(sizes)
        if width * height <= max_texels and height <= MAX_SIDE:
            break
        texels = texels * 1.1
    return charts(mesh, tris, texels, sizes, corners, (width, height))


def _extent(tri: np.ndarray) -> np.ndarray:
    flat = _frames(tri)[3]
    return flat.max(axis=1) - flat.min(axis=1)


def packed(mesh: MeshData, tris: Triangles, texels: np.ndarray) -> Atlas:
    """An atlas of the triangles at their texel sizes (T,) m, packed in shelves (at most
    MAX_SIDE wide). The page of a paged memory (app.export.paged)."""
    sizes = chart_sizes(tris, texels)
    corners, width, height = pack(sizes)
    return charts(mesh, tris, texels, sizes, corners, (width, height))


def charts(
    mesh: MeshData,
    tris: Triangles,
    texels: np.ndarray,
    sizes: np.ndarray,
    corners: np.ndarray,
    size: tuple[int, int],
) -> Atlas:
    """The atlas of the triangles, each chart (sizes (T, 2), lower-left corners (T, 2)) laid
    out in an atlas of `size` (w, h) texels at its triangle's texel size (T,) m: its samples,
    uvs and the model's colours."""
    tri = tris.corners
    e1, e2, n, flat = _frames(tri)
    lo = flat.min(axis=1)
    width, height = size
    pixels, points, normals, bary_all, on = [], [], [], [], []
    uvs = np.zeros((len(tri), 3, 2))
    for t in range(len(tri)):
        texel = texels[t]
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
        on.append(np.full(int(near.sum()), t))
        bary_all.append(clamped[near] @ tris.within[t])  # in the source triangle
        uvs[t] = (corners[t] + (flat[t] - lo[t]) / texel + 1.0) / [width, height]
    on_s = np.concatenate(on) if on else np.zeros(0, np.int64)
    empty = np.zeros((0, 3))
    return Atlas(
        float(np.min(texels)) if len(texels) else 0.0,
        (width, height),
        tri,
        uvs,
        np.concatenate(pixels).astype(np.int64) if pixels else np.zeros((0, 2), np.int64),
        np.concatenate(points or [empty]).astype(np.float32),
        np.concatenate(normals or [empty]).astype(np.float32),
        _base_colours(
            mesh, tris.owner[on_s], np.concatenate(bary_all or [empty]), tris.index[on_s]
        ),
        on_s,
        corners,
        sizes,
        np.asarray(texels, np.float64),
    )
