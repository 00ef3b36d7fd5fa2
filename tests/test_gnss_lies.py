"""GNSS that fails or lies (issue 52): every frame says what posed it (the solve CSV's `gnss`
column, the FMV CSV's trailing column, the viewer's timeline and Stats panel), a jump, a
drag-off, a frozen or replayed track and a height lie are caught against the scene's registered
keyframes, said once with their time and kind and not followed, outages are said with their
span, a clean session raises no alarm. The sessions are simulated (a drone orbit over a world
that differs from its model), their gnss.csv falsified by app.simulate.lies."""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from app.camera.fixes import MISSING, REJECTED, USED, FixStatus
from app.export.gis import FMV_FIELDS, FMV_HEADER, properties, write_fmv_csv
from app.export.records import frame_records
from app.register import solve
from app.register.gnss import (
    DISAGREES,
    FROZEN,
    HEIGHT,
    REPLAYED,
    CheckSettings,
    check_fixes,
    drifting,
)
from app.register.keyframe import PoseFix, posed
from app.register.solve import Cancelled, Registrar, registered_track
from app.session import open_session
from app.simulate import sensors
from app.simulate import session as sample
from app.simulate.lies import Lie, falsify
from app.simulate.sample import SAMPLE_SCENE
from app.solve.accuracy import true_track
from app.solve.track import COLUMNS, csv_rows, solve_track
from app.solve.uncertainty import frame_sigmas
from app.ui import gnss as viewer_gnss
from tests.conftest import run_viewer

DURATION_S = 18.0
LIE_FROM_S = 6.0  # clip seconds (from the simulation's start); a 3 m/s drag-off passes the
# scene's threshold (11.25 m) 3.75 s later, well before the clip's last seconds, where the gate's
# window is one-sided
# said against the scene, the IMU's motion (app.register.inertial) or both
ALARM = re.compile(
    r"GNSS disagrees with the (?:scene|IMU's motion)(?: and the IMU's motion)? from .*?t = (\d+\.\d) s"
)


# --- the test on its own, on synthetic fixes -------------------------------------------------------


def _circle(t: np.ndarray) -> np.ndarray:
    """ENU m along a 110 m circle at 60 m flown at about 6 m/s, at times t (s)."""
    return np.column_stack([110 * np.cos(t / 18), 110 * np.sin(t / 18), np.full(len(t), 60.0)])


