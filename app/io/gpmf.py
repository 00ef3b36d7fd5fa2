"""GPMF (GoPro Metadata Format) decoding, written from GoPro's published format description
(github.com/gopro/gpmf-parser, README: "GPMF Deeper Dive").

A payload is a sequence of KLV 3-tuples, big-endian and 32-bit aligned: a FourCC key; a type
character; a structure size (bytes per sample, 8 bits); a repeat count (samples, 16 bits); then
size x repeat bytes of data, padded to a multiple of 4. Type 0 (null) nests more KLVs (DEVC, STRM).
Inside a nest, SCAL, TYPE, UNIT, SIUN, ORIN, TIMO... modify the data KLV that follows them.

Why our own decoder rather than a PyPI reader: the format is small and fully specified, the
maintained readers on PyPI either shell out to ffmpeg/exiftool or drop the structure this project
needs (TYPE-described records, ORIN, TIMO, per-payload MP4 time spans); owning ~200 lines keeps
every trap testable on the shared real files.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from app.core.errors import DataFormatError

# Type character -> numpy big-endian dtype (and a divisor for the fixed-point Q types).
NUMERIC = {
    "b": (">i1", 1.0),
    "B": (">u1", 1.0),
    "s": (">i2", 1.0),
    "S": (">u2", 1.0),
    "l": (">i4", 1.0),
    "L": (">u4", 1.0),
    "j": (">i8", 1.0),
    "J": (">u8", 1.0),
    "f": (">f4", 1.0),
    "d": (">f8", 1.0),
    "q": (">i4", 65536.0),
    "Q": (">i8", 4294967296.0),
}
TEXT = {"c", "U", "F", "G"}
NESTED = "\x00"
COMPLEX = "?"
MODIFIERS = {
    "SCAL",
    "TYPE",
    "UNIT",
    "SIUN",
    "ORIN",
    "ORIO",
    "MTRX",
    "TIMO",
    "TSMP",
    "STMP",
    "STNM",
    "RMRK",
    "EMPT",
    "TMPC",
    "GPSF",
    "GPSP",
    "GPSU",
    "GPSA",
}


@dataclass
class KLV:
    """One decoded KLV: `value` is an (repeat, n) float array for numeric and complex data, a
    string (or list of strings) for text, a list of KLVs when nested."""

    key: str
    type: str
    size: int
    repeat: int
    value: object
    offset: int


@dataclass
class Counts:
    """Keys skipped because their data could not be decoded (unknown type, bad TYPE...)."""

    skipped: dict[str, int] = field(default_factory=dict)

    def skip(self, key: str) -> None:
        self.skipped[key] = self.skipped.get(key, 0) + 1


def _complex_dtype(spec: str) -> list[str]:
    """TYPE string ("ffffBBBB", "f[8]L") -> one type character per field."""
    out: list[str] = []
    for ch, n in re.findall(r"(.)(?:\[(\d+)\])?", spec):
        out.extend([ch] * (int(n) if n else 1))
    return out


def _decode_complex(data: bytes, size: int, repeat: int, spec: str) -> np.ndarray:
    fields = _complex_dtype(spec)
    if any(c not in NUMERIC for c in fields):
        raise ValueError(f"TYPE {spec!r} has non-numeric fields")
    dtype = np.dtype([(f"f{i}", NUMERIC[c][0]) for i, c in enumerate(fields)])
    if dtype.itemsize != size:
        raise ValueError(f"TYPE {spec!r} is {dtype.itemsize} bytes, samples are {size}")
    rec = np.frombuffer(data, dtype=dtype, count=repeat)
    cols = [rec[f"f{i}"].astype(np.float64) / NUMERIC[c][1] for i, c in enumerate(fields)]
    return np.column_stack(cols) if cols else np.zeros((repeat, 0))


def _decode_value(type_: str, size: int, repeat: int, data: bytes, type_spec: str | None) -> object:
    if type_ in NUMERIC:
        dt, div = NUMERIC[type_]
        width = np.dtype(dt).itemsize
        if size % width:
            raise ValueError(f"sample size {size} is not a multiple of {width}")
        arr = np.frombuffer(data, dtype=dt, count=repeat * (size // width)).astype(np.float64) / div
        return arr.reshape(repeat, size // width)
    if type_ == "c":
        text = data[: size * repeat].decode("latin-1")
        if repeat > 1 and size > 1:
            return [text[i * size : (i + 1) * size].rstrip("\x00 ") for i in range(repeat)]
        return text.rstrip("\x00")
    if type_ == "U":
        return data[:16].decode("latin-1")
    if type_ == "F":
        return [data[i : i + 4].decode("latin-1") for i in range(0, size * repeat, 4)]
    if type_ == "G":
        return data[: size * repeat].hex()
    if type_ == COMPLEX:
        if type_spec is None:
            raise ValueError("complex data without a preceding TYPE")
        return _decode_complex(data, size, repeat, type_spec)
    raise ValueError(f"unknown type character {type_!r}")


def parse(
    payload: bytes, path: str = "<payload>", counts: Counts | None = None, _base: int = 0
) -> list[KLV]:
    """Decode one GPMF payload into nested KLVs. Truncated data is an error naming the byte offset;
    undecodable data keys are skipped and counted, never fatal."""
    counts = counts if counts is not None else Counts()
    out: list[KLV] = []
    pos = 0
    type_spec: str | None = None
    while pos + 8 <= len(payload):
        key = payload[pos : pos + 4].decode("latin-1")
        type_ = chr(payload[pos + 4])
        size = payload[pos + 5]
        repeat = int.from_bytes(payload[pos + 6 : pos + 8], "big")
        length = size * repeat
        padded = (length + 3) & ~3
        if key == "\x00\x00\x00\x00":
            break  # padding at the end of a payload
        if pos + 8 + length > len(payload):
            raise DataFormatError(
                path,
                f"GPMF payload cut short: {key!r} at byte {_base + pos} needs {length} bytes, {len(payload) - pos - 8} remain",
                field=key,
            )
        data = payload[pos + 8 : pos + 8 + length]
        if type_ == NESTED:
            value: object = parse(data, path, counts, _base + pos + 8)
        else:
            try:
                value = _decode_value(type_, size, repeat, data, type_spec)
            except ValueError:
                counts.skip(key)
                value = None
        if key == "TYPE" and isinstance(value, str):
            type_spec = value
        out.append(KLV(key, type_, size, repeat, value, _base + pos))
        pos += 8 + padded
    return out


@dataclass
class StreamChunk:
    """The samples of one data key in one payload, with the modifiers that preceded it."""

    key: str
    samples: np.ndarray  # (n, k), scaled by SCAL
    t0: float  # the payload's MP4 time span, seconds
    t1: float
    modifiers: dict[str, object]
    device: str


def _scaled(samples: np.ndarray, scal: object) -> np.ndarray:
    if scal is None:
        return samples
    s = np.asarray(scal, np.float64).ravel()
    s = np.where(s == 0, 1.0, s)
    if len(s) == 1:
        return samples / s[0]
    if len(s) == samples.shape[1]:
        return samples / s[None, :]
    return samples


def chunks(payload: list[KLV], t0: float, t1: float) -> list[StreamChunk]:
    """The data of every STRM in every DEVC of a decoded payload, scaled, with its modifiers."""
    out: list[StreamChunk] = []
    for devc in payload:
        if devc.key != "DEVC" or not isinstance(devc.value, list):
            continue
        name = next(
            (k.value for k in devc.value if k.key == "DVNM" and isinstance(k.value, str)), ""
        )
        for strm in devc.value:
            if strm.key != "STRM" or not isinstance(strm.value, list):
                continue
            mods: dict[str, object] = {}
            for k in strm.value:
                if k.key in MODIFIERS:
                    mods[k.key] = k.value
                    if k.key == "SCAL" and isinstance(k.value, np.ndarray):
                        mods["SCAL"] = k.value
                elif isinstance(k.value, np.ndarray):
                    samples = _scaled(k.value, mods.get("SCAL"))
                    out.append(StreamChunk(k.key, samples, t0, t1, dict(mods), name))
    return out
