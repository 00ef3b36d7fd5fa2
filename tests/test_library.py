import numpy as np
import pytest

from app.camera.frame_time import corrected_times
from app.playback.library import SolverLibrary
from app.session import open_session
from app.simulate.phone import walking_pan, write_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return open_session(
        write_session(tmp_path_factory.mktemp("lib"), walking_pan(), duration_s=10.0)
    )


def test_every_source_is_solved_in_the_background(session):
    lib = SolverLibrary(session, first="offline")
    assert lib.order[0] == "offline"
    assert lib.wait(timeout=60)
    assert (
        lib.solved() == list(lib.order)
        and set(lib.order) == set(session.sources)
        and not lib.errors()
    )
    table = {row[0]: row for row in lib.rms_table()}
    assert lib.reference() == "truth" and "truth" not in table
    assert table["gd-ahrs"][4] < 1.0  # total RMS, degrees
    c = lib.curves("gd-ahrs")
    assert c.hpr.shape == (len(session.frame_times), 3) and np.all(np.diff(c.t) > 0)


def test_a_time_offset_moves_every_camera_along_its_track(session):
    """The offset is the library's: asking for 0.5 s gives the camera 0.5 s later on the track."""
    lib = SolverLibrary(session)
    assert lib.wait(timeout=60)
    track = lib.track("truth")
    k = 100
    late = track.poses.at(session.frame_times[k : k + 1] + 0.5)[0][0]
    version = lib.version
    lib.set_time_offset(0.5)
    assert lib.version == version + 1 and lib.time_offset_s == 0.5
    np.testing.assert_allclose(lib.track("truth").frame_camera(k).position, late, atol=1e-9)
    assert not np.allclose(
        track.frame_camera(k).position, late, atol=1e-3
    )  # the old snapshot is unchanged


def test_a_sync_with_clock_drift_reaches_every_track(session):
    """The viewer's Sync applies the drift it found, not only the offset, through the one
    conversion the manifest's "auto" offset uses (app.camera.frame_time.corrected_times)."""
    lib = SolverLibrary(session)
    assert lib.wait(timeout=60)
    base = lib.track("gd-ahrs").clock.session_time([5.0, 15.0])
    pivot = float(base[0])
    lib.set_time_offset(0.1, 200.0, pivot)
    for name in ("gd-ahrs", "truth"):
        got = lib.track(name).clock.session_time([5.0, 15.0])
        np.testing.assert_allclose(got, corrected_times(base, 0.1, 200.0, pivot), atol=1e-9)
    # 200 ppm stretches the 10 s between the two frames by 2 ms (Unix-time floats: to 1 us).
    assert got[1] - got[0] == pytest.approx((base[1] - base[0]) * (1 + 200e-6), abs=1e-6)
