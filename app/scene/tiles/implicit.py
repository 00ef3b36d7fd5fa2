"""Implicit tiling (3D Tiles 1.1): subtree files, availability bitstreams, Morton order.

A subtree covers `subtree_levels` levels below its root tile. Tiles inside it are numbered level
by level, each level in Morton order of its local coordinates (x in the lowest bit, then y, then
z for octrees); bit i of a bitstream is bit i % 8 of byte i // 8. Child subtrees are numbered by
the Morton index of their root at level `subtree_levels` below.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from dataclasses import dataclass


class SubtreeError(ValueError):
    """A damaged subtree file (the caller names it)."""


@dataclass(frozen=True)
class Availability:
    """One availability: a constant (0 or 1) or a bitstream."""

    constant: int | None = None
    bits: bytes = b""

    def __call__(self, index: int) -> bool:
        if self.constant is not None:
            return bool(self.constant)
        byte = index >> 3
        return byte < len(self.bits) and bool(self.bits[byte] >> (index & 7) & 1)


@dataclass(frozen=True)
class Subtree:
    tiles: Availability
    contents: tuple[Availability, ...]
    children: Availability


def morton(coords: tuple[int, ...]) -> int:
    """Interleave the bits of (x, y) or (x, y, z): x lowest."""
    out, dims = 0, len(coords)
    for bit in range(32):
        for d, c in enumerate(coords):
            out |= ((c >> bit) & 1) << (bit * dims + d)
    return out


def level_offset(level: int, dims: int) -> int:
    """Index of the first tile of `level` inside a subtree: (4^L - 1) / 3 or (8^L - 1) / 7."""
    branching = 1 << dims
    return (branching**level - 1) // (branching - 1)


def read_subtree(data: bytes, fetch: Callable[[str], bytes]) -> Subtree:
    """A binary (.subtree, magic 'subt') or JSON subtree; fetch(uri) reads external buffers."""
    if data[:4] == b"subt":
        if len(data) < 24:
            raise SubtreeError("subtree header truncated")
        version, json_len, bin_len = struct.unpack_from("<IQQ", data, 4)
        if version != 1:
            raise SubtreeError(f"subtree version {version} (expected 1)")
        body = data[24 : 24 + json_len]
        binary = data[24 + json_len : 24 + json_len + bin_len]
    else:
        body, binary = data, b""
    try:
        doc = json.loads(body.decode("utf-8").rstrip(" \x00"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SubtreeError(f"subtree JSON: {exc}") from exc
    buffers = []
    for buf in doc.get("buffers", []):
        buffers.append(fetch(buf["uri"]) if "uri" in buf else binary)

    def availability(spec: dict | None, name: str) -> Availability:
        if spec is None:
            raise SubtreeError(f"subtree without {name}")
        if "constant" in spec:
            return Availability(constant=int(spec["constant"]))
        index = spec.get("bitstream", spec.get("bufferView"))
        try:
            view = doc["bufferViews"][index]
            buf = buffers[view.get("buffer", 0)]
        except (KeyError, IndexError, TypeError) as exc:
            raise SubtreeError(
                f"{name}: bitstream {index!r} not in the subtree's buffer views"
            ) from exc
        start = view.get("byteOffset", 0)
        bits = buf[start : start + view["byteLength"]]
        if len(bits) < view["byteLength"]:
            raise SubtreeError(f"{name}: bitstream runs past its buffer")
        return Availability(bits=bytes(bits))

    contents = doc.get("contentAvailability", [])
    if isinstance(contents, dict):  # the 3DTILES_implicit_tiling draft's single object
        contents = [contents]
    return Subtree(
        availability(doc.get("tileAvailability"), "tileAvailability"),
        tuple(availability(c, "contentAvailability") for c in contents),
        availability(doc.get("childSubtreeAvailability"), "childSubtreeAvailability"),
    )


def expand_template(template: str, level: int, coords: tuple[int, ...]) -> str:
    """A template URI with {level}, {x}, {y} and {z} filled in."""
    names = ("x", "y", "z")
    out = template.replace("{level}", str(level))
    for name, value in zip(names, coords, strict=False):
        out = out.replace("{" + name + "}", str(value))
    return out
