"""glTF 2.0 content of 3D Tiles (GLB or JSON glTF) -> triangles in the tile's frame. No GL here.

Read per the glTF 2.0 specification: the default scene's node hierarchy (matrix or TRS),
triangle primitives (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN), accessors with byte strides and
normalized integer components (so KHR_mesh_quantization works), base colour factor, COLOR_0 and
the base colour texture (PNG/JPEG/WebP), KHR_draco_mesh_compression (through DracoPy) and the
CESIUM_RTC centre of older content. What cannot be drawn is counted in `Skipped`, never fatal:
point and line primitives, KTX2/Basis textures (KHR_texture_basisu: drawn untextured),
meshopt-compressed content and sparse accessors.

Positions come out in the tile's Z-up frame: node transform, then glTF's Y-up -> Z-up turn
(3D Tiles specification, "glTF transforms": x -> x, y -> z, z -> -y), then the CESIUM_RTC centre.
"""

from __future__ import annotations

import base64
import io
import json
import struct
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import DracoPy
import numpy as np
from PIL import Image

GLB_MAGIC = b"glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
COMPONENT = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
NORMALIZER = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0, 5125: 4294967295.0}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
Y_UP_TO_Z_UP = np.array(
    [[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
)  # (x, y, z) -> (x, -z, y)
# required extensions we can honour (KTX2/Basis textures: the mesh is drawn untextured and counted)
SUPPORTED_REQUIRED = {
    "KHR_texture_basisu",
    "KHR_draco_mesh_compression",
    "KHR_mesh_quantization",
    "KHR_materials_unlit",
    "CESIUM_RTC",
    "KHR_texture_transform",
    "EXT_texture_webp",
}
WHITE = (1.0, 1.0, 1.0, 1.0)


class GltfError(ValueError):
    """Content that is not valid glTF (the caller names the file)."""


@dataclass
class Skipped:
    """What readers left out, by kind (e.g. 'point primitives', 'KTX2 textures'), as counts.
    Worker threads add to it while the render thread reads `snapshot()`."""

    counts: Counter = field(default_factory=Counter)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, kind: str, n: int = 1) -> None:
        with self._lock:
            self.counts[kind] += n

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)


@dataclass
class RawPrimitive:
    """Triangles of one material in the tile's Z-up frame (float64 until placed).

    positions (N, 3); indices (M, 3) uint32; colors (N, 4) float32; uvs (N, 2) float32 with
    v = 0 at the image's bottom, or None; texture (H, W, 4) uint8 bottom row first, or None."""

    positions: np.ndarray
    indices: np.ndarray
    colors: np.ndarray
    uvs: np.ndarray | None = None
    texture: np.ndarray | None = None


