"""Writing 3D Tiles' JSON: a tileset root's ENU -> ECEF transform, matrices column-major,
box bounding volumes, the JSON file. Shared by the painted model's tileset (app.export) and the
simulator's (app.simulate.tileset)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.geodesy.enu import LocalFrame


def enu_to_ecef_matrix(frame: LocalFrame) -> np.ndarray:
    """The 4x4 that takes ENU metres at `frame`'s origin to ECEF (a tileset root's transform)."""
    m = np.eye(4)
    m[:3, :3] = frame.rotation.T
    m[:3, 3] = frame.origin_ecef
    return m


def column_major(m: np.ndarray) -> list[float]:
    return np.asarray(m, np.float64).T.ravel().tolist()


def write_json(path: Path, doc: dict) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    return path


def box_of(lo_enu: npt.ArrayLike, hi_enu: npt.ArrayLike) -> list[float]:
    """A 3D Tiles box (centre and three half-axes) of an axis-aligned box in the tile's frame."""
    lo, hi = np.asarray(lo_enu, np.float64), np.asarray(hi_enu, np.float64)
    c, half = (lo + hi) / 2, (hi - lo) / 2
    return list(c) + [half[0], 0, 0, 0, half[1], 0, 0, 0, half[2]]
