"""`geofuse export model --out DIR/tileset.json`: the painted scene (app.export.painted) as 3D
Tiles 1.1 for scenes too large for one GLB, each tile one GLB beside the tileset JSON. A paged
memory (app.export.paged, the default) gives a tile a page, its texture the page's atlas,
written while that page is held (so the memory stays within its bound). One atlas is split
into tiles of at most `max_triangles` (halving the longer horizontal side of their centres'
box, at the median, until each part is small enough), each with its own atlas holding only its
triangles' charts (copied from the scene's painted atlas, so the texels are the same).

The tileset's root transform takes the session's local east-north-up metres to ECEF; its
children are the tiles (refine ADD, geometric error 0), each with a box bounding volume. Any
3D Tiles viewer (CesiumJS, QGIS, geofuse) places it on the globe.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from app.core.outputs import check_output, write_atomically
from app.export.atlas import Atlas, pack
from app.export.memory import SurfaceMemory
from app.export.paged import PagedMemory, spatial_groups
from app.export.painted import glb_bytes
from app.geodesy.enu import LocalFrame
from app.scene.tiles.write import box_of, column_major, enu_to_ecef_matrix

MAX_TILE_TRIANGLES = 50_000
Tile = tuple[
    np.ndarray, np.ndarray, np.ndarray
]  # triangles (n, 3, 3) ENU, uvs (n, 3, 2), RGB top row first


def tile_groups(triangles: np.ndarray, max_triangles: int = MAX_TILE_TRIANGLES) -> list[np.ndarray]:
    """Indices of the triangles (T, 3, 3) ENU in each tile: split at the median of the longer
    horizontal side of their centres' box until each part holds at most max_triangles."""
    return spatial_groups(triangles.mean(axis=1), np.ones(len(triangles)), max_triangles)


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


def atlas_tiles(
    atlas: Atlas, memory: SurfaceMemory, max_triangles: int = MAX_TILE_TRIANGLES
) -> Iterator[Tile]:
    """The painted atlas's tiles: triangles grouped by tile_groups, each with its own atlas."""
    texture = atlas.texture(np.where(memory.seen[:, None], memory.rgb, atlas.base))
    for tris in tile_groups(atlas.triangles, max_triangles):
        image, uvs = tile_atlas(atlas, texture, tris)
        yield atlas.triangles[tris], uvs, np.flipud(image)[..., :3]


def page_tiles(paged: PagedMemory) -> Iterator[Tile]:
    """A paged memory's tiles: one a page, its atlas its texture (held one page at a time)."""
    for _, atlas, memory in paged.each_page():
        yield atlas.triangles, atlas.uvs, atlas.image(memory.rgb, memory.seen)


def write_painted_tiles(
    tiles: Iterable[Tile], frame: LocalFrame, out: Path, inputs: list[Path], credit: str = ""
) -> tuple[Path, int]:
    """The tileset at `out` (…/tileset.json) and its tiles (atlas_tiles, page_tiles) beside
    it, never over an input; credit: the scene's (app.scene.layers.scene_credit), in each
    tile's asset.copyright (what CesiumJS shows as the tileset's credits). Returns (its path,
    the number of tiles)."""
    out = check_output(out, "--out", (".json",), inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    children = []
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, (triangles, uvs, image) in enumerate(tiles):
        data = glb_bytes(triangles, uvs, image, credit)
        name = f"{out.stem}_{k}.glb"
        tile = check_output(out.parent / name, "--out", (".glb",), inputs)  # never over an input
        write_atomically(tile, "--out", lambda f, d=data: f.write(d), binary=True)
        pts = triangles.reshape(-1, 3)
        tile_lo, tile_hi = pts.min(axis=0) - 0.01, pts.max(axis=0) + 0.01
        lo, hi = np.minimum(lo, tile_lo), np.maximum(hi, tile_hi)
        children.append(
            {
                "boundingVolume": {"box": box_of(tile_lo, tile_hi)},
                "geometricError": 0.0,
                "content": {"uri": name},
            }
        )
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