def split_glb(data: bytes) -> tuple[dict, bytes]:
    """(JSON document, BIN chunk) of a GLB; raises GltfError on a malformed container."""
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise GltfError("not a GLB (magic 'glTF' expected)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise GltfError(f"GLB version {version} (expected 2)")
    if length > len(data):
        raise GltfError(f"GLB truncated: header says {length} bytes, {len(data)} present")
    doc, binary, offset = None, b"", 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8 : offset + 8 + size]
        if len(chunk) != size:
            raise GltfError("GLB chunk runs past the end of the data")
        if kind == CHUNK_JSON:
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == CHUNK_BIN and not binary:
            binary = chunk
        offset += 8 + size + (-size % 4)
    if doc is None:
        raise GltfError("GLB without a JSON chunk")
    return doc, binary


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major in glTF
    m = np.eye(4)
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m[:3, :3] = r * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), np.float64)
    m[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return m


class _Document:
    """One glTF document with its buffers resolved."""

    def __init__(
        self, doc: dict, binary: bytes, fetch: Callable[[str], bytes], skipped: Skipped
    ) -> None:
        self.doc = doc
        self.skipped = skipped
        self.buffers: list[bytes] = []
        for i, buf in enumerate(doc.get("buffers", [])):
            uri = buf.get("uri")
            if uri is None:
                self.buffers.append(binary)
            elif uri.startswith("data:"):
                self.buffers.append(base64.b64decode(uri.split(",", 1)[1]))
            else:
                self.buffers.append(fetch(uri))
            if len(self.buffers[-1]) < buf.get("byteLength", 0):
                raise GltfError(
                    f"buffer {i} holds {len(self.buffers[-1])} bytes, byteLength says {buf['byteLength']}"
                )
        self.fetch = fetch
        self._images: dict[int, np.ndarray | None] = {}

    def view_bytes(self, index: int) -> bytes:
        view = self.doc["bufferViews"][index]
        buf = self.buffers[view["buffer"]]
        start = view.get("byteOffset", 0)
        return buf[start : start + view["byteLength"]]

    def accessor(self, index: int) -> np.ndarray:
        """The accessor as float64 (normalized ints scaled) or its integer type, shape (count, width)."""
        acc = self.doc["accessors"][index]
        dtype = np.dtype(COMPONENT[acc["componentType"]]).newbyteorder("<")
        width = WIDTH[acc["type"]]
        count = acc["count"]
        if "sparse" in acc:
            self.skipped.add("sparse accessors")
        if "bufferView" not in acc:
            out = np.zeros((count, width), dtype)
        else:
            view = self.doc["bufferViews"][acc["bufferView"]]
            buf = self.buffers[view["buffer"]]
            start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            item = dtype.itemsize * width
            stride = view.get("byteStride") or item
            need = start + stride * (count - 1) + item if count else start
            if need > len(buf):
                raise GltfError(
                    f"accessor {index} reads past its buffer ({need} > {len(buf)} bytes)"
                )
            out = np.ndarray(
                (count, width), dtype, buffer=buf, offset=start, strides=(stride, dtype.itemsize)
            ).copy()
        if acc.get("normalized") and acc["componentType"] in NORMALIZER:
            return np.maximum(out.astype(np.float64) / NORMALIZER[acc["componentType"]], -1.0)
        return out

    def image(self, texture_index: int) -> np.ndarray | None:
        """The base colour texture as uint8 RGBA, bottom row first; None when it cannot be decoded."""
        if texture_index in self._images:
            return self._images[texture_index]

        tex = self.doc["textures"][texture_index]
        ext = tex.get("extensions", {})
        source = tex.get("source")
        if "EXT_texture_webp" in ext:
            source = ext["EXT_texture_webp"].get("source", source)
        result = None
        if source is None:
            self.skipped.add(
                "KTX2/Basis textures (drawn untextured)"
                if "KHR_texture_basisu" in ext
                else "textures without a source"
            )
        else:
            img = self.doc["images"][source]
            try:
                if "bufferView" in img:
                    raw = self.view_bytes(img["bufferView"])
                elif img.get("uri", "").startswith("data:"):
                    raw = base64.b64decode(img["uri"].split(",", 1)[1])
                else:
                    raw = self.fetch(img["uri"])
                result = np.asarray(Image.open(io.BytesIO(raw)).convert("RGBA"), np.uint8)[
                    ::-1
                ].copy()
            except Exception:  # an image PIL cannot decode (KTX2 named as a plain image, damage)
                self.skipped.add("undecodable textures (drawn untextured)")
        self._images[texture_index] = result
        return result


def _draco(doc: _Document, ext: dict) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:

    mesh = DracoPy.decode(doc.view_bytes(ext["bufferView"]))
    attributes = {}
    for name, uid in ext.get("attributes", {}).items():
        attr = mesh.get_attribute_by_unique_id(uid)
        if attr is not None:
            attributes[name] = np.asarray(attr["data"]).reshape(len(mesh.points), -1)
    positions = attributes.get("POSITION", np.asarray(mesh.points))
    return (
        np.asarray(positions, np.float64),
        np.asarray(mesh.faces, np.uint32).reshape(-1, 3),
        attributes,
    )


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    i = indices.reshape(-1).astype(np.uint32)
    if mode == 4:
        return i[: len(i) // 3 * 3].reshape(-1, 3)
    if mode == 5:  # strip: alternate winding
        n = max(len(i) - 2, 0)
        k = np.arange(n)
        even = k % 2 == 0
        tri = np.stack(
            [i[k], np.where(even, i[k + 1], i[k + 2]), np.where(even, i[k + 2], i[k + 1])], axis=1
        )
        return tri
    n = max(len(i) - 2, 0)  # fan
    k = np.arange(n)
    return np.stack([np.full(n, i[0]), i[k + 1], i[k + 2]], axis=1).astype(np.uint32)


def _primitive(doc: _Document, prim: dict, matrix: np.ndarray) -> RawPrimitive | None:
    mode = prim.get("mode", 4)
    if mode not in (4, 5, 6):
        doc.skipped.add("point and line primitives")
        return None
    ext = prim.get("extensions", {})
    if "KHR_draco_mesh_compression" in ext:
        positions, tri, attrs = _draco(doc, ext["KHR_draco_mesh_compression"])
        uv_source = attrs.get("TEXCOORD_0")
        color_source = attrs.get("COLOR_0")
    else:
        attrs_idx = prim.get("attributes", {})
        if "POSITION" not in attrs_idx:
            doc.skipped.add("primitives without positions")
            return None
        positions = doc.accessor(attrs_idx["POSITION"]).astype(np.float64)[:, :3]
        ids = (
            doc.accessor(prim["indices"])
            if "indices" in prim
            else np.arange(len(positions), dtype=np.uint32)
        )
        tri = _triangles(ids, mode)
        uv_source = doc.accessor(attrs_idx["TEXCOORD_0"]) if "TEXCOORD_0" in attrs_idx else None
        color_source = doc.accessor(attrs_idx["COLOR_0"]) if "COLOR_0" in attrs_idx else None
    n = len(positions)
    if len(tri) and int(tri.max()) >= n:
        raise GltfError(
            f"an index ({int(tri.max())}) points past the {n} vertices of its primitive"
        )
    material = doc.doc.get("materials", [])[prim["material"]] if "material" in prim else {}
    pbr = material.get("pbrMetallicRoughness", {})
    colors = np.tile(np.asarray(pbr.get("baseColorFactor", WHITE), np.float32), (n, 1))
    if color_source is not None and len(color_source) == n:
        c = np.asarray(color_source, np.float32)
        if c.shape[1] == 3:
            c = np.concatenate([c, np.ones((n, 1), np.float32)], axis=1)
        colors *= c[:, :4]
    texture = uvs = None
    if "baseColorTexture" in pbr and uv_source is not None and len(uv_source) == n:
        texture = doc.image(pbr["baseColorTexture"]["index"])
        if texture is not None:
            uvs = np.stack([uv_source[:, 0], 1.0 - uv_source[:, 1]], axis=1).astype(
                np.float32
            )  # glTF v runs down
    if (
        texture is None
        and "baseColorTexture" not in pbr
        and "baseColorFactor" not in pbr
        and color_source is None
    ):
        colors[:] = (0.75, 0.75, 0.72, 1.0)  # no material: the scene's default grey
    placed = positions @ matrix[:3, :3].T + matrix[:3, 3]
    return RawPrimitive(placed, tri.astype(np.uint32), colors, uvs, texture)


def read_gltf(
    data: bytes,
    fetch: Callable[[str], bytes],
    skipped: Skipped,
    transform: np.ndarray | None = None,
) -> list[RawPrimitive]:
    """Triangles of a GLB or JSON glTF, in the tile's Z-up frame times `transform` (4x4, default
    identity), per the module docstring. fetch(uri) returns the bytes of an external buffer or
    image (relative to the content). Raises GltfError on a malformed document."""
    if data[:4] == GLB_MAGIC:
        doc_json, binary = split_glb(data)
    else:
        try:
            doc_json, binary = json.loads(data.decode("utf-8")), b""
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise GltfError(f"neither GLB nor glTF JSON ({exc})") from exc
    unsupported = set(doc_json.get("extensionsRequired", [])) - SUPPORTED_REQUIRED
    if unsupported:
        skipped.add(f"content needing {', '.join(sorted(unsupported))}")
        return []
    try:
        doc = _Document(doc_json, binary, fetch, skipped)
        rtc = np.eye(4)
        center = doc_json.get("extensions", {}).get("CESIUM_RTC", {}).get("center")
        if center is not None:
            rtc[:3, 3] = center
        base = (np.eye(4) if transform is None else transform) @ rtc @ Y_UP_TO_Z_UP
        nodes = doc_json.get("nodes", [])
        scenes = doc_json.get("scenes")
        if scenes:
            roots = scenes[doc_json.get("scene", 0)].get("nodes", [])
        else:
            children = {c for n in nodes for c in n.get("children", [])}
            roots = [i for i in range(len(nodes)) if i not in children]
        out: list[RawPrimitive] = []
        stack = [(i, base) for i in roots]
        seen = 0
        while stack:
            index, parent = stack.pop()
            seen += 1
            if seen > 100_000:
                raise GltfError("node hierarchy has a cycle")
            node = nodes[index]
            m = parent @ _node_matrix(node)
            if "mesh" in node:
                for prim in doc_json["meshes"][node["mesh"]].get("primitives", []):
                    p = _primitive(doc, prim, m)
                    if p is not None and len(p.indices):
                        out.append(p)
            stack.extend((c, m) for c in node.get("children", []))
        return out
    except (KeyError, IndexError, TypeError, struct.error) as exc:
        raise GltfError(f"malformed glTF: {type(exc).__name__} {exc}") from exc
