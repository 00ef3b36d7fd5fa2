import numpy as np
import pytest

from app.playback.clock import FrameSchedule, PlaybackClock


def test_clock_accumulates_speed_pause_and_seek():
    c = PlaybackClock(duration=10.0, loop=False)
    assert c.time(100.0) == 0.0
    assert c.time(101.0) == pytest.approx(1.0)
    c.set_speed(2.0, 101.0)
    assert c.time(102.5) == pytest.approx(4.0)
    c.set_paused(True, 102.5)
    assert c.time(110.0) == pytest.approx(4.0)
    c.set_paused(False, 110.0)
    serial = c.serial
    c.seek(8.0, 110.0)
    assert c.serial == serial + 1 and c.time(110.0) == 8.0
    assert c.time(112.0) == 10.0 and c.paused  # stops at the end without loop
    with pytest.raises(ValueError):
        c.set_speed(8.0, 112.0)


def test_clock_loops_and_bumps_serial():
    c = PlaybackClock(duration=4.0, loop=True)
    c.time(0.0)
    s = c.serial
    assert c.time(5.0) == pytest.approx(1.0)
    assert c.serial == s + 1


def test_due_frame_and_wall_time():
    sched = FrameSchedule(np.array([0.0, 0.033, 0.07, 0.1]))
    assert (
        sched.due(0.0) == 0 and sched.due(0.05) == 1 and sched.due(0.07) == 2 and sched.due(5) == 3
    )
    assert sched.step(0, -1) == 0 and sched.step(2, 5) == 3
    c = PlaybackClock(duration=1.0, speed=0.5)
    c.time(10.0)
    assert c.wall_time_of(0.1, 10.0) == pytest.approx(10.2)