def _fixes(seed: int, lie: Lie | None = None, duration_s: float = 120.0, sigma_v_m: float = 0.0):
    """Fixes at 1 Hz along a 6 m/s circle with a GNSS error of 2.5 m (1 sigma per axis,
    correlated over 30 s, as the simulator's; in height sigma_v_m, the simulator's 4 m where
    given) and the lie applied (app.simulate.lies.Lie.apply); keyframes every 0.5 s at the true
    positions with 0.1 m of noise and one in 20 registered 6 m wrong."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0)
    err = np.column_stack([sensors.gauss_markov(t, 2.5, 30.0, rng, 2), np.zeros(len(t))])
    if sigma_v_m > 0:
        err[:, 2] = sensors.gauss_markov(t, sigma_v_m, 30.0, rng)[:, 0]
    fixes = _circle(t) + err
    if lie is not None:
        fixes = lie.apply(t, fixes)
    kt = np.arange(0.0, duration_s, 0.5)
    kp = _circle(kt) + rng.normal(0, 0.1, (len(kt), 3))
    kp[rng.random(len(kt)) < 0.05] += [6.0, 0.0, 0.0]
    return t, fixes, kt, kp


@pytest.mark.parametrize("seed", range(20))
def test_fixes_at_their_stated_accuracy_raise_no_alarm(seed):
    t, fixes, kt, kp = _fixes(seed)
    check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, kp)
    assert check.lies == () and not check.status.rejected.any()


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("lie", [Lie("jump", 30.0), Lie("drag", 30.0, speed_mps=2.0)])
def test_a_jump_and_a_drag_off_are_caught_from_where_they_began(seed, lie):
    t, fixes, kt, kp = _fixes(seed, lie)
    check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, kp)
    assert len(check.lies) == 1
    found = check.lies[0]
    exceeds = lie.from_s + (2.5 / lie.speed_mps if lie.kind == "drag" else 0.0)
    # the goal is 5 s at 2 m/s; where the GNSS's own offset points against the drag it
    # must first be undone (measured in docs/ACCURACY.md)
    assert found.caught_s - exceeds <= 7.0
    assert abs(found.began_s - lie.from_s) <= 4.0
    assert check.status.rejected[t >= found.caught_s].all()
    assert not check.status.rejected[t < lie.from_s - 4.0].any()


@pytest.mark.parametrize("seed", range(5))
def test_a_slow_drag_off_over_a_gap_in_the_keyframes_is_dated_inside_the_gap(seed):
    """A 1 m/s drag-off from 30 s, no keyframe from 37 to 46 s (a survey's turn over grass):
    the residual's rise across the gap is a ramp's, not a step, so the lie is said from where
    it crossed half-way inside the gap, back by as long again, not from the first keyframe
    after it (survey seed 4 said 31 s for a drag from 15 s); a 200 m jump inside the same gap
    is still said from the keyframes after the gap."""
    for lie in (Lie("drag", 30.0, speed_mps=1.0), Lie("jump", 41.0)):
        t, fixes, kt, kp = _fixes(seed, lie)
        seen = (kt < 37.0) | (kt >= 46.0)
        check = check_fixes(t, fixes, np.full(len(t), 2.5), kt[seen], kp[seen])
        assert len(check.lies) == 1, check.lies
        found = check.lies[0]
        if lie.kind == "jump":  # not dated back into the gap
            assert found.began_s >= 46.0, found
        else:  # caught after the gap (25-33 s on these seeds; the fixes' own wander)
            assert found.caught_s >= 46.0 and -5.0 <= found.began_s - lie.from_s <= 4.0, found


@pytest.mark.parametrize("speed", [1.0, 2.0, 5.0])
def test_a_drag_off_without_noise_is_said_from_the_first_fix_at_or_after_it_began(speed):
    """By hand: fixes at 1 Hz where the camera was, keyframes every 0.5 s exact, a drag-off from
    30.0, 30.3, 30.6 or 30.9 s: the half-way moment lies between two fixes, where the straight
    line between them crosses it, and the lie is said from the first fix at or after where it
    began (31 s; 30 s for one from 30.0). Taking the first fix past half-way dated each a fix
    or two late (32 s)."""
    t = np.arange(0.0, 80.0)
    truth = np.column_stack([6.0 * t, np.zeros_like(t), np.full_like(t, 60.0)])
    kt = np.arange(0.0, 80.0, 0.5)
    keys = np.column_stack([6.0 * kt, np.zeros_like(kt), np.full_like(kt, 60.0)])
    for began in (30.0, 30.3, 30.6, 30.9):
        fixes = Lie("drag", began, speed_mps=speed).apply(t, truth)
        [lie] = check_fixes(t, fixes, np.full(len(t), 2.5), kt, keys).lies
        assert lie.began_s == np.ceil(began), (began, lie)


def test_a_drag_off_is_dated_by_how_far_it_had_gone_along_its_walk_not_across_it():
    """A drone downlink's fixes (a KLV set per frame, 30 Hz; stated 2.5 m; the live bench's GNSS
    error, 2.5 m per axis correlated over 30 s) dragged east from 10 s, keyframes every 0.5 s
    where the camera was: each drag is said from within 5 s (1 m/s), 3 s (2 m/s) and 1 s (5 m/s)
    of where it began, over 20 seeds. Dated by the residual's distance from the GNSS's own
    offset, seed 3's wander, 6 m north over the 10 s before the drag, said its drags from 0.1,
    2.6 and 5.6 s (bench/bench_gnss_lies.py's recorded feeds, docs/ACCURACY.md)."""
    t = np.arange(0.0, 30.0, 1.0 / 30.0)
    truth = np.column_stack([6.0 * t, np.zeros_like(t), np.full_like(t, 60.0)])
    for speed, within in ((1.0, 5.0), (2.0, 3.0), (5.0, 1.0)):
        off = {}
        for seed in range(1, 21):
            rng = np.random.default_rng(seed)
            noise = np.column_stack([sensors.gauss_markov(t, 2.5, 30.0, rng, 2), sensors.gauss_markov(t, 4.0, 30.0, rng)])  # fmt: skip
            fixes = Lie("drag", 10.0, speed_mps=speed).apply(t, truth + noise)
            keys = truth[::15] + rng.normal(0.0, 0.05, (len(t[::15]), 3))
            check = check_fixes(t, fixes, np.full(len(t), 2.5), t[::15], keys)
            assert len(check.lies) == 1, (speed, seed, check.lies)
            off[seed] = check.lies[0].began_s - 10.0
        assert all(abs(o) <= within for o in off.values()), (speed, off)
        assert abs(off[3]) <= 2.0, (speed, off[3])  # the wander across the drag
        assert all(o >= -2.0 for o in off.values()), (speed, off)  # no honest fix accused


def test_a_drag_off_at_2_mps_is_caught_within_5_s_of_passing_the_stated_accuracy():
    """The issue's goal, on the synthetic fixes (stated 2.5 m): a 2 m/s drag passes 2.5 m 1.25 s
    after it begins and the threshold (11.25 m) 4.4 s after that, caught a fix or two later, so
    by the threshold alone 9 of these 20 seeds within 5 s; walking off steadily it passes the
    drift test's 6 m over 4 s about 3 s after it begins: 17 of 20 (the rest, where the GNSS's
    own wander pulls against it, 5.75-7.75 s). One lie each, said from within 4 s of where it
    began on 19 (seed 13's wander, 6 m off its offset before the lie, dates it from 12 s, with
    or without the drift test)."""
    delays, began = [], []
    for seed in range(20):
        lie = Lie("drag", 30.0, speed_mps=2.0)
        t, fixes, kt, kp = _fixes(seed, lie)
        check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, kp)
        assert len(check.lies) == 1
        delays.append(check.lies[0].caught_s - (lie.from_s + 2.5 / lie.speed_mps))
        began.append(check.lies[0].began_s - lie.from_s)
    assert sum(d <= 5.0 for d in delays) >= 16, delays
    assert max(delays) <= 8.0
    assert sum(abs(b) <= 4.0 for b in began) >= 19, began


