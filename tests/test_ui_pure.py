from types import SimpleNamespace

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.errors import DataFormatError
from app.geodesy import rotations
from app.session.model import REGISTERED
from app.ui.navigation import Navigator
from app.ui.script import Action, parse_script
from app.ui.sessions import Loaded, ViewerSessions
from app.ui.state import UiState
from app.ui.viewer import Options, Viewer


def test_free_roam_moves_along_the_view():
    nav = Navigator(position=np.zeros(3), yaw=90.0, pitch=0.0, speed=2.0)
    nav.move(1.5, forward=1, right=0, up=0)
    np.testing.assert_allclose(nav.position, [3, 0, 0], atol=1e-12)  # yaw 90 = east
    nav.move(1.0, forward=0, right=1, up=1)
    np.testing.assert_allclose(nav.position, [3, -2, 2], atol=1e-12)  # right of east is south
    cam = nav.camera(Intrinsics.from_fov(100, 50, 60), None)
    np.testing.assert_allclose(rotations.rotate(cam.orientation, [0, 0, -1]), [1, 0, 0], atol=1e-12)


def test_orbit_keeps_the_target_in_the_centre_and_wheel_zooms():
    nav = Navigator(position=np.array([0.0, -50.0, 10.0]))
    nav.orbit_around(np.array([0.0, 0.0, 10.0]))
    nav.look(100, 0)
    nav.wheel(2)
    cam = nav.camera(Intrinsics.from_fov(100, 100, 60), None)
    uv, depth = cam.project([[0.0, 0.0, 10.0]])
    np.testing.assert_allclose(uv[0], [50, 50], atol=1e-9)
    assert depth[0] == pytest.approx(50 * 0.85**2)


def test_phone_mode_rides_the_video_camera_and_reset_returns_home():
    nav = Navigator()
    phone = Camera.create(
        Intrinsics.from_fov(64, 36, 66), [1, 2, 3], rotations.camera_quat_from_hpr(30, 5, 0)
    )
    nav.mode = "phone"
    cam = nav.camera(Intrinsics.from_fov(200, 100, 66), phone)
    assert cam.position == phone.position and cam.orientation == phone.orientation
    home = nav.position.copy()
    nav.mode = "free"
    nav.move(1.0, 1, 0, 0)
    nav.reset()
    np.testing.assert_allclose(nav.position, home)


def test_script_parsing(tmp_path):
    p = tmp_path / "s.txt"
    p.write_text("# a test\n0 play\n2.5 alpha 0.5  # half\n1 seek 10\n3 quit\n")
    actions = parse_script(p)
    assert [(a.at_s, a.name, a.arg) for a in actions] == [
        (0.0, "play", None),
        (1.0, "seek", "10"),
        (2.5, "alpha", "0.5"),
        (3.0, "quit", None),
    ]
    p.write_text("0 play\nsoon quit\n")
    with pytest.raises(DataFormatError, match=r"s.txt:2"):
        parse_script(p)
    p.write_text("0 dance\n")
    with pytest.raises(DataFormatError, match="unknown action 'dance'"):
        parse_script(p)


def test_actions_after_a_wait_see_the_time_it_took():
    """A script's `wait registered` on the wall clock can take a minute: the `play` after it must
    start the playback clock then, not when the wait began (else a minute of frames is due at
    once and dropped)."""
    now = [100.0]
    v = Viewer(Options(None), clock=lambda: now[0])
    seen = []

    def apply(name, arg, t):
        seen.append((name, t))
        if name == "wait":
            now[0] += 60.0  # the wait took a minute of wall time

    v.apply = apply
    v.script = [Action(0.0, "wait", "registered", 1), Action(0.0, "play", None, 2)]
    v._run_script(0.0, now[0])
    assert seen == [("wait", 100.0), ("play", 160.0)]


def _viewer_with_registered(used: list[bool], chosen: bool) -> SimpleNamespace:
    """A viewer's state as _prefer_registered reads it: gd-ahrs shown, `registered` solved with
    keyframes used or not, the user having chosen a source or not."""
    keyframes = tuple(SimpleNamespace(used=u) for u in used)
    registered = SimpleNamespace(registration=SimpleNamespace(keyframes=keyframes))
    loaded = Loaded(
        session=SimpleNamespace(sources=("gd-ahrs", "offline", REGISTERED)),
        renderer=None,
        player=None,
        library=SimpleNamespace(track=lambda name: registered if name == REGISTERED else None),
        source="gd-ahrs",
        source_chosen=chosen,
    )
    return SimpleNamespace(loaded=loaded, ui=UiState())


def test_the_viewer_shows_registered_once_solved_unless_the_user_chose_a_source():
    v = _viewer_with_registered([True, False, True], chosen=False)
    ViewerSessions._prefer_registered(v)
    assert v.loaded.source == REGISTERED
    assert v.ui.info == [
        "registered is solved: showing it instead of gd-ahrs (the Attitude panel switches back)"
    ]
    v.loaded.source = "gd-ahrs"  # switched back by hand: not switched again
    ViewerSessions._prefer_registered(v)
    assert v.loaded.source == "gd-ahrs" and len(v.ui.info) == 1

    chosen = _viewer_with_registered([True], chosen=True)
    ViewerSessions._prefer_registered(chosen)
    assert chosen.loaded.source == "gd-ahrs" and chosen.ui.info == []

    useless = _viewer_with_registered([False, False], chosen=False)
    ViewerSessions._prefer_registered(useless)
    assert useless.loaded.source == "gd-ahrs"
    assert useless.ui.info == [
        "registered used no keyframe: staying on gd-ahrs (the Attitude panel says why)"
    ]


def test_a_session_is_read_off_the_frame_loop_and_a_failure_is_shown(tmp_path, monkeypatch):
    """Reading what the viewer opens happens on a thread of its own: with the reader held (a
    district's CityJSON takes seconds), `open` returns at once and the frame loop's poll installs
    nothing; once the reader is done, the poll installs its outcome: a file that cannot be read
    is shown as an error, runs the failure's undo and leaves no session half open."""
    import threading

    from app.core.errors import GeofuseError
    from app.ui import sessions

    release = threading.Event()

    def held_reader(path, *args, **kwargs):
        release.wait(30)
        raise GeofuseError(f"{path}: broken JSON at line 3")

    monkeypatch.setattr(sessions, "open_any", held_reader)
    v = Viewer(Options(None))
    undone = threading.Event()
    assert v.open(tmp_path / "district.city.json.toml", background=True, on_fail=undone.set)
    for _ in range(5):  # frames go by while the reader is held
        v.poll_open()
        assert v.ui.opening is not None and not undone.is_set() and v.ui.errors == []
    assert not v.open(tmp_path / "other.toml", background=True)  # one at a time, said
    assert "still opening" in v.ui.errors.pop()
    release.set()
    assert v.ui.opening._done.wait(30)
    v.poll_open()
    assert v.ui.opening is None and v.loaded is None and undone.is_set()
    assert v.ui.errors == [f"{tmp_path / 'district.city.json.toml'}: broken JSON at line 3"]
