"""The render-side playback loop, driven by a simulated clock against a real decoder thread."""

import numpy as np
import pytest

from app.io.video import probe
from app.playback.player import Player
from app.simulate.phone import write_video


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("p") / "c.mp4", np.arange(90) / 30.0, (64, 32), 0)


def wait_for_frames(player, n=4, timeout=60.0):
    """Until the decoder has queued n frames (each put notifies the queue's condition); the
    timeout only stops a broken decoder from hanging the test."""
    q = player.decoder.frames
    with q.not_empty:
        q.not_empty.wait_for(lambda: q._qsize() >= min(n, q.maxsize), timeout)


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
    p = Player(probe(clip), loop=False)
    try:
        shown = run(p, 2.0, tick_s=0.004, render_s=0.003)
        assert shown == list(range(len(shown))) and len(shown) >= 58
        assert p.stats.dropped == 0
        lat = np.asarray(p.stats.latencies)
        assert (
            np.abs(lat).max() < 0.008
        )  # look-ahead keeps the display within a tick of the due time
    finally:
        p.close()


def test_slow_render_drops_frames_and_counts_them(clip):
    p = Player(probe(clip), loop=False)
    try:
        shown = run(p, 2.0, tick_s=0.05, render_s=0.05)  # 20 fps loop for 30 fps video
        assert p.stats.dropped >= 15 and len(shown) + p.stats.dropped >= 55
    finally:
        p.close()


def settle(player, now, timeout=3.0):
    """Tick (at a frozen `now`) until the frame of the last seek has arrived."""
    q = player.decoder.frames
    for _ in range(1000):
        seen = q.unfinished_tasks  # counts every put (the player never calls task_done)
        player.tick(now)
        if player.current is not None and player.current.serial == player.clock.serial:
            return player.index
        with q.not_empty:  # the decoder's next frame, not a sleep
            if not q.not_empty.wait_for(lambda s=seen: q.unfinished_tasks > s, timeout):
                break
    raise AssertionError("no frame after the seek")


def test_seek_and_step_show_the_exact_frame(clip):
    p = Player(probe(clip))
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
    p = Player(probe(clip), loop=False)
    try:
        assert p.next_due_wall(0.0) is None  # paused
        shown = run(p, 0.2, tick_s=0.004, render_s=0.003, start=50.0)
        now = 50.2
        due = p.next_due_wall(now)
        assert due is not None and 0.0 <= due - now <= 1 / 30 + 0.004
        assert float(p.schedule.pts[p.index + 1]) > float(p.schedule.pts[p.index]) and shown
    finally:
        p.close()


@pytest.mark.parametrize("step_s", [1 / 30, 0.4])
def test_a_fixed_step_clock_shows_exactly_the_frame_due(clip, step_s):
    """A scripted run's clock: each tick waits for the decoder, so the frame shown is the one due
    on every tick, and frames shown + frames dropped = frames due, at 30 fps or at 2.5 fps of
    drawing (a slow machine) alike."""
    p = Player(probe(clip), loop=False)
    try:
        now = 0.0
        p.clock.set_paused(False, now)
        first = None
        while now < 2.5:
            p.tick(now, wait_s=10.0)
            assert p.index == p.due_index(now)
            first = p.index if first is None else first
            p.shown(now, 0.0)
            now += step_s
        due = p.index - first + 1
        assert len(p.stats.latencies) + p.stats.dropped == due
        assert np.abs(p.stats.latencies).max() < 1e-9  # shown exactly when due
        if step_s > 0.1:
            assert (
                p.stats.dropped > 40
            )  # 12 frames of every 12 drawn... most are skipped, and counted
    finally:
        p.close()


def test_the_decoder_skips_late_frames_to_keep_up_with_the_clock(clip):
    """Drawing far slower than the video: the decoder, told which media time is due, neither
    converts nor queues frames that are already late, so the next frame handed over is the one
    due and not the next in line."""
    p = Player(probe(clip), loop=False)
    try:
        p.clock.set_paused(False, 0.0)
        p.tick(0.0, wait_s=10.0)
        assert p.index == 0
        p.decoder.due_s = 2.0  # as the render thread publishes it, two seconds later
        p.tick(2.0, wait_s=10.0)
        assert p.index == p.due_index(2.0) == 60
        assert p.decoder.skipped > 0
    finally:
        p.close()