def test_a_lie_goes_on_while_its_fixes_stand_off_their_offset_and_ends_when_they_come_back():
    """By hand, no GNSS noise, fixes at 1 Hz stating 2.5 m, keyframes every 0.5 s at the truth:
    from 15 s the fixes walk east at 2 m/s, caught at 19 s by the drift test, and hold 10 m off
    (under the 11.25 m threshold, no longer walking). Before, the lie ended at 20 s, and the
    fixes 10 m off were used from there. It goes on while they stand farther than the release
    threshold (3 sigma, 7.5 m) from their offset before it: to the clip's end where the
    keyframes stop at 24 s and the drag walks on unseen (survey seed 4's 2 m/s drag: the fixes
    used 10-40 m off over a turn, docs/ACCURACY.md), and to 29 s where they come back to it at
    30 s, those after used again."""
    t = np.arange(0.0, 60.0, 1.0)
    held = np.column_stack([np.clip(2.0 * (t - 15.0), 0.0, 10.0), 0.0 * t, 0.0 * t])
    unseen = held + np.column_stack([2.0 * np.clip(t - 24.0, 0.0, None), 0.0 * t, 0.0 * t])
    back = np.where(t[:, None] >= 30.0, 0.0, held)
    kt = np.arange(0.0, 60.0, 0.5)
    for offset, until in ((unseen, 24.0), (back, 60.0)):
        seen = kt < until
        check = check_fixes(
            t, _circle(t) + offset, np.full(len(t), 2.5), kt[seen], _circle(kt[seen])
        )
        [lie] = check.lies
        assert lie.kind == DISAGREES and lie.caught_s == 19.0
        rejected = check.status.rejected
        assert not rejected[t < 15.0].any() and rejected[(t >= 17.0) & (t < 30.0)].all()
        if offset is unseen:
            assert rejected[t >= 17.0].all() and lie.ended_s == t[-1]
        else:
            assert lie.ended_s == 29.0 and not rejected[t >= 30.0].any()


def _walk(t: np.ndarray, start_s: float, mps: float) -> np.ndarray:
    """(N, 3) residuals (ENU m): none before start_s, then walking east at mps (m/s)."""
    out = np.zeros((len(t), 3))
    out[:, 0] = mps * np.clip(t - start_s, 0.0, None)
    return out


def test_a_steady_drift_is_told_from_wander_multipath_and_a_jump():
    """drifting() on residuals by hand, one a second, the stated accuracy 2.5 m (limit max(6,
    2.4 x 2.5) = 6 m over 4 s): walking off at 2 m/s from 20 s it has gone 6 m from 19 to 23 s
    (not past 6) and 8 m from 20 to 24 s, each half 4 m: drifting from 24 s on. The same walk
    while the receiver's stated accuracy grows (multipath it says) is not; nor a swing from 5 m
    west to 5 m east of its offset (no farther from it), nor a 10 m step (one half only: the
    level test's), nor a walk back towards the offset."""
    t = np.arange(0.0, 60.0)
    acc = np.full(len(t), 2.5)
    settings = CheckSettings()
    walk = drifting(t, _walk(t, 20.0, 2.0), acc, settings)
    assert np.flatnonzero(walk)[0] == 24 and walk[24:].all()
    # the receiver says it: 2.5 m -> 5 m over the walk's first 5 s, then held (12 m over 4 s);
    # over 8 s (the walk test's, below) the accuracy holds from 24 s (4.5 m: within 1.2 x), so
    # the walk on from there is caught at 32 s (16 m in 8 s)
    growing = acc + np.clip(t - 20.0, 0.0, 5.0) * 0.5
    halves = replace(settings, walk_s=0.0)
    assert not drifting(t, _walk(t, 20.0, 2.0), growing, halves).any()
    assert np.flatnonzero(drifting(t, _walk(t, 20.0, 2.0), growing, settings))[0] == 32
    swing = _walk(t, 20.0, 2.5) - [5.0, 0.0, 0.0]
    swing[t > 24.0, 0] = 5.0
    swing[t < 20.0, 0] = -5.0
    swing[t < 10.0, 0] = 0.0  # the GNSS's own offset: 0 over 30 to 10 s before the swing
    assert not drifting(t, swing, acc, settings)[:40].any()
    step = np.zeros((len(t), 3))
    step[t >= 20.0, 0] = 10.0
    assert not drifting(t, step, acc, settings).any()
    back = _walk(t, 20.0, 2.0)
    back[t >= 20.0, 0] = 30.0 - 2.0 * (t[t >= 20.0] - 20.0)
    back[t < 20.0, 0] = 0.0
    assert not drifting(t, back, acc, settings)[20:35].any()
    # none judged without a baseline (the first 10 s) or with the drift test off
    assert not drifting(t, _walk(t, 0.0, 3.0), acc, settings)[:10].any()
    off = replace(settings, drift_s=0.0, walk_s=0.0)
    assert not drifting(t, _walk(t, 20.0, 2.0), acc, off).any()


