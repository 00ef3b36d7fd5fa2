"""The GNSS fixes drawn in the 3D view (issue 52): the receiver's own track beside the track the
scene made of it, its lying stretch in the timeline's red, never a line across an outage."""

from __future__ import annotations

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera, look_at_quat
from app.core.settings import OverlaySettings, ProjectionSettings
from app.render.overlays import FIX_REJECTED_COLOR, FIX_USED_COLOR
from app.scene.ground_plane import ground_plane
from app.ui.gnss import segments


def test_segments_split_by_verdict_and_never_cross_an_outage():
    p = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0], [5, 0, np.nan]], float)
    rejected = np.array([False, False, True, False, False, False])
    joined = np.array([True, True, True, False, True])  # 3 -> 4: an outage
    lines = segments(p, rejected, joined)
    # 0-1 used; 1-2 and 2-3 touch the rejected fix; 3-4 spans the outage; 4-5 has no position
    np.testing.assert_array_equal(lines.used, [[0, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(lines.rejected, [[1, 0, 0], [2, 0, 0], [2, 0, 0], [3, 0, 0]])
    empty = segments(p[:1], rejected[:1], np.zeros(0, bool))
    assert empty.used.shape == (0, 3) and empty.rejected.shape == (0, 3)


@pytest.mark.gl
@pytest.mark.parametrize("deferred", [True, False])
def test_the_fixes_are_drawn_where_the_view_projects_them_in_their_colours(gl_ctx, deferred):
    """Straight down from 100 m on a grey ground: a used segment 20 m north of the centre is
    white on the pixels the view's pinhole puts it, a rejected one 20 m south is red; with the
    lines switched off neither is drawn."""
    from app.render.offscreen import OffscreenTarget
    from app.render.renderer import FusionRenderer

    w, h = 200, 150
    view = Camera.create(
        Intrinsics.from_fov(w, h, 60.0),
        [0.0, 0.0, 100.0],
        look_at_quat([0.0, 0.0, 100.0], [0.0, 0.0, 0.0], (0.0, 1.0, 0.0)),
        0.5,
        500.0,
    )
    used = np.array([[-40.0, 20.0, 1.0], [40.0, 20.0, 1.0]])
    lying = np.array([[-40.0, -20.0, 1.0], [40.0, -20.0, 1.0]])
    r = FusionRenderer(gl_ctx, ground_plane(np.zeros(2), 0.0, 300.0), deferred=deferred)
    target = OffscreenTarget(gl_ctx, w, h)
    try:
        r.set_fixes(used, lying)
        lines = OverlaySettings(frustum=False, trajectory=True)
        r.draw(view, target.fbo, ProjectionSettings(), lines)
        on = target.read().astype(int)
        r.draw(
            view, target.fbo, ProjectionSettings(), OverlaySettings(frustum=False, trajectory=False)
        )
        off = target.read().astype(int)
    finally:
        target.release()
        r.release()

    def near(image, point, colour):
        """Whether a pixel within 1 px of where the view projects `point` has `colour`."""
        uv, _ = view.project([point])
        c, row = (int(x) for x in np.floor(uv[0]))
        patch = image[row - 1 : row + 2, c - 1 : c + 2, :3].reshape(-1, 3)
        want = np.round(np.asarray(colour[:3]) * 255)
        return bool(np.any(np.abs(patch - want).max(axis=1) <= 3))

    for x in (-30.0, 0.0, 30.0):
        assert near(on, [x, 20.0, 1.0], FIX_USED_COLOR)
        assert near(on, [x, -20.0, 1.0], FIX_REJECTED_COLOR)
        assert not near(on, [x, 20.0, 1.0], FIX_REJECTED_COLOR)
        assert not near(off, [x, 20.0, 1.0], FIX_USED_COLOR)
        assert not near(off, [x, -20.0, 1.0], FIX_REJECTED_COLOR)
    r.set_fixes(None)
    assert r.fixes is None
