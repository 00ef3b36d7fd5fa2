"""Write 3D Tiles: GLB, b3dm, cmpt, subtrees and tileset JSON, and a generated city.

Used by the tests (tilesets of every feature the reader handles, written at test time) and by
`geofuse bench render` (a city of several million triangles in four levels of detail). Geometry is
given in a tile's Z-up frame; GLB stores it Y-up as glTF requires ((x, y, z) -> (x, z, -y)), so a
reader that applies the 3D Tiles Y-up -> Z-up rule gets the input back.
"""

from __future__ import annotations

import io
import json
import shutil
import struct
from dataclasses import dataclass
from pathlib import Path

import DracoPy
import numpy as np
import numpy.typing as npt
from PIL import Image

from app.geodesy.enu import LocalFrame, geodetic_to_ecef
from app.scene import shapes
from app.scene.tiles.implicit import level_offset, morton
from app.scene.tiles.write import box_of, column_major, enu_to_ecef_matrix, write_json
from app.simulate.sample import SAMPLE_SCENE
from app.simulate.stadium import SITE_ORIGIN

Z_UP_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # (x, y, z) -> (x, z, -y)


def _pad(b: bytes, fill: bytes = b"\x00") -> bytes:
    """`b` padded to a multiple of 4 bytes (glTF's chunk and buffer-view alignment)."""
    return b + fill * (-len(b) % 4)


