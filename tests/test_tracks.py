import numpy as np

from app.playback.tracks import TrackLibrary
from app.session import open_session
from app.simulate.phone import walking_pan, write_session


def test_every_source_is_solved_in_the_background(tmp_path):
    session = open_session(write_session(tmp_path, walking_pan(), duration_s=10.0))
    lib = TrackLibrary(session, first="offline")
    assert lib.order[0] == "offline"
    assert lib.wait(timeout=60)
    assert set(lib.tracks) == set(session.filters) and not lib.errors
    table = {row[0]: row for row in lib.rms_table()}
    assert lib.reference() == "truth" and "truth" not in table
    assert table["gd-ahrs"][4] < 1.0  # total RMS, degrees
    c = lib.curves["gd-ahrs"]
    assert c.hpr.shape == (len(session.frame_times), 3) and np.all(np.diff(c.t) > 0)