def test_a_slow_drift_is_caught_over_a_longer_walk_and_multipath_is_not():
    """The walk test (drifting's second): over 8 s in four 2 s pieces, each moving the residual
    by 15 % of the whole or more the same way, by more than max(8, 2.4 x the accuracy). Fixes
    that state none (DJI) are held to 5 m: 12 m, which 2 m/s never walks in the halves' 4 s but
    walks in 8 s: 16 m from 20 to 28 s, caught at 28 s (at 27 s the first piece, 19 to 21 s,
    moved 2 m, under 15 % of 14). At the stated 2.5 m (8 m), 1.25 m/s: 10 m from 20 to 28 s.
    Multipath comes in within a piece or two (held to 5 m: a 10 m burst over 1.5 s, and two of
    7 m, 3 s apart and the same way, 14 m in all) and is no walk."""
    t = np.arange(0.0, 60.0)
    five, stated = np.full(len(t), 5.0), np.full(len(t), 2.5)
    settings = CheckSettings()
    walk = drifting(t, _walk(t, 20.0, 2.0), five, settings)
    assert np.flatnonzero(walk)[0] == 28 and walk[28:].all()
    assert not drifting(t, _walk(t, 20.0, 2.0), five, replace(settings, walk_s=0.0)).any()
    assert np.flatnonzero(drifting(t, _walk(t, 20.0, 1.25), stated, settings))[0] == 28

    def burst(start_s: float, size_m: float) -> np.ndarray:
        return np.clip(_walk(t, start_s, size_m / 1.5), None, size_m)

    assert not drifting(t, burst(20.0, 10.0), five, settings).any()
    assert not drifting(t, burst(20.0, 7.0) + burst(23.0, 7.0), five, settings).any()


@pytest.mark.parametrize("seed", range(20))
def test_heights_at_the_simulators_accuracy_raise_no_alarm(seed):
    """4 m of height error (the simulator's, correlated over 30 s) against a vertical threshold
    of 4.5 x 2 x the stated 2.5 m: no alarm (over 400 such tracks the largest vertical residual
    was 16.2 m: docs/ACCURACY.md)."""
    t, fixes, kt, kp = _fixes(seed, sigma_v_m=4.0)
    check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, kp)
    assert check.lies == () and not check.status.rejected.any()


KINDS = {  # the lie, the kind check_fixes names, its message (clip times: the synthetic t)
    "frozen": (Lie("frozen", 30.0), FROZEN, r"GNSS frozen from t = 30\.0 s, \d+ m behind the scene by t = "),
    "replay": (Lie("replay", 30.0, back_s=20.0), REPLAYED, r"GNSS replays its fixes of t = 10\.0 s from t = 30\.0 s, \d+ m off the scene by t = "),
    "height up": (Lie("height", 30.0, height_m=40.0), HEIGHT, r"GNSS height disagrees with the scene by (\d+) m from t = 30\.0 s"),
    "height down": (Lie("height", 30.0, height_m=-30.0), HEIGHT, r"GNSS height disagrees with the scene by (\d+) m from t = 30\.0 s"),
}  # fmt: skip


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("name", list(KINDS))
def test_a_frozen_a_replayed_and_a_height_lie_are_caught_and_named(seed, name):
    lie, kind, said = KINDS[name]
    t, fixes, kt, kp = _fixes(seed, lie, sigma_v_m=4.0)
    check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, kp)
    assert [found.kind for found in check.lies] == [kind]
    found = check.lies[0]
    # frozen: the camera, flying on at 6 m/s, leaves the fix by the 11.25 m threshold in 2 s
    # (4 s at most over 100 seeds, with the GNSS's own offset against it)
    assert found.began_s == lie.from_s and found.caught_s - lie.from_s <= 4.0
    assert check.status.rejected[t >= found.caught_s].all()
    assert not check.status.rejected[t < lie.from_s - 1.0].any()
    text = found.said(0.0)
    match = re.match(said, text)
    assert match, text
    if kind == HEIGHT:  # how far: the lie, give or take the GNSS's own height error
        assert abs(int(match.group(1)) - abs(lie.height_m)) <= 15
    if kind == REPLAYED:
        assert found.replay_of_s == lie.from_s - lie.back_s


def test_a_frozen_fix_with_the_camera_at_rest_and_a_repeated_output_are_no_frozen_lie():
    """A fix that stops while the camera hovers disagrees with nothing; a receiver that says
    each fix twice (2 Hz out, 1 Hz updates) is not frozen: its jump is a jump."""
    t = np.arange(0.0, 90.0, 1.0)
    kt = np.arange(0.0, 90.0, 0.5)
    still = np.tile([20.0, 30.0, 60.0], (len(t), 1))
    frozen = Lie("frozen", 30.0).apply(t, still + np.random.default_rng(1).normal(0, 0.3, still.shape))  # fmt: skip
    check = check_fixes(t, frozen, None, kt, np.tile([20.0, 30.0, 60.0], (len(kt), 1)))
    assert check.lies == ()
    t2 = np.arange(0.0, 90.0, 0.5)
    twice = _circle(np.floor(t2)) + Lie("jump", 30.0).offset_enu(np.floor(t2))
    check = check_fixes(t2, twice, np.full(len(t2), 2.5), kt, _circle(kt))
    assert [found.kind for found in check.lies] == [DISAGREES]
    assert check.lies[0].began_s == 30.0