def glb(
    positions: npt.ArrayLike,
    faces: npt.ArrayLike,
    color: tuple[float, float, float, float] = (0.8, 0.8, 0.78, 1.0),
    uvs: npt.ArrayLike | None = None,
    texture_rgb: np.ndarray | None = None,
    node_matrix: np.ndarray | None = None,
    draco: bool = False,
    extensions_required: tuple[str, ...] = (),
    ktx2: bool = False,
) -> bytes:
    """One mesh as GLB. positions (N, 3) in the tile's Z-up frame (stored Y-up, as float32);
    uvs with v = 0 at the image's top (glTF); texture_rgb (H, W, 3) uint8 top row first, PNG;
    node_matrix: the root node's 4x4 (applied in glTF's Y-up space); draco: compress with
    KHR_draco_mesh_compression; ktx2: the texture is declared as KTX2 (KHR_texture_basisu), as
    tilesets with GPU-compressed textures do (the bytes stay PNG: readers must not decode them)."""
    p = np.asarray(positions, np.float64) @ Z_UP_TO_Y_UP.T
    f = np.asarray(faces, np.uint32).reshape(-1, 3)
    t = None if uvs is None else np.asarray(uvs, np.float32)
    bin_parts: list[bytes] = []
    views, accessors = [], []

    def add_view(data: bytes) -> int:
        offset = sum(len(b) for b in bin_parts)
        bin_parts.append(_pad(data))
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data)})
        return len(views) - 1

    prim: dict = {"attributes": {}, "material": 0}
    if draco:
        blob = DracoPy.encode(
            p.astype(np.float32),
            f,
            tex_coord=None if t is None else t.astype(np.float64),
            quantization_bits=16,
        )
        mesh = DracoPy.decode(blob)
        ids = {a["attribute_type"]: a["unique_id"] for a in mesh.attributes}
        ext = {"bufferView": add_view(blob), "attributes": {"POSITION": ids[0]}}
        if t is not None:
            ext["attributes"]["TEXCOORD_0"] = ids[3]
        n = len(mesh.points)
        accessors.append(
            {
                "componentType": 5126,
                "count": n,
                "type": "VEC3",
                "min": p.min(0).tolist(),
                "max": p.max(0).tolist(),
            }
        )
        prim["attributes"]["POSITION"] = 0
        if t is not None:
            accessors.append({"componentType": 5126, "count": n, "type": "VEC2"})
            prim["attributes"]["TEXCOORD_0"] = 1
        accessors.append({"componentType": 5125, "count": len(mesh.faces) * 3, "type": "SCALAR"})
        prim["indices"] = len(accessors) - 1
        prim["extensions"] = {"KHR_draco_mesh_compression": ext}
    else:
        accessors.append(
            {
                "bufferView": add_view(p.astype(np.float32).tobytes()),
                "componentType": 5126,
                "count": len(p),
                "type": "VEC3",
                "min": p.min(0).tolist(),
                "max": p.max(0).tolist(),
            }
        )
        prim["attributes"]["POSITION"] = 0
        if t is not None:
            accessors.append(
                {
                    "bufferView": add_view(t.tobytes()),
                    "componentType": 5126,
                    "count": len(t),
                    "type": "VEC2",
                }
            )
            prim["attributes"]["TEXCOORD_0"] = 1
        accessors.append(
            {
                "bufferView": add_view(f.tobytes()),
                "componentType": 5125,
                "count": f.size,
                "type": "SCALAR",
            }
        )
        prim["indices"] = len(accessors) - 1
    material: dict = {"pbrMetallicRoughness": {"baseColorFactor": list(color)}}
    doc: dict = {
        "asset": {"version": "2.0", "generator": "geofuse tests"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
    }
    if texture_rgb is not None:
        png = io.BytesIO()
        Image.fromarray(np.asarray(texture_rgb, np.uint8)).save(png, "PNG")
        doc["images"] = [
            {
                "bufferView": add_view(png.getvalue()),
                "mimeType": "image/ktx2" if ktx2 else "image/png",
            }
        ]
        doc["textures"] = [
            {"extensions": {"KHR_texture_basisu": {"source": 0}}} if ktx2 else {"source": 0}
        ]
        if ktx2:
            extensions_required = (*extensions_required, "KHR_texture_basisu")
        material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": 0}
    node: dict = {"mesh": 0}
    if node_matrix is not None:
        node["matrix"] = np.asarray(node_matrix, np.float64).T.ravel().tolist()
    doc.update(
        nodes=[node],
        meshes=[{"primitives": [prim]}],
        materials=[material],
        accessors=accessors,
        bufferViews=views,
    )
    used = ["KHR_draco_mesh_compression"] if draco else []
    if used or extensions_required:
        doc["extensionsUsed"] = sorted(set(used) | set(extensions_required))
        doc["extensionsRequired"] = sorted(set(used) | set(extensions_required))
    binary = b"".join(bin_parts)
    doc["buffers"] = [{"byteLength": len(binary)}]
    js = _pad(json.dumps(doc).encode(), b" ")
    body = (
        struct.pack("<II", len(js), 0x4E4F534A)
        + js
        + struct.pack("<II", len(binary), 0x004E4942)
        + binary
    )
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def _feature_table(table: dict) -> bytes:
    raw = json.dumps(table).encode() if table else b""
    return raw + b" " * (-(28 + len(raw)) % 8)


def b3dm(glb_bytes: bytes, rtc_center: npt.ArrayLike | None = None, batch_length: int = 0) -> bytes:
    """A Batched 3D Model tile around a GLB; rtc_center: the feature table's RTC_CENTER."""
    table: dict = {"BATCH_LENGTH": batch_length}
    if rtc_center is not None:
        table["RTC_CENTER"] = [float(v) for v in rtc_center]
    ft = _feature_table(table)
    body = ft + glb_bytes
    body += b"\x00" * (-(28 + len(body)) % 8)  # tiles end on 8-byte boundaries (inside a cmpt too)
    return b"b3dm" + struct.pack("<6I", 1, 28 + len(body), len(ft), 0, 0, 0) + body


def cmpt(tiles: list[bytes]) -> bytes:
    """A Composite tile holding `tiles` (each a whole tile whose byte length is a multiple of 8)."""
    body = b"".join(tiles)
    return b"cmpt" + struct.pack("<3I", 1, 16 + len(body), len(tiles)) + body


def other_tile(magic: bytes) -> bytes:
    """A minimal i3dm or pnts tile (header and an empty feature table): content the reader skips."""
    extra = struct.pack("<I", 1) if magic == b"i3dm" else b""  # i3dm: gltfFormat
    header = 28 + len(extra)
    ft = json.dumps({"INSTANCES_LENGTH": 0} if magic == b"i3dm" else {"POINTS_LENGTH": 0}).encode()
    ft += b" " * (-(header + len(ft)) % 8)
    return magic + struct.pack("<6I", 1, header + len(ft), len(ft), 0, 0, 0) + extra + ft


def subtree(
    dims: int,
    levels: int,
    tiles: set[tuple[int, tuple[int, ...]]],
    contents: set[tuple[int, tuple[int, ...]]],
    children: set[tuple[int, ...]] | None = None,
) -> bytes:
    """A binary subtree: available tiles and contents as (local level, local coords); child
    subtrees by their local coordinates at level `levels` (None: none)."""

    def bits(items: set, index) -> bytes:
        total = level_offset(levels, dims) if index is not morton else (1 << dims) ** levels
        out = bytearray((total + 7) // 8)
        for item in items:
            i = index(item)
            out[i >> 3] |= 1 << (i & 7)
        return bytes(out)

    def tile_index(item):
        level, coords = item
        return level_offset(level, dims) + morton(coords)

    streams = [bits(tiles, tile_index), bits(contents, tile_index)]
    if children:
        streams.append(bits(children, morton))
    binary, views = b"", []
    for s in streams:
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(s)})
        binary += s + b"\x00" * (-len(s) % 8)
    doc = {
        "buffers": [{"byteLength": len(binary)}],
        "bufferViews": views,
        "tileAvailability": {"bitstream": 0},
        "contentAvailability": [{"bitstream": 1}],
        "childSubtreeAvailability": {"bitstream": 2} if children else {"constant": 0},
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 8)
    return b"subt" + struct.pack("<IQQ", 1, len(js), len(binary)) + js + binary


