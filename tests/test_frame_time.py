"""Which video frame is shown at media time t: one function (app.io.video.frame_at) for the
viewer's schedule, `render --session`, `export --from/--to`; and a frame found again from its own
time whatever the clock's rounding (app.io.video.frame_of) for the video and KLV exports."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.camera.frame_time import frame_at, frame_of
from app.cli import main
from app.playback.clock import FrameSchedule
from app.session import open_session
from app.simulate.sample import SAMPLE_DIR


def test_the_frame_shown_is_the_last_at_or_before_t():
    pts = np.array([0.0, 0.0333, 0.0667, 0.1001, 0.1334])
    assert frame_at(pts, -0.5) == 0  # before the first: the first
    assert frame_at(pts, 0.05) == 1  # between two frames: the earlier, still on screen
    assert frame_at(pts, 0.0667) == 2  # at a frame's time: that frame
    assert frame_at(pts, 0.0667 - 1e-9) == 2  # float noise of a sum of steps does not lose it
    assert frame_at(pts, 0.0667 - 1e-3) == 1
    assert frame_at(pts, 9.0) == 4


def test_a_frame_is_found_from_its_time_whatever_the_rounding():
    """DJI subtitles give whole milliseconds (00:00:00,033): at 29.97 fps every frame's time so
    rounded still finds its frame, one to one; a time between frames finds none."""
    pts = np.arange(600) / 29.97
    rounded = np.round(pts, 3)
    assert [frame_of(pts, t) for t in rounded] == list(range(600))
    assert [frame_of(pts, t) for t in np.round(pts, 4)] == list(range(600))
    assert frame_of(pts, pts[-1] + 1.0) is None


@pytest.mark.gl
def test_render_and_the_viewer_show_the_same_frame_for_the_same_time(tmp_path, capsys):
    """The sample's frame times vary by up to 3 ms (a phone's variable rate): a time just after a
    frame, and one just before the next, give the frame the viewer's schedule shows."""
    session = open_session(SAMPLE_DIR / "session.toml")
    pts = session.video.pts_s
    schedule = FrameSchedule(np.asarray(pts))
    for t in (pts[300] + 0.001, pts[301] - 0.001):
        assert main(["render", "--session", str(SAMPLE_DIR / "session.toml"), "--time", repr(float(t)),
                     "--source", "gd-ahrs", "--size", "64x36", "--out", str(tmp_path / "f.png")]) == 0  # fmt: skip
        shown = int(re.search(r"frame (\d+) at", capsys.readouterr().out).group(1))
        assert shown == schedule.due(t) == 300
