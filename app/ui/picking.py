"""The model point under a point of the viewer's 3D view: what control points, measuring and
an archive's "open the clip that saw this" all start from."""

from __future__ import annotations

import numpy as np

from app.core.errors import GeofuseError

__all__ = ["model_point"]


def model_point(v, xy: tuple[float, float]) -> np.ndarray:
    """The model point (ENU m) under view point xy (in [0, 1] of the 3D view, from its top-left
    corner), by the renderer's position pass; GeofuseError where the view sees no model."""
    cam = v.window_camera
    p = None if cam is None else v.loaded.renderer.pick(cam, *xy)
    if p is None:
        raise GeofuseError("no model under that point of the view")
    return p
