"""`geofuse export model --out DIR/tileset.json`: the painted scene (app.export.painted) as 3D
Tiles 1.1 for scenes too large for one GLB: its triangles split into tiles of at most
`max_triangles` (halving the longer horizontal side of their centres' box, at the median, until
each part is small enough), each tile one GLB whose own atlas holds only its triangles' charts
(copied from the scene's painted atlas, so the texels are the same), beside the tileset JSON.

The tileset's root transform takes the session's local east-north-up metres to ECEF; its
children are the tiles (refine ADD, geometric error 0), each with a box bounding volume. Any
3D Tiles viewer (CesiumJS, QGIS, geofuse) places it on the globe.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from app.core.outputs import check_output, write_atomically
from app.export.atlas import Atlas, pack
from app.export.memory import SurfaceMemory
from app.export.painted import glb_bytes
from app.geodesy.enu import LocalFrame
from app.scene.tiles.write import box_of, column_major, enu_to_ecef_matrix

MAX_TILE_TRIANGLES = 50_000


def tile_groups(triangles: np.ndarray, max_triangles: int = MAX_TILE_TRIANGLES) -> list[np.ndarray]:
    """Indices of the triangles (T, 3, 3) ENU in each tile: split at the median of the longer
    horizontal side of their centres' box until each part holds at most max_triangles."""
    centres = triangles.mean(axis=1)
    todo, out = [np.arange(len(triangles))], []
    while todo:
        idx = todo.pop()
        if len(idx) <= max_triangles:
            out.append(idx)
            continue
        c = centres[idx, :2]
        axis = int(np.argmax(np.ptp(c, axis=0)))
        order = idx[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        todo += [order[:half], order[half:]]
    return out


def tile_atlas(
    atlas: Atlas, texture: np.ndarray, tris: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One tile's own atlas: ((h, w, 4) bottom row first, its triangles' uvs (n, 3, 2)), the
    charts of `tris` copied from the scene's texture (bottom row first) and packed again."""
    sizes, old = atlas.sizes[tris], atlas.corners[tris]
    new, w, h = pack(sizes)
    out = np.zeros((h, w, 4), np.uint8)
    for (nx, ny), (ox, oy), (sw, sh) in zip(new, old, sizes, strict=True):
        out[ny : ny + sh, nx : nx + sw] = texture[oy : oy + sh, ox : ox + sw]
    W, H = atlas.size
    uvs = (atlas.uvs[tris] * [W, H] - old[:, None, :] + new[:, None, :]) / [w, h]
    return out, uvs


def write_painted_tiles(
    atlas: Atlas,
    memory: SurfaceMemory,
    frame: LocalFrame,
    out: Path,
    inputs: list[Path],
    max_triangles: int = MAX_TILE_TRIANGLES,
) -> tuple[Path, int]:
    """The tileset at `out` (…/tileset.json) and its tiles beside it, never over an input.
    Returns (its path, the number of tiles)."""
    out = check_output(out, "--out", (".json",), inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    texture = atlas.texture(np.where(memory.seen[:, None], memory.rgb, atlas.base))
    children = []
    for k, tris in enumerate(tile_groups(atlas.triangles, max_triangles)):
        image, uvs = tile_atlas(atlas, texture, tris)
        data = glb_bytes(atlas.triangles[tris], uvs, np.flipud(image)[..., :3])
        name = f"{out.stem}_{k}.glb"
        tile = check_output(out.parent / name, "--out", (".glb",), inputs)  # never over an input
        write_atomically(tile, "--out", lambda f, d=data: f.write(d), binary=True)
        pts = atlas.triangles[tris].reshape(-1, 3)
        children.append(
            {
                "boundingVolume": {"box": box_of(pts.min(axis=0) - 0.01, pts.max(axis=0) + 0.01)},
                "geometricError": 0.0,
                "content": {"uri": name},
            }
        )
    pts = atlas.triangles.reshape(-1, 3)
    lo, hi = pts.min(axis=0) - 0.01, pts.max(axis=0) + 0.01
    error = float(np.linalg.norm(hi - lo))
    doc = {
        "asset": {"version": "1.1", "generator": "geofuse export model"},
        "geometricError": error,
        "root": {
            "transform": column_major(enu_to_ecef_matrix(frame)),
            "boundingVolume": {"box": box_of(lo, hi)},
            "geometricError": error,
            "refine": "ADD",
            "children": children,
        },
    }
    text = json.dumps(doc, indent=1)
    return write_atomically(out, "--out", lambda f: f.write(text)), len(children)
