"""GNSS that fails or lies (issue 52): every frame says what posed it (the solve CSV's `gnss`
column), a jump and a drag-off are caught against the scene's registered keyframes, said once
with their time and not followed, outages are said with their span, a clean session raises no
alarm. The sessions are simulated (a drone orbit over a world that differs from its model),
their gnss.csv falsified by app.simulate.lies."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from app.camera.fixes import MISSING, REJECTED, USED, FixStatus
from app.export.gis import properties
from app.export.records import frame_records
from app.register.gnss import check_fixes
from app.register.solve import registered_track
from app.session import open_session
from app.simulate import sensors
from app.simulate import session as sample
from app.simulate.lies import Lie, falsify
from app.simulate.sample import SAMPLE_SCENE
from app.solve.accuracy import true_track
from app.solve.track import COLUMNS, csv_rows, solve_track

DURATION_S = 24.0
LIE_FROM_S = 10.0  # clip seconds (from the simulation's start)
ALARM = re.compile(r"GNSS disagrees with the scene from .*?t = (\d+\.\d) s")


# --- the test on its own, on synthetic fixes -------------------------------------------------------


def _circle(t: np.ndarray) -> np.ndarray:
    """ENU m along a 110 m circle at 60 m flown at about 6 m/s, at times t (s)."""
    return np.column_stack([110 * np.cos(t / 18), 110 * np.sin(t / 18), np.full(len(t), 60.0)])


def _fixes(seed: int, lie: Lie | None = None, duration_s: float = 120.0):
    """Fixes at 1 Hz along a 6 m/s circle with a GNSS error of 2.5 m (1 sigma per axis,
    correlated over 30 s, as the simulator's) and the lie added; keyframes every 0.5 s at the
    true positions with 0.1 m of noise and one in 20 registered 6 m wrong."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0)
    err = np.column_stack([sensors.gauss_markov(t, 2.5, 30.0, rng, 2), np.zeros(len(t))])
    fixes = _circle(t) + err
    if lie is not None:
        fixes[:, 0] += lie.offset_m(t)
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
    # no interpolation across the jump: near the clean run's error everywhere, not metres off
    assert np.median(error[t >= LIE_FROM_S]) < 1.5 * np.median(clean_error[t >= LIE_FROM_S]) + 0.1
    assert np.percentile(error, 99) < 2.0, np.percentile(error, 99)
    header, *rows = [COLUMNS, *csv_rows(poses)]
    assert header[-1] == "gnss" and {r[-1] for r in rows} == {USED, REJECTED}
    # the footprints say it too, frame by frame (a `gnss` property)
    records = list(frame_records(session, track.source, every=60, track=track))
    assert [properties(r)["gnss"] for r in records] == [poses.gnss[r.index] for r in records]
    assert {r.gnss for r in records} == {USED, REJECTED}


@pytest.mark.gl
def test_a_drag_off_is_caught_within_seconds_and_not_followed(solved):
    session, track, poses, error, t = solved("drag")
    _, _, _, clean_error, _ = solved("clean")
    alarms = _alarms(session)
    assert len(alarms) == 1 and LIE_FROM_S - 1.0 <= alarms[0] <= LIE_FROM_S + 4.0, alarms
    caught = track.registration.gnss.lies[0].caught_s - sample.START_UNIX_S
    assert caught - (LIE_FROM_S + 2.5 / 3.0) <= 5.0
    assert (poses.gnss[t < LIE_FROM_S - 3.0] == USED).all()
    assert np.mean(poses.gnss[t >= caught] == REJECTED) >= 0.95
    during = t >= LIE_FROM_S
    assert np.median(error[during]) < 1.5 * np.median(clean_error[during]) + 0.1


def test_an_outage_is_said_with_its_span_and_its_frames_missing(orbit):
    session = open_session(orbit["outage"])
    poses = solve_track(session, "offline").frame_poses()
    t = poses.time_s - sample.START_UNIX_S
    said = [m.text for m in session.messages.since(0) if m.text.startswith("no GNSS from")]
    # the outage is [10, 16) s of the simulation; said from the last fix before it to the first
    # after it (fixes at 1 Hz, clip times from the first frame)
    span = re.match(r"no GNSS from t = (\d+\.\d) s to (\d+\.\d) s \((\d) s\)", said[0])
    assert len(said) == 1 and span, said
    began, ended = float(span.group(1)), float(span.group(2))
    assert LIE_FROM_S - 1.5 <= began <= LIE_FROM_S and LIE_FROM_S + 5.5 <= ended <= LIE_FROM_S + 7.0
    assert (poses.gnss[(t > LIE_FROM_S) & (t < LIE_FROM_S + 5.5)] == MISSING).all()
    assert (poses.gnss[(t < LIE_FROM_S - 1.5) | (t > LIE_FROM_S + 7.5)] == USED).all()