def test_lies_written_into_a_gnss_log():
    """Lie.apply: a frozen track repeats its first fix, a replay the fixes back_s before, a height
    lie moves up only; outside the lie nothing moves."""
    t = np.arange(0.0, 10.0, 1.0)
    p = _circle(t)
    frozen = Lie("frozen", 4.0, until_s=7.0).apply(t, p)
    np.testing.assert_array_equal(frozen[4:7], np.tile(p[4], (3, 1)))
    np.testing.assert_array_equal(frozen[[0, 3, 7, 9]], p[[0, 3, 7, 9]])
    replay = Lie("replay", 5.0, back_s=3.0).apply(t, p)
    np.testing.assert_array_equal(replay[5:], p[2:7])
    np.testing.assert_array_equal(replay[:5], p[:5])
    up = Lie("height", 5.0, height_m=-30.0).apply(t, p) - p
    assert (up[5:, 2] == -30.0).all() and not up[:5].any() and not up[:, :2].any()
    with pytest.raises(ValueError, match="unknown lie"):
        Lie("spoof")


def test_the_timeline_band_runs_and_lines_up_with_the_scrubbers_grab():
    status = np.array([USED, USED, REJECTED, REJECTED, MISSING])
    pts = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    runs = viewer_gnss.runs(status, pts, 5.0)
    assert [(r.start_s, r.end_s, r.status) for r in runs] == [(0.0, 2.0, USED), (2.0, 4.0, REJECTED), (4.0, 5.0, MISSING)]  # fmt: skip
    # ImGui's slider: the grab's centre from 2 px + half the grab in at either end
    assert viewer_gnss.slider_x(0.0, 5.0, 100.0, 600.0, 10.0) == 107.0
    assert viewer_gnss.slider_x(5.0, 5.0, 100.0, 600.0, 10.0) == 593.0
    assert viewer_gnss.slider_x(2.5, 5.0, 100.0, 600.0, 10.0) == 350.0
    said = viewer_gnss.frame_said(None, "offline", None, 0)  # type: ignore[arg-type]
    assert [s for _, s in said] == [None] and "only `registered`" in said[0][0]


def test_frames_say_used_rejected_and_missing():
    fixes = FixStatus(np.array([0.0, 1, 2, 3, 20, 21, 22, 23]), np.array([0, 0, 0, 0, 0, 0, 1, 1], bool))  # fmt: skip
    got = fixes.at([0.5, 2.5, 10.0, 20.5, 21.5, 22.5, 25.0, 40.0, -10.0])
    assert list(got) == [USED, USED, MISSING, USED, REJECTED, REJECTED, REJECTED, MISSING, MISSING]
    assert fixes.outages(-1.0, 30.0) == [(3.0, 20.0), (23.0, 30.0)]


# --- simulated sessions, solved --------------------------------------------------------------------


@pytest.fixture(scope="module")
def orbit(tmp_path_factory):
    """A short drone orbit and copies of it whose GNSS lies or fails from LIE_FROM_S."""
    out = tmp_path_factory.mktemp("gnss-lies")
    config = replace(sample.quick_config(DURATION_S), flight="orbit", seed=7)
    sample.write_sample_session(out / "clean", SAMPLE_SCENE, config)
    lies = {
        "jump": Lie("jump", LIE_FROM_S, size_m=200.0),
        "drag": Lie("drag", LIE_FROM_S, speed_mps=3.0),
        "outage": Lie("outage", LIE_FROM_S, until_s=LIE_FROM_S + 6.0),
    }
    return {"clean": out / "clean" / "session.toml"} | {
        k: falsify(out / "clean", out / k, lie) for k, lie in lies.items()
    }


@pytest.fixture(scope="module")
def solved(orbit, gl_ctx):
    """The registered track of each session (solved once, on first use), its session, the true
    track, and its frames' clip times (s from the simulation's start)."""
    cache: dict = {}

    def get(kind: str):
        if kind not in cache:
            session = open_session(orbit[kind])
            track = registered_track(session, ctx=gl_ctx)
            poses = track.frame_poses()
            truth = true_track(session)
            true = truth.poses_at(truth.clock.media_s[poses.index])
            error = np.linalg.norm(poses.enu - true.enu, axis=1)
            cache[kind] = (session, track, poses, error, poses.time_s - sample.START_UNIX_S)
        return cache[kind]

    return get


def _alarms(session) -> list[float]:
    """The clip times (s, from the first frame) of the lies the session's messages say."""
    texts = [m.text for m in session.messages.since(0)]
    return [float(m.group(1)) for m in map(ALARM.search, texts) if m]


