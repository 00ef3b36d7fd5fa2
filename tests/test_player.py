"""The render-side playback loop, driven by a simulated clock against a real decoder thread."""

import time

import numpy as np
import pytest

from app.playback.player import Player
from app.simulate.phone import write_video


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("p") / "c.mp4", np.arange(90) / 30.0, (64, 32), 0)


def wait_for_frames(player, n=4, timeout=2.0):
    end = time.monotonic() + timeout
    while player.decoder.frames.qsize() < n and time.monotonic() < end:
        time.sleep(0.005)


def run(player, seconds, tick_s, render_s, start=100.0):
    now = start
    player.clock.set_paused(False, now)
    shown = []
    while now < start + seconds:
        wait_for_frames(player, 2)
        if player.tick(now):
            shown.append(player.index)
        player.shown(now + render_s, render_s)
        now += tick_s
    return shown


def test_every_frame_shown_once_with_low_latency_when_render_is_fast(clip):
    p = Player(str(clip), np.arange(90) / 30.0, loop=False)
    try:
        shown = run(p, 2.0, tick_s=0.004, render_s=0.003)
        assert shown == list(range(len(shown))) and len(shown) >= 58
        assert p.stats.dropped == 0
        lat = np.asarray(p.stats.latencies)
        assert np.abs(lat).max() < 0.008  # look-ahead keeps the display within a tick of the due time
    finally:
        p.close()


def test_slow_render_drops_frames_and_counts_them(clip):
    p = Player(str(clip), np.arange(90) / 30.0, loop=False)
    try:
        shown = run(p, 2.0, tick_s=0.05, render_s=0.05)  # 20 fps loop for 30 fps video
        assert p.stats.dropped >= 15 and len(shown) + p.stats.dropped >= 55
    finally:
        p.close()


def settle(player, now, timeout=3.0):
    """Tick (at a frozen `now`) until the frame of the last seek has arrived."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        player.tick(now)
        if player.current is not None and player.current.serial == player.clock.serial:
            return player.index
        time.sleep(0.005)
    raise AssertionError("no frame after the seek")


def test_seek_and_step_show_the_exact_frame(clip):
    p = Player(str(clip), np.arange(90) / 30.0)
    try:
        p.seek(1.5, 0.0)
        assert settle(p, 0.0) == 45
        p.step(1, 0.0)
        assert settle(p, 0.0) == 46 and p.clock.paused
        p.step(-3, 0.0)
        assert settle(p, 0.0) == 43
    finally:
        p.close()


def test_next_due_wall_lets_an_idle_loop_sleep(clip):
    p = Player(str(clip), np.arange(90) / 30.0, loop=False)
    try:
        assert p.next_due_wall(0.0) is None  # paused
        shown = run(p, 0.2, tick_s=0.004, render_s=0.003, start=50.0)
        now = 50.2
        due = p.next_due_wall(now)
        assert due is not None and 0.0 <= due - now <= 1 / 30 + 0.004
        assert float(p.schedule.pts[p.index + 1]) > float(p.schedule.pts[p.index]) and shown
    finally:
        p.close()
