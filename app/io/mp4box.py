"""MP4/QuickTime boxes read by seeking: box headers and the few small boxes asked for, never the
media data (a 4 GB clip costs a handful of reads). Pure Python; PyAV does the media itself.

- `boxes(f, start, end)`: (type, payload start, payload end) of the boxes in a byte range of an
  open file; stops quietly at a box that runs past the range (a truncated file).
- `user_data(path)`: the children of moov/udta and of moov/udta/meta/ilst, by type, as bytes.
- `udta_text(value)`: the text of a user-data string in any of the layouts cameras write: a
  QuickTime international text ('\\xa9' types: 16-bit length, 16-bit language, text), an ilst
  item (a 'data' box: type, locale, text), or a bare string (DJI's '\\xa9mdl').
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

MAX_UDTA_BYTES = 16 << 20  # a user-data box larger than this is not metadata worth reading


def boxes(f: BinaryIO, start: int, end: int) -> Iterator[tuple[str, int, int]]:
    """(type, payload start, payload end) of the boxes in bytes [start, end) of an open file."""
    pos = start
    while pos + 8 <= end:
        f.seek(pos)
        head = f.read(16)
        if len(head) < 8:
            return
        size = int.from_bytes(head[:4], "big")
        kind = head[4:8].decode("latin-1")
        header = 8
        if size == 1:
            if len(head) < 16:
                return
            size = int.from_bytes(head[8:16], "big")
            header = 16
        elif size == 0:
            size = end - pos
        if size < header or pos + size > end:
            return
        yield kind, pos + header, pos + size
        pos += size


def _child(f: BinaryIO, start: int, end: int, kind: str) -> tuple[int, int] | None:
    return next(((a, b) for k, a, b in boxes(f, start, end) if k == kind), None)


def user_data(path: str | Path) -> dict[str, bytes]:
    """The payloads of the boxes in moov/udta (and in moov/udta/meta/ilst, where a same-named
    udta box wins), by four-character type ('\\xa9mdl', 'GPMF', ...). Empty when the file has no
    movie box (a truncated recording) or no user data."""
    path = Path(path)
    out: dict[str, bytes] = {}
    with path.open("rb") as f:
        size = f.seek(0, 2)
        moov = _child(f, 0, size, "moov")
        udta = _child(f, *moov, "udta") if moov else None
        if udta is None:
            return out
        for kind, a, b in boxes(f, *udta):
            if b - a <= MAX_UDTA_BYTES and kind not in out:
                f.seek(a)
                out[kind] = f.read(b - a)
        meta = _child(f, *udta, "meta")
        ilst = _child(f, meta[0] + 4, meta[1], "ilst") if meta else None  # meta is a full box
        if ilst:
            for kind, a, b in boxes(f, *ilst):
                if b - a <= MAX_UDTA_BYTES:
                    f.seek(a)
                    out.setdefault(kind, f.read(b - a))
    return out


def udta_text(value: bytes) -> str:
    """The text of a user-data string box's payload (see the module note), stripped of padding."""
    if len(value) >= 16 and value[4:8] == b"data":  # an ilst item
        n = int.from_bytes(value[:4], "big")
        value = value[16 : max(16, min(n, len(value)))]
    elif (
        len(value) >= 4
        and value[0] < 0x20
        and 0 < int.from_bytes(value[:2], "big") <= len(value) - 4
    ):
        value = value[
            4 : 4 + int.from_bytes(value[:2], "big")
        ]  # international text (the first language)
    return value.split(b"\0", 1)[0].decode("utf-8", "replace").strip()