@pytest.mark.gl
def test_a_clean_session_raises_no_alarm(solved):
    session, track, poses, error, _ = solved("clean")
    assert _alarms(session) == []
    assert set(poses.gnss) == {USED}
    assert np.median(error) < 0.5


@pytest.mark.gl
def test_a_jump_is_said_once_rejected_and_not_followed(solved):
    session, track, poses, error, t = solved("jump")
    _, _, _, clean_error, _ = solved("clean")
    alarms = _alarms(session)
    assert len(alarms) == 1 and abs(alarms[0] - LIE_FROM_S) <= 3.0, alarms
    assert (poses.gnss[t < LIE_FROM_S - 3.0] == USED).all()
    assert (poses.gnss[t >= LIE_FROM_S + 1.0] == REJECTED).all()
    # its offset held: the fixes moved back by it carry the track (rejected as given), and say so
    [lie] = track.registration.gnss.lies
    assert lie.shift is not None and abs(np.linalg.norm(lie.shift) - 200.0) < 10.0, lie
    said = [m.text for m in session.messages.since(0) if "moved back by" in m.text]
    assert len(said) == 1 and "not used as given" in said[0], said
    # no interpolation across the jump: near the clean run's error everywhere, not metres off
    assert np.median(error[t >= LIE_FROM_S]) < 1.5 * np.median(clean_error[t >= LIE_FROM_S]) + 0.1
    assert np.percentile(error, 99) < 2.0, np.percentile(error, 99)
    header, *rows = [COLUMNS, *csv_rows(poses)]
    assert header[-1] == "gnss" and {r[-1] for r in rows} == {USED, REJECTED}
    # the footprints say it too, frame by frame (a `gnss` property)
    records = list(frame_records(session, track.source, every=60, track=track))
    assert [properties(r)["gnss"] for r in records] == [poses.gnss[r.index] for r in records]
    assert {r.gnss for r in records} == {USED, REJECTED}
    # each frame's position sigma, from the track the IMU carried over the fixes kept and the
    # keyframes (app.solve.uncertainty): the true error within 3 sigma at 95 % of the frames
    sigma, _ = frame_sigmas(session, track, poses.index)
    assert np.mean(error <= 3.0 * np.sqrt(3.0) * sigma) >= 0.95, np.percentile(error / sigma, 95)


@pytest.mark.gl
def test_a_drag_off_is_caught_within_seconds_and_not_followed(solved):
    session, track, poses, error, t = solved("drag")
    _, _, _, clean_error, _ = solved("clean")
    alarms = _alarms(session)
    assert len(alarms) == 1 and LIE_FROM_S - 1.0 <= alarms[0] <= LIE_FROM_S + 4.0, alarms
    caught = track.registration.gnss.lies[0].caught_s - sample.START_UNIX_S
    # caught by the scene (3 m/s is too slow a step for the IMU): the GNSS's own offset, which
    # may point against the drag, is undone first (5.8-6.8 s at 2 m/s on 40 s sessions,
    # docs/ACCURACY.md; 5.2 s here)
    assert caught - (LIE_FROM_S + 2.5 / 3.0) <= 6.0
    # its fixes, less the drag's line, carry the track where no keyframe registers, and say so
    said = track.registration.gnss.lies[0].said(0.0)
    assert "not used as given" in said and "the fixes' motion less the drag's line" in said, said
    assert (poses.gnss[t < LIE_FROM_S - 3.0] == USED).all()
    assert np.mean(poses.gnss[t >= caught] == REJECTED) >= 0.95
    during = t >= LIE_FROM_S
    assert np.median(error[during]) < 1.5 * np.median(clean_error[during]) + 0.1


@pytest.mark.gl
def test_keyframes_a_lie_lost_register_again_from_the_track_carried_through_it(solved, gl_ctx):
    # where a first pass started keyframes from the lying fixes and lost them (over a survey's
    # turn, bench/bench_gnss_lies.py: a 5 m/s drag 70 m off by the time the scene came back),
    # they are registered again from the track the scene and the IMU carried through the lie
    session, track, _, _, _ = solved("drag")
    reg = track.registration
    [lie] = reg.gnss.lies
    lost_from = sample.START_UNIX_S + LIE_FROM_S + 4.0
    lost = [
        replace(k, used=False, position=None, q=None, reason="lost") if k.time_s >= lost_from else k
        for k in reg.keyframes
    ]
    registrar = Registrar(session, ctx=gl_ctx)
    try:
        again = registrar.retried(lost, track, [(lie.began_s, lie.ended_s)], reg.carried)
        assert registrar.retried(lost, track, [], reg.carried) is lost  # no lie: none tried
        with pytest.raises(Cancelled):  # the viewer closed the session
            registrar.retried(lost, track, [(lie.began_s, lie.ended_s)], reg.carried, lambda: True)
    finally:
        registrar.release()
    assert all(a is b for a, b in zip(again, lost, strict=True) if b.time_s < lost_from)
    found = [a for a in again if a.time_s >= lost_from and a.registered]
    assert len(found) >= 0.9 * sum(k.time_s >= lost_from for k in lost) and all(
        a.used for a in found
    )
    truth = true_track(session)
    true = truth.poses_at(truth.clock.media_s[[a.index for a in found]])
    off = np.linalg.norm(np.array([a.position for a in found]) - true.enu, axis=1)
    assert np.median(off) < 0.3 and off.max() < 1.0, off
    # a solve says how many it took so; a clean one had none to take
    said = replace(reg, retried=tuple(a.time_s for a in found)).summary()
    assert f"{len(found)} lost under a GNSS lie registered again" in said, said
    assert solved("clean")[1].registration.retried == ()