def region_of(frame: LocalFrame, lo_enu: npt.ArrayLike, hi_enu: npt.ArrayLike) -> list[float]:
    """A 3D Tiles region (rad, rad, rad, rad, m, m) enclosing an ENU box of `frame`."""
    lo, hi = np.asarray(lo_enu, np.float64), np.asarray(hi_enu, np.float64)
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    geo = frame.enu_to_geodetic(corners)
    lat, lon, h = np.radians(geo[:, 0]), np.radians(geo[:, 1]), geo[:, 2]
    pad = 1e-7
    return [
        float(lon.min() - pad),
        float(lat.min() - pad),
        float(lon.max() + pad),
        float(lat.max() + pad),
        float(h.min() - 1),
        float(h.max() + 1),
    ]


# -- a generated city ------------------------------------------------------------------------


@dataclass(frozen=True)
class CityStats:
    path: Path
    tiles: int
    triangles: int  # over every level
    leaf_triangles: int  # at full detail
    levels: int


def _block_shape(lo: np.ndarray, hi: np.ndarray, detail: int) -> shapes.Shape:
    """A building block whose walls are split into detail x detail quads (and a flat roof)."""
    walls = []
    ex, ey, ez = np.eye(3)
    d = hi - lo
    for origin, edge in (
        (lo, ex * d[0]),
        (np.array([hi[0], lo[1], lo[2]]), ey * d[1]),
        (np.array([hi[0], hi[1], lo[2]]), -ex * d[0]),
        (np.array([lo[0], hi[1], lo[2]]), -ey * d[1]),
    ):
        s, t = np.meshgrid(
            np.linspace(0, 1, detail + 1), np.linspace(0, 1, detail + 1), indexing="ij"
        )
        verts = origin + s.reshape(-1, 1) * edge + t.reshape(-1, 1) * ez * d[2]
        k = np.arange(detail)
        i, j = np.meshgrid(k, k, indexing="ij")
        a = (i * (detail + 1) + j).ravel()
        b, c, e = a + (detail + 1), a + (detail + 1) + 1, a + 1
        faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, e], 1)])
        walls.append(shapes.Shape(verts, faces, np.zeros((len(verts), 2))))
    walls.append(shapes.quad([lo[0], lo[1], hi[2]], ex * d[0], ey * d[1]))
    return shapes.Shape.concat(walls)


