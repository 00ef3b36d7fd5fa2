"""Tile content: b3dm, cmpt, glb/glTF -> triangles in ECEF (the tile's world transform applied).

Per the 3D Tiles specification (1.0 formats, kept by 1.1): a b3dm's feature table may carry
RTC_CENTER, a translation in the tile's Z-up frame applied after glTF's Y-up -> Z-up turn; legacy
b3dm headers (20 and 24 bytes, recognised by the specification's byte-length test) are read too;
a cmpt holds inner tiles of any format, read recursively. Instanced (i3dm) and point-cloud (pnts)
content and anything unknown are skipped and counted, never fatal. GLB is told by its magic,
JSON glTF by its first byte, whatever the file is called.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable

import numpy as np

from app.scene.tiles.gltf import GltfError, RawPrimitive, Skipped, read_gltf

LEGACY_TEST = 570425344  # 0x22000000: a byte length this large is the JSON start of a legacy header


class ContentError(ValueError):
    """Tile content that is damaged (the caller names the file)."""


def _feature_json(data: bytes, start: int, length: int) -> dict:
    if length == 0:
        return {}
    try:
        return json.loads(data[start : start + length].decode("utf-8").rstrip(" \x00"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ContentError(f"feature table JSON: {exc}") from exc


def _b3dm(
    data: bytes, fetch: Callable[[str], bytes], skipped: Skipped, transform: np.ndarray
) -> list[RawPrimitive]:
    if len(data) < 20:
        raise ContentError("b3dm header truncated")
    ft_json, ft_bin, bt_json, bt_bin = (
        struct.unpack_from("<4I", data, 12) if len(data) >= 28 else (0, 0, 0, 0)
    )
    if bt_json >= LEGACY_TEST:  # legacy: [batchLength, batchTableByteLength], 20-byte header
        header, ft_json, ft_bin, bt_json, bt_bin = (
            20,
            0,
            0,
            struct.unpack_from("<I", data, 16)[0],
            0,
        )
    elif (
        bt_bin >= LEGACY_TEST
    ):  # legacy: [batchTableJsonByteLength, batchTableBinaryByteLength, batchLength], 24 bytes
        header, ft_json, ft_bin = 24, 0, 0
        bt_json, bt_bin = struct.unpack_from("<2I", data, 12)
    else:
        header = 28
    table = _feature_json(data, header, ft_json)
    rtc = np.eye(4)
    center = table.get("RTC_CENTER")
    if isinstance(center, dict):  # a reference into the binary body
        offset = header + ft_json + int(center.get("byteOffset", 0))
        center = struct.unpack_from("<3f", data, offset)
    if center is not None:
        if len(center) != 3 or not np.all(np.isfinite(center)):
            raise ContentError(f"RTC_CENTER must be three finite numbers, got {center!r}")
        rtc[:3, 3] = center
    glb = data[header + ft_json + ft_bin + bt_json + bt_bin :]
    return read_gltf(glb, fetch, skipped, transform @ rtc)


def _cmpt(
    data: bytes, fetch: Callable[[str], bytes], skipped: Skipped, transform: np.ndarray, depth: int
) -> list[RawPrimitive]:
    if len(data) < 16:
        raise ContentError("cmpt header truncated")
    count = struct.unpack_from("<I", data, 12)[0]
    out, offset = [], 16
    for i in range(count):
        if offset + 12 > len(data):
            raise ContentError(f"cmpt inner tile {i} of {count} runs past the end")
        length = struct.unpack_from("<I", data, offset + 8)[0]
        if length < 12 or offset + length > len(data):
            raise ContentError(f"cmpt inner tile {i}: byte length {length} does not fit")
        out += read_content(data[offset : offset + length], fetch, skipped, transform, depth + 1)
        offset += length
    return out


def read_content(
    data: bytes,
    fetch: Callable[[str], bytes],
    skipped: Skipped,
    transform: np.ndarray,
    depth: int = 0,
) -> list[RawPrimitive]:
    """Triangles (ECEF when `transform` is the tile's world transform) of one tile's content.

    fetch(uri) reads files the content refers to (relative to the content). Raises ContentError
    or GltfError on damaged content; unknown or undrawable formats only count in `skipped`."""
    if depth > 8:
        raise ContentError("cmpt nested more than 8 deep")
    magic = data[:4]
    try:
        if magic == b"b3dm":
            return _b3dm(data, fetch, skipped, transform)
        if magic == b"cmpt":
            return _cmpt(data, fetch, skipped, transform, depth)
        if magic == b"glTF" or data[:1] == b"{":
            return read_gltf(data, fetch, skipped, transform)
    except struct.error as exc:
        raise ContentError(f"truncated {magic!r} content: {exc}") from exc
    kind = {b"i3dm": "instanced models (i3dm)", b"pnts": "point clouds (pnts)"}.get(
        magic, "contents of unknown format"
    )
    skipped.add(kind)
    return []


__all__ = ["ContentError", "GltfError", "read_content"]
