"""Still images in and out (PNG/JPEG through Pillow), with errors that name the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin, UnidentifiedImageError

from app.core.errors import DataFormatError
from app.core.outputs import IMAGE_SUFFIXES, check_output, write_atomically


def read_rgb(path: str | Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB, row 0 = top."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "image file does not exist")
    try:
        with Image.open(path) as img:
            return np.asarray(img.convert("RGB"), np.uint8).copy()
    except (UnidentifiedImageError, OSError) as exc:
        raise DataFormatError(path, f"cannot read image ({exc}); expected PNG or JPEG") from exc


EXIF_COPYRIGHT = 0x8298  # the EXIF/TIFF Copyright tag


def write_rgb(path: str | Path, rgb: np.ndarray, option: str = "--out", credit: str = "") -> Path:
    """Write (H, W, 3) uint8 RGB to PNG/JPEG by suffix, atomically (app.core.outputs); creates the folder.
    credit: what the picture's imagery must be credited with ('' none), in a PNG's Copyright
    text chunk or a JPEG's EXIF Copyright tag."""
    path = check_output(path, option, IMAGE_SUFFIXES)
    image = Image.fromarray(np.asarray(rgb, np.uint8))
    fmt = "PNG" if path.suffix.lower() == ".png" else "JPEG"
    extra = {}
    if credit and fmt == "PNG":
        extra["pnginfo"] = PngImagePlugin.PngInfo()
        extra["pnginfo"].add_itxt("Copyright", credit)
    elif credit:
        exif = Image.Exif()
        exif[EXIF_COPYRIGHT] = credit
        extra["exif"] = exif
    return write_atomically(path, option, lambda f: image.save(f, format=fmt, **extra), binary=True)
