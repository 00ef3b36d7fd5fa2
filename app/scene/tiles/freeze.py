"""The tiles of a scene's streamed 3D Tiles layers that a set of cameras needs, decoded once
and held as static primitives: what the exports paint (an orthophoto, a painted model) when the
scene is a tileset. Pure of GL.

Each camera selects the tiles it would draw at `max_sse_px` screen-space error (the viewer's
rule, app.scene.tiles.stream); the union is kept, less any tile under REPLACE refinement whose
selected descendants stand in for it (the finest detail any camera asked for wins). Memory
grows with the tiles kept, and is said (`frozen_tiles` returns their count and bytes).
"""

from __future__ import annotations

from collections.abc import Iterable

from app.camera.pinhole import Camera
from app.core.errors import GeofuseError
from app.scene.mesh import MeshData
from app.scene.tiles.stream import DEFAULT_MAX_SSE_PX, TileStream, TileView
from app.scene.tiles.tileset import Tile

WAIT_S = 1.0  # each round waits at most this long for a worker's result


class FreezeError(GeofuseError):
    """The tiles a camera needs did not load within the time given."""


def _selected(
    stream: TileStream, camera: Camera, rounds: int, loaded: dict[int, MeshData]
) -> dict[int, Tile]:
    """The tiles `camera` draws once its selection is complete, their decoded contents kept in
    `loaded` by tile id."""
    view = TileView.of(camera)
    for _ in range(rounds):
        sel = stream.select(view, "freeze")
        for item in stream.take_loaded():
            if item.mesh is not None:
                loaded[item.tile.id] = item.mesh
                stream.mark_ready(item.tile)
        if sel.complete:
            return {t.id: t for t in sel.tiles}
        stream.wait_loaded(WAIT_S)
    raise FreezeError(f"{stream.tileset.location}: the 3D Tiles a camera needs did not load")


def _finest(root: Tile, chosen: dict[int, Tile]) -> list[Tile]:
    """The chosen tiles less those under REPLACE refinement with a chosen descendant."""
    keep = []

    def visit(tile: Tile) -> bool:
        """Whether the tile or a descendant is chosen (visiting all of them)."""
        below = any([visit(c) for c in tile.children or []])
        if tile.id in chosen and (tile.refine == "ADD" or not below):
            keep.append(tile)
        return below or tile.id in chosen

    visit(root)
    return keep


def frozen_tiles(
    mesh: MeshData,
    cameras: Iterable[Camera],
    max_sse_px: float = DEFAULT_MAX_SSE_PX,
    rounds: int = 600,
) -> tuple[MeshData, int, int]:
    """(the mesh with each tileset's needed tiles as static primitives and no tileset, tiles
    kept, their bytes). Without tilesets, the mesh itself. Raises FreezeError when a camera's
    tiles do not load within `rounds` waits of WAIT_S."""
    if not mesh.tilesets:
        return mesh, 0, 0
    cameras = list(cameras)
    prims = list(mesh.primitives)
    count = nbytes = 0
    for tileset in mesh.tilesets:
        stream = TileStream(tileset, max_sse_px)
        loaded: dict[int, MeshData] = {}
        try:
            chosen: dict[int, Tile] = {}
            for camera in cameras:
                chosen.update(_selected(stream, camera, rounds, loaded))
            for tile in _finest(tileset.root, chosen):
                data = loaded.get(tile.id) or stream.decode(tileset, tile, stream.skipped)
                prims += data.primitives
                count += 1
                nbytes += sum(p.positions.nbytes + p.indices.nbytes + (p.texture.nbytes if p.texture is not None else 0) for p in data.primitives)  # fmt: skip
        finally:
            stream.close()
    return MeshData(prims, [], mesh.features), count, nbytes