@pytest.mark.gl
def test_keyframes_tried_again_follow_those_found_before_not_a_carry_half_a_period_off(
    solved, gl_ctx, monkeypatch
):
    """A scene whose texture repeats every 14 m east, where a keyframe lands on the copy
    nearest its start (bench/bench_gnss_lies.py, survey seed 4 at 5 m/s: 14 m), and a track
    carried through the lie 8 m east of the truth, past half a period. Started from that carry
    alone every keyframe lands a period east, within the carry's reach; started first from
    where the keyframes found before lead, each lands on the truth. Where the copy is all that
    registers, it is refused while those keyframes lead (within chain_s of the last), taken
    from the carry after."""
    session, track, _, _, _ = solved("drag")
    reg = track.registration
    [lie] = reg.gnss.lies
    spans = [(lie.began_s, lie.ended_s)]
    truth = true_track(session)
    index = np.array([k.index for k in reg.keyframes])
    true_enu = dict(zip(index, truth.poses_at(truth.clock.media_s[index]).enu, strict=True))
    period, east = 14.0, np.array([1.0, 0.0, 0.0])

    class Carried:  # the track carried through the lie, 8 m east of where the platform is
        def frame_camera(self, k: int):
            cam = track.frame_camera(k)
            return posed(cam, np.asarray(cam.position) + 8.0 * east, cam.orientation)

    def nearest_copy(k, start, first=None):  # where a registration from `start` lands
        copy = np.round((np.asarray(start.position)[0] - true_enu[k][0]) / period)
        return _landed(start, true_enu[k] + copy * period * east)

    def copy_only(k, start, first=None):
        return _landed(start, true_enu[k] + period * east)

    monkeypatch.setattr(solve, "frames_at", lambda video, idx, side: ((k, k) for k in idx))
    lost_from = sample.START_UNIX_S + LIE_FROM_S + 4.0
    lost = [
        replace(k, used=False, position=None, q=None, reason="lost") if k.time_s >= lost_from else k
        for k in reg.keyframes
    ]
    none_before = [replace(k, used=False) if k.time_s < lost_from else k for k in lost]
    registrar = Registrar(session, ctx=gl_ctx)
    try:
        registrar.keyframe = nearest_copy
        led = registrar.retried(lost, Carried(), spans, reg.carried)
        unled = registrar.retried(none_before, Carried(), spans, reg.carried)
        registrar.keyframe = copy_only
        copies = registrar.retried(lost, Carried(), spans, reg.carried)
    finally:
        registrar.release()

    def east_of_truth(keyframes):
        return np.array([k.position[0] - true_enu[k.index][0] for k in keyframes if k.time_s >= lost_from])  # fmt: skip

    assert np.abs(east_of_truth(led)).max() < 1e-6  # each led to the truth by the ones before
    # from the carry alone: the copy a period east (every one tried registered there)
    carry_pick = east_of_truth([k for k in unled if k.registered])
    assert len(carry_pick) == len(east_of_truth(unled)) and np.allclose(carry_pick, period)
    last_used = max(k.time_s for k in lost if k.used)
    chain_s = registrar.settings.chain_s
    reach = [k.time_s - last_used <= chain_s for k in copies if k.time_s >= lost_from]
    taken = [k.registered for k in copies if k.time_s >= lost_from]
    assert any(reach) and not all(reach)
    assert taken == [not r for r in reach], (reach, taken)


@pytest.mark.gl
def test_a_frozen_fix_over_a_turn_the_scene_lost_is_carried_by_the_keyframes_found_again(
    tmp_path, gl_ctx
):
    """A survey whose fix freezes at 15 s and which turns over grass at 26-28 s
    (bench/bench_gnss_lies.py survey seed 5): the first pass loses every keyframe after the
    turn, the IMU alone carries the track 50 m off by the clip's end, and the keyframes tried
    again from that carry register only up to the turn. From the carry those make, the rest
    register too (Registrar.retried, RETRY_ROUNDS): the track after the turn stands on the
    scene (one round only: 8.9 m median after 28 s, 21 m at worst)."""
    config = replace(sample.quick_config(40.0), flight="survey", seed=5)
    sample.write_sample_session(tmp_path / "clean", SAMPLE_SCENE, config)
    session = open_session(falsify(tmp_path / "clean", tmp_path / "frozen", Lie("frozen", 15.0)))
    track = registered_track(session, ctx=gl_ctx)
    [lie] = track.registration.gnss.lies
    assert lie.kind == FROZEN
    poses = track.frame_poses()
    truth = true_track(session)
    error = np.linalg.norm(poses.enu - truth.poses_at(truth.clock.media_s[poses.index]).enu, axis=1)
    after = poses.time_s - sample.START_UNIX_S >= 28.0
    assert np.median(error[after]) < 1.0 and error[after].max() < 2.0, np.percentile(error[after], [50, 100])  # fmt: skip
    assert len(track.registration.retried) >= 15, track.registration.retried


