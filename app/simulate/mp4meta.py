"""Give an MP4 written by PyAV the user data a camera writes (moov/udta boxes), in place.

Used by the tests to make clips that name their camera the way DJI's do: a bare '\\xa9mdl' camera
code and a '\\xa9too' encoder string in QuickTime international text. The movie box must come after
the media data (PyAV's default), so the media's chunk offsets stay valid when it grows.
"""

from __future__ import annotations

from pathlib import Path

from app.io.mp4box import boxes


def box(kind: str, payload: bytes) -> bytes:
    """One MP4 box: 32-bit size, four-character type, payload."""
    return (8 + len(payload)).to_bytes(4, "big") + kind.encode("latin-1") + payload


def intl_text(text: str, language: int = 0x55C4) -> bytes:
    """A QuickTime international text payload: 16-bit length, 16-bit language ('und'), UTF-8."""
    raw = text.encode("utf-8")
    return len(raw).to_bytes(2, "big") + language.to_bytes(2, "big") + raw


def add_user_data(path: str | Path, items: dict[str, bytes]) -> Path:
    """Append boxes (type -> payload) to the file's moov/udta, creating udta where absent. A box
    of a type already there is replaced."""
    path = Path(path)
    data = bytearray(path.read_bytes())
    with path.open("rb") as f:
        top = list(boxes(f, 0, len(data)))
        moov = next(((a, b) for k, a, b in top if k == "moov"), None)
        if moov is None or any(k == "mdat" and a > moov[0] for k, a, _ in top):
            raise ValueError(f"{path}: the movie box must follow the media data")
        children = list(boxes(f, *moov))
    kept = b"".join(bytes(data[a - 8 : b]) for k, a, b in children if k != "udta")
    udta = next(((a, b) for k, a, b in children if k == "udta"), None)
    old = []
    if udta is not None:
        with path.open("rb") as f:
            old = [(k, bytes(data[a:b])) for k, a, b in boxes(f, *udta) if k not in items]
    user = b"".join(box(k, v) for k, v in (*old, *items.items()))
    new_moov = box("moov", kept + box("udta", user))
    path.write_bytes(bytes(data[: moov[0] - 8]) + new_moov + bytes(data[moov[1] :]))
    return path
