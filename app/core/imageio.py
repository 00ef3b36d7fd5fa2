"""Still images in and out (PNG/JPEG through Pillow), with errors that name the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

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


def write_rgb(path: str | Path, rgb: np.ndarray, option: str = "--out") -> Path:
    """Write (H, W, 3) uint8 RGB to PNG/JPEG by suffix, atomically (app.core.outputs); creates the folder."""
    path = check_output(path, option, IMAGE_SUFFIXES)
    image = Image.fromarray(np.asarray(rgb, np.uint8))
    fmt = "PNG" if path.suffix.lower() == ".png" else "JPEG"
    return write_atomically(path, option, lambda f: image.save(f, format=fmt), binary=True)