def _landed(start, position):
    """(fix, camera, renderings) of a registration that landed at `position` (ENU m) with the
    start's attitude: Registrar.keyframe's outcome."""
    cam = posed(start, position, start.orientation)
    fix = PoseFix(True, "", 40, 30, 0.5, np.asarray(cam.position), np.asarray(cam.orientation))
    return fix, cam, 1


def test_an_outage_is_said_with_its_span_and_its_frames_missing(orbit):
    session = open_session(orbit["outage"])
    poses = solve_track(session, "offline").frame_poses()
    t = poses.time_s - sample.START_UNIX_S
    said = [m.text for m in session.messages.since(0) if m.text.startswith("no GNSS from")]
    # the outage is [6, 12) s of the simulation; said from the last fix before it to the first
    # after it (fixes at 1 Hz, clip times from the first frame)
    span = re.match(r"no GNSS from t = (\d+\.\d) s to (\d+\.\d) s \((\d) s\)", said[0])
    assert len(said) == 1 and span, said
    began, ended = float(span.group(1)), float(span.group(2))
    assert LIE_FROM_S - 1.5 <= began <= LIE_FROM_S and LIE_FROM_S + 5.5 <= ended <= LIE_FROM_S + 7.0
    assert (poses.gnss[(t > LIE_FROM_S) & (t < LIE_FROM_S + 5.5)] == MISSING).all()
    assert (poses.gnss[(t < LIE_FROM_S - 1.5) | (t > LIE_FROM_S + 7.5)] == USED).all()


@pytest.mark.gl
def test_the_fmv_csv_says_what_posed_each_frame_as_the_solve_csv_does(solved):
    """The FMV CSV's trailing `geofuse GNSS Status` column, frame by frame, is the solve CSV's
    `gnss` on a jump session (used before the lie, rejected inside it); the MISB fields keep
    their places in front of it."""
    session, track, poses, _, _ = solved("jump")
    every = 24
    out = io.StringIO()
    write_fmv_csv(frame_records(session, track.source, every=every, track=track), out)
    header, *rows = list(csv.reader(io.StringIO(out.getvalue())))
    assert tuple(header) == FMV_HEADER and tuple(header[: len(FMV_FIELDS)]) == FMV_FIELDS
    assert header[-1] == "geofuse GNSS Status"
    solve = {int(r[0]): r[COLUMNS.index("gnss")] for r in csv_rows(poses)}
    frames = range(0, track.frame_count, every)
    assert len(rows) == len(frames)
    assert [r[-1] for r in rows] == [solve[k] for k in frames]
    assert {r[-1] for r in rows} == {USED, REJECTED}


@pytest.mark.gl
def test_the_viewer_says_what_posed_each_frame(orbit, display, tmp_path):
    """One viewer launch on the jump session, `registered` solved: the state says `used` before
    the lie and `rejected` inside it with the lie's message, the timeline's band is the rejected
    colour under the grab's place for a time inside the lie and the used colour before it, and
    under another source there is no status, said as such."""
    d = tmp_path
    script = d / "script.txt"
    script.write_text(
        f"""0 clock 0.0333333
0 wait registered
0 source registered
0 seek 2
0.3 state {d / "before.json"}
0.4 seek 13
0.8 screenshot {d / "inside.png"}
0.8 state {d / "inside.json"}
1.0 source offline
1.2 state {d / "other.json"}
1.3 quit
"""
    )
    result = run_viewer(display, str(orbit["jump"]), "--script", str(script), "--size", "1280x720")
    assert result.returncode == 0, result.stderr[-3000:]
    before = json.loads((d / "before.json").read_text())
    inside = json.loads((d / "inside.json").read_text())
    other = json.loads((d / "other.json").read_text())
    assert before["errors"] == [] and inside["errors"] == [], inside["errors"]
    assert before["gnss"]["source"] == "registered" and before["gnss"]["frame"] == USED
    g = inside["gnss"]
    assert g["frame"] == REJECTED and g["said"][0].startswith("GNSS this frame: rejected")
    assert ALARM.search(g["said"][1]), g["said"]
    assert other["gnss"]["frame"] is None and other["gnss"]["band"] is None
    assert "only `registered`" in other["gnss"]["said"][0]
    # the band along the scrubber: x at media time 0 and at the end, y top and bottom (px)
    shot = np.asarray(Image.open(d / "inside.png").convert("RGB"), int)
    x0, x1, y0, y1 = g["band"]
    row = int(round((y0 + y1) / 2))

    def pixel(media_s: float) -> np.ndarray:
        return shot[row, int(round(x0 + (x1 - x0) * media_s / g["duration_s"]))]

    for media_s, status in ((11.0, REJECTED), (14.5, REJECTED), (1.5, USED)):
        assert np.abs(pixel(media_s) - g["colours"][status]).max() <= 12, (media_s, pixel(media_s))
