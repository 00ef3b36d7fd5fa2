"""A picture of exported footprints: the scene seen from straight above, the footprints outlined
on it and the camera track drawn, off-screen (`geofuse export footprints --preview PNG`)."""

from __future__ import annotations

import numpy as np

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.constants import VIEW_NEAR_M
from app.core.settings import OverlaySettings, ProjectionSettings
from app.export.records import FrameRecord
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.render.context import create_offscreen_context, keep_current
from app.render.offscreen import render_to_array
from app.render.renderer import FusionRenderer
from app.scene.mesh import MeshData

PREVIEW_FOV_DEG = 40.0
PREVIEW_MARGIN = 1.15  # of the footprints' extent


@keep_current()  # its own context, made and released here: the caller's stays current
def footprint_preview(
    mesh: MeshData, frame: LocalFrame, records: list[FrameRecord], size: tuple[int, int]
) -> np.ndarray:
    """(H, W, 3) uint8: a top view of the unclipped footprints (all of them when every one is
    clipped) and the track."""
    enu = lambda g: frame.geodetic_to_enu(*np.asarray(g, np.float64).T)  # noqa: E731
    rings = [enu(r.footprint) for r in records]
    track = enu([r.sensor for r in records])
    near = [ring for ring, r in zip(rings, records, strict=True) if not r.clipped] or rings
    pts = np.vstack(near + [track])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    w, h = size
    span = max(hi[0] - lo[0], (hi[1] - lo[1]) * w / h, 10.0) * PREVIEW_MARGIN
    height = span / 2 / np.tan(np.radians(PREVIEW_FOV_DEG) / 2) + hi[2]
    view = Camera.create(
        Intrinsics.from_fov(w, h, PREVIEW_FOV_DEG),
        [centre[0], centre[1], height],
        rotations.camera_quat_from_hpr(0.0, -90.0, 0.0),
        VIEW_NEAR_M,
        2 * height + 1000.0,
    )
    segments = np.vstack([np.repeat(np.vstack([ring, ring[:1]]), 2, axis=0)[1:-1] for ring in near])
    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, mesh)
    try:
        renderer.set_outlines(segments + [0.0, 0.0, 0.2])  # just above the surface they lie on
        renderer.set_trajectory(track)
        return render_to_array(
            renderer,
            view,
            ProjectionSettings(enabled=False),
            OverlaySettings(frustum=False, trajectory=True),
        )
    finally:
        renderer.release()
        ctx.release()