def write_city(
    folder: Path,
    origin: tuple[float, float, float],
    size_m: float = 800.0,
    levels: int = 4,
    blocks_per_leaf: int = 16,
    leaf_detail: int = 24,
) -> CityStats:
    """A city tileset: a quadtree of `levels` levels over size_m x size_m, b3dm content with
    RTC_CENTER, REPLACE refinement. Leaf tiles hold blocks_per_leaf blocks with walls of
    leaf_detail^2 quads; each coarser level merges 2 x 2 blocks into one of their mean height and
    halves the wall detail. A tile's geometricError is what its merging changes (the height range
    of a merged group, the gaps it fills), 0 at the leaves.
    """
    folder.mkdir(parents=True, exist_ok=True)
    frame = LocalFrame(*origin)
    rng = np.random.default_rng(7)
    n_leaf = 1 << (levels - 1)
    side = int(np.sqrt(blocks_per_leaf))
    # block heights: districts of taller and lower buildings (smooth) with a few metres of variety
    k = n_leaf * side
    gy, gx = np.mgrid[0:k, 0:k] * (size_m / k)
    heights = 30.0 + 22.0 * np.sin(gx / 260.0) * np.cos(gy / 210.0) + rng.uniform(-3.0, 3.0, (k, k))
    counts = {"tiles": 0, "triangles": 0, "leaf": 0}

    def tile(level: int, x: int, y: int) -> dict:
        n = 1 << level
        cell = size_m / n
        lo = np.array([-size_m / 2 + x * cell, -size_m / 2 + y * cell, 0.0])
        hi = lo + [cell, cell, 0.0]
        # blocks: at the leaves side x side per tile; coarser tiles merge them 2x2 per level
        merge = 1 << (levels - 1 - level)
        per = max(1, side * n_leaf // (n * merge))
        step = cell / per
        detail = max(1, leaf_detail >> (levels - 1 - level))
        parts = []
        top = 0.0
        # geometric error: how far this level's merged blocks stray from the full-detail ones
        # (the height range within a merged group; the gaps between blocks they fill)
        error = 0.0
        leaf_step = size_m / (n_leaf * side)
        for i in range(per):
            for j in range(per):
                gi, gj = (x * per + i) * merge, (y * per + j) * merge
                group = heights[gi : gi + merge, gj : gj + merge]
                h = float(group.mean())
                if merge > 1:
                    error = max(error, float(group.max() - group.min()), 0.3 * leaf_step)
                b_lo = lo + [i * step + step * 0.15, j * step + step * 0.15, 0.0]
                b_hi = lo + [(i + 1) * step - step * 0.15, (j + 1) * step - step * 0.15, h]
                parts.append(_block_shape(b_lo, b_hi, detail))
                top = max(top, h)
        parts.append(shapes.quad(lo, [cell, 0, 0], [0, cell, 0]))  # the ground of the tile
        shape = shapes.Shape.concat(parts)
        centre = (lo + hi) / 2
        rtc_enu = np.array([centre[0], centre[1], 0.0])
        rtc_ecef = frame.enu_to_ecef(rtc_enu)
        # content in the tile frame (ECEF, no tileset transform): vertices relative to RTC_CENTER
        local = frame.enu_to_ecef(shape.vertices) - rtc_ecef
        name = f"{level}_{x}_{y}.b3dm"
        (folder / name).write_bytes(b3dm(glb(local, shape.faces), rtc_ecef))
        counts["tiles"] += 1
        counts["triangles"] += len(shape.faces)
        node = {
            "boundingVolume": {"region": region_of(frame, lo - [0, 0, 1], hi + [0, 0, top + 1])},
            "geometricError": error,
            "content": {"uri": name},
        }
        if level == levels - 1:
            counts["leaf"] += len(shape.faces)
        else:
            node["children"] = [
                tile(level + 1, 2 * x + a, 2 * y + b) for a in (0, 1) for b in (0, 1)
            ]
        return node

    root = tile(0, 0, 0)
    root["refine"] = "REPLACE"
    doc = {"asset": {"version": "1.1"}, "geometricError": size_m / 4, "root": root}
    path = write_json(folder / "tileset.json", doc)
    return CityStats(path, counts["tiles"], counts["triangles"], counts["leaf"], levels)


__all__ = ["b3dm", "cmpt", "geodetic_to_ecef", "glb", "subtree", "write_city"]


def write_site(folder: Path) -> Path:
    """The sample site's model (app.simulate.sample.SAMPLE_SCENE: glTF, Y-up) as a one-tile
    tileset georeferenced at SITE_ORIGIN (its root's ENU -> ECEF transform): the scene a clip
    opened straight from its files (no manifest, so no origin) can be given with --scene.
    Returns the tileset.json's path."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(SAMPLE_SCENE, folder / "site.glb")
    root = {
        "transform": column_major(enu_to_ecef_matrix(LocalFrame(*SITE_ORIGIN))),
        "boundingVolume": {"box": box_of([-180.0, -180.0, 0.0], [180.0, 180.0, 48.0])},
        "geometricError": 0.0,
        "refine": "ADD",
        "content": {"uri": "site.glb"},
    }
    doc = {"asset": {"version": "1.1"}, "geometricError": 100.0, "root": root}
    return write_json(folder / "tileset.json", doc)
