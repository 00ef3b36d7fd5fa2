"""Session-wide fixtures: one EGL GL context, the shared data folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
IN_CI = os.environ.get("CI") == "true"


def _unavailable(reason: str) -> None:
    if IN_CI:
        pytest.fail(f"{reason} (CI installs it, so this must not be skipped)")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def gl_ctx():
    """One standalone EGL context for the whole session (Mesa llvmpipe without a GPU)."""
    from app.render.context import RenderUnavailable, create_offscreen_context

    try:
        ctx = create_offscreen_context()
    except RenderUnavailable as exc:
        _unavailable(str(exc))
    yield ctx
    ctx.release()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data beside the checkout (BROAD trials, real device files)."""
    if not SHARED_DATA.is_dir():
        _unavailable(f"{SHARED_DATA} is absent (a user's clone has no ../shared)")
    return SHARED_DATA
