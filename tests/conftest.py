"""Session-wide fixtures: one EGL GL context, the shared data folder."""

from __future__ import annotations

import os
import select
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
IN_CI = os.environ.get("CI") == "true"
# No test drapes a clip on a world from the user's settings (app.world): none reaches the
# internet; tests of worlds name their own (tests/test_world.py). Subprocesses inherit it.
os.environ["GEOFUSE_WORLD"] = "none"


def _unavailable(reason: str) -> None:
    if IN_CI:
        pytest.fail(f"{reason} (CI installs it, so this must not be skipped)")
    pytest.skip(reason)


_SHARED_GL: list = []  # what current_context() said once gl_ctx was made


@pytest.fixture(scope="session")
def gl_ctx():
    """One standalone EGL context for the whole session (Mesa llvmpipe without a GPU)."""
    from app.render.context import RenderUnavailable, create_offscreen_context, current_context

    try:
        ctx = create_offscreen_context()
    except RenderUnavailable as exc:
        _unavailable(str(exc))
    _SHARED_GL.append(current_context())
    yield ctx
    _SHARED_GL.clear()
    ctx.release()


@pytest.fixture(autouse=True)
def _shared_gl_context_stays_current():
    """After every test the session's shared context is still current on the main thread: code
    that makes a context of its own and leaves the caller's not current sends the next GL test's
    calls nowhere (clears skipped, reads of uninitialised memory), a failure far from its cause."""
    yield
    if _SHARED_GL:
        from app.render.context import current_context, make_current

        left = current_context()
        make_current(_SHARED_GL[0])  # one offender, one failure: the next tests start sound
        assert left == _SHARED_GL[0], (
            "this test left the shared GL context not current (use app.render.context.keep_current "
            "around a context of one's own)"
        )


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data beside the checkout (BROAD trials, real device files)."""
    if not SHARED_DATA.is_dir():
        _unavailable(f"{SHARED_DATA} is absent (a user's clone has no ../shared)")
    return SHARED_DATA


XVFB_START_S = 30.0  # how long Xvfb may take to say its display number before we give up


@pytest.fixture(scope="session")
def display():
    """An X display: the existing one, or a private Xvfb started for these tests. Xvfb picks a
    free display itself and writes its number (-displayfd); one that exits or says nothing
    within XVFB_START_S fails the tests that need it in CI and skips them elsewhere, with what
    Xvfb printed, instead of handing out a display no window can open on."""
    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"]
        return
    if shutil.which("Xvfb") is None:
        _unavailable("Xvfb is not installed (apt-get install xvfb)")
    read_end, write_end = os.pipe()
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=log,
        pass_fds=(write_end,),
    )
    os.close(write_end)
    number = b""
    while b"\n" not in number:  # every read waits at most XVFB_START_S
        ready, _, _ = select.select([read_end], [], [], XVFB_START_S)
        chunk = os.read(read_end, 16) if ready else b""
        if not chunk:
            break
        number += chunk
    os.close(read_end)
    if not number.strip().isdigit():
        proc.kill()
        proc.wait()
        log.seek(0)
        said = log.read().decode(errors="replace").strip().splitlines()[-3:]
        log.close()
        _unavailable(
            f"Xvfb gave no display within {XVFB_START_S:g} s: {' / '.join(said) or 'it said nothing'}"
        )
    yield f":{int(number)}"
    proc.terminate()
    proc.wait(timeout=5)
    log.close()


def run_viewer(
    display: str,
    *args: str,
    timeout: float = 300,
    config_home: Path | None = None,
    cwd: Path | None = None,
):
    """`geofuse view ARGS` as a subprocess on the given X display, remembering its panel layout
    in `config_home` (default: a fresh folder, removed once the viewer has exited, so that no
    earlier run's layout is used and none is left behind), run in `cwd` (default: the
    repository)."""
    if config_home is None:
        with tempfile.TemporaryDirectory(
            prefix="geofuse-config-", ignore_cleanup_errors=True
        ) as fresh:
            return run_viewer(display, *args, timeout=timeout, config_home=Path(fresh), cwd=cwd)
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(config_home))
    return subprocess.run(
        [sys.executable, "-m", "app", "view", *args],
        cwd=cwd or ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture(scope="session")
def session_dir(tmp_path_factory):
    """A simulated 20 s phone session with truth (app.simulate.phone), written once; tests copy
    it before changing anything in it."""
    from app.simulate.phone import walking_pan, write_session

    folder = tmp_path_factory.mktemp("phone")
    write_session(folder, walking_pan(), duration_s=20.0)
    return folder


@pytest.fixture(scope="session")
def short_walk(tmp_path_factory) -> Path:
    """The manifest of a 6 s world-versus-model walk (app.simulate.session.quick_config(6.0)),
    simulated once for the modules that register against it (tests/test_register.py,
    tests/test_hardening_inputs.py); they read it, and a test that writes a file beside it
    (NAME.control.csv) removes it."""
    from app.simulate import session as sample
    from app.simulate.sample import SAMPLE_SCENE

    out = tmp_path_factory.mktemp("short-walk")
    return sample.write_sample_session(out, SAMPLE_SCENE, sample.quick_config(6.0))


def state_camera(wc: dict):
    """The window camera a viewer's `state` JSON describes (its "window_camera")."""
    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera

    return Camera.create(
        Intrinsics(*wc["size"], wc["fx"], wc["fy"], wc["cx"], wc["cy"]),
        wc["position"],
        wc["orientation"],
        wc["near"],
        wc["far"],
    )
