"""GNSS fixes tested against the IMU's motion, and the track carried by it where they are
rejected or missing, with an uncertainty that grows away from the keyframes and fixes and
shrinks at each (issue 52; app.register.inertial). Synthetic fixes along known flights, with the
simulator's GNSS error (app.simulate.sensors) and multipath bursts; the accelerometer the
flight's true acceleration plus a slowly turning error of 0.1 m/s^2 (a phone's 10 mg)."""

from __future__ import annotations

import re
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from app.camera.fixes import MISSING, REJECTED, USED, FixStatus
from app.camera.pinhole import Camera, Intrinsics
from app.export import klv
from app.register.fuse import Correction
from app.register.gnss import (
    BOTH,
    DISAGREES,
    FROZEN,
    IMU,
    REPLAYED,
    SCENE,
    GnssCheck,
    GnssLie,
    check_fixes,
    merged,
)
from app.register.inertial import (
    InertialSettings,
    Motion,
    carried_positions,
    carry,
    chained,
    check_against_imu,
    shifted_back,
)
from app.register.solve import _chained
from app.simulate import sensors
from app.simulate.lies import Lie

RADIUS_M, SPEED = 110.0, 6.0  # the synthetic circle: 110 m at 6 m/s (about the orbit's)
W = SPEED / RADIUS_M  # rad/s
ACC_ERROR = 0.1  # m/s^2, turning once in 120 s


def _circle(t: np.ndarray) -> np.ndarray:
    return np.column_stack(
        [RADIUS_M * np.cos(W * t), RADIUS_M * np.sin(W * t), np.full(len(t), 60.0)]
    )


def _felt(t0: float, t1: float, accel) -> Motion:
    """The accelerometer at 100 Hz from t0 to t1 s: accel(t) (N, 3) m/s^2 plus ACC_ERROR."""
    t = np.arange(t0 - 1.0, t1 + 1.0, 0.01)
    turn = 2 * np.pi * t / 120.0
    error = ACC_ERROR * np.column_stack([np.cos(turn), np.sin(turn), np.zeros(len(t))])
    return Motion(t, accel(t) + error)


def _circle_motion(t0: float, t1: float) -> Motion:
    return _felt(t0, t1, lambda t: -(W**2) * np.column_stack([_circle(t)[:, :2], np.zeros(len(t))]))


def _fixes(seed: int, lie: Lie | None = None, duration_s: float = 60.0):
    """(times (N,) s, fixes (N, 3) ENU m, stated accuracy (N,) m) at 1 Hz along the circle:
    the simulator's GNSS error (2.5 m, 4 m in height, correlated over 30 s), multipath bursts
    (app.simulate.lies' `multipath`, seeded), then the lie."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0)
    err = np.column_stack(
        [sensors.gauss_markov(t, 2.5, 30.0, rng, 2), sensors.gauss_markov(t, 4.0, 30.0, rng)]
    )
    bursts = Lie("multipath", -1.0, seed=seed)
    fixes = bursts.apply(t, _circle(t) + err)
    acc = bursts.accuracy(t, np.full(len(t), 2.5))
    if lie is not None:
        fixes = lie.apply(t, fixes)
    return t, fixes, acc


@pytest.mark.parametrize("seed", range(20))
def test_clean_fixes_with_multipath_bursts_raise_no_alarm(seed):
    """Neither against the IMU nor against the scene (keyframes every 0.5 s at the truth, 0.1 m
    of noise): bursts of 3-8 m, their stated accuracy grown by half of it."""
    t, fixes, acc = _fixes(seed)
    assert (acc > 2.5).any()  # a burst in every track
    check = check_against_imu(_circle_motion(t[0], t[-1]), t, fixes, acc)
    assert check.lies == () and not check.status.rejected.any()
    kt = np.arange(0.0, t[-1], 0.5)
    kp = _circle(kt) + np.random.default_rng(seed).normal(0, 0.1, (len(kt), 3))
    check = check_fixes(t, fixes, acc, kt, kp)
    assert check.lies == () and not check.status.rejected.any()


IMU_LIES = {  # the lie from 30 s, what it is named, the most seconds to the alarm from 30 s
    "frozen": (Lie("frozen", 30.0), FROZEN, 6.0),
    "replay": (Lie("replay", 30.0, back_s=10.0), REPLAYED, 1.0),
    "jump": (Lie("jump", 30.0, size_m=50.0), DISAGREES, 1.0),
}


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("name", list(IMU_LIES))
def test_a_lie_the_imu_did_not_feel_is_caught_without_a_scene(seed, name):
    """A frozen fix while the IMU says the platform flies on at 6 m/s, a replay whose motion
    is not the platform's, a jump whose step it did not feel: caught from the IMU alone (the
    frozen fix once the camera has left it by 5.5 times the fix-to-fix spread, 1-6 s in at
    6 m/s over 8 seeds), named, and the fixes after it rejected for as long as the IMU alone
    can tell the lie from its own drift (10 s asserted: its spread grows as the cube of the
    time and more, so a lie small enough passes again in the end, where the scene's keyframes
    take over)."""
    lie, kind, within_s = IMU_LIES[name]
    t, fixes, acc = _fixes(seed, lie)
    check = check_against_imu(_circle_motion(t[0], t[-1]), t, fixes, acc)
    assert [(found.kind, found.witness) for found in check.lies] == [(kind, IMU)], check.lies
    found = check.lies[0]
    assert lie.from_s <= found.caught_s <= lie.from_s + within_s
    assert abs(found.began_s - lie.from_s) <= 2.0
    caught = t >= found.caught_s
    assert check.status.rejected[caught & (t <= found.caught_s + 10.0)].all()
    assert not check.status.rejected[t < lie.from_s - 2.0].any()


def test_a_frozen_fix_is_rejected_for_as_long_as_it_has_not_moved():
    """Frozen from 30 s of 120: the IMU's spread grows until, 60 s on, the frozen fix would pass
    its test again; every fix of the run that has not moved is a lie all the same (rejected to
    the end, the lie said to last as long)."""
    for seed in range(3):
        t, fixes, acc = _fixes(seed, Lie("frozen", 30.0), duration_s=120.0)
        check = check_against_imu(_circle_motion(t[0], t[-1]), t, fixes, acc)
        [found] = check.lies
        assert found.kind == FROZEN and found.ended_s == t[-1]
        assert check.status.rejected[t >= 30.0].all()


def test_a_fast_drag_off_is_caught_by_the_imu_a_slow_one_is_left_to_the_scene():
    """A 5 m/s drag-off east (a velocity step the IMU did not feel) is caught on at least 6 of
    8 tracks within 8 s; a 1 m/s one hides in the GNSS's own wander and the IMU's drift, and
    raises no alarm (nor a false one): the scene's keyframes catch it (check_fixes)."""
    caught = 0
    for seed in range(8):
        t, fixes, acc = _fixes(seed, Lie("drag", 30.0, speed_mps=5.0))
        check = check_against_imu(_circle_motion(t[0], t[-1]), t, fixes, acc)
        if check.lies and 30.0 <= check.lies[0].caught_s <= 38.0:
            caught += 1
        assert not check.status.rejected[t < 26.0].any()  # said from where it began
    assert caught >= 6
    t, fixes, acc = _fixes(0, Lie("drag", 30.0, speed_mps=1.0))
    assert check_against_imu(_circle_motion(t[0], t[-1]), t, fixes, acc).lies == ()


def test_no_accelerometer_tests_nothing():
    t, fixes, acc = _fixes(0, Lie("jump", 30.0))
    check = check_against_imu(Motion.none(), t, fixes, acc)
    assert check.lies == () and not check.status.rejected.any()


def test_the_motion_integrates_by_hand():
    """Constant 0.5 m/s^2 east for 4 s: from rest, 1 m in 2 s (from 0 or from 1 s), 4 m in 4 s
    (a t^2 / 2); held beyond the samples (no acceleration: the velocity carries on); a device
    turned 90 deg about up with its x axis feeling 2 m/s^2 moves north; gravity is taken off."""
    t = np.linspace(0.0, 4.0, 401)
    m = Motion(t, np.tile([0.5, 0.0, 0.0], (len(t), 1)))
    np.testing.assert_allclose(m.drift([0.0, 0.0, 1.0], [2.0, 4.0, 3.0])[:, 0], [1.0, 4.0, 1.0])
    np.testing.assert_allclose(m.drift([0.0], [6.0])[0, 0], 4.0 + 2.0 * 2.0)
    q_north = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # x -> north
    turned = Motion.of(t, np.tile([2.0, 0.0, 9.80665], (len(t), 1)), [0.0, 4.0], [q_north] * 2)
    np.testing.assert_allclose(turned.acc, np.tile([0.0, 2.0, 0.0], (len(t), 1)), atol=1e-9)


def test_keyframes_are_chained_along_a_turn_by_the_imu():
    """Keyframes at 0, 0.5, 1 s on the circle, the position at 2 s: by the IMU within 1 cm (the
    turn followed); at constant velocity through the last two (no accelerometer) 0.25 m off:
    the chord's velocity is the one at 0.75 s, so the centripetal a = W^2 R adds
    a ((2 - 0.75)^2 - 0.25^2) / 2 to the line."""
    kt = np.array([0.0, 0.5, 1.0])
    m = _circle_motion(0.0, 3.0)
    turn = 2 * np.pi * m.t / 120.0  # the accelerometer's error taken off: the true motion
    m = Motion(m.t, m.acc - ACC_ERROR * np.column_stack([np.cos(turn), np.sin(turn), 0 * m.t]))
    want = _circle(np.array([2.0]))[0]
    assert np.linalg.norm(chained(m, kt, _circle(kt), 2.0) - want) < 0.01
    straight = np.linalg.norm(chained(Motion.none(), kt[1:], _circle(kt[1:]), 2.0) - want)
    assert straight == pytest.approx(W**2 * RADIUS_M * (1.25**2 - 0.25**2) / 2, rel=0.02)


def _line(t: np.ndarray, v: float = 10.0) -> np.ndarray:
    return np.column_stack([v * t, np.zeros(len(t)), np.full(len(t), 70.0)])


def test_the_uncertainty_grows_in_an_outage_and_drops_at_a_keyframe():
    """A straight flight at 10 m/s, its accelerometer 0.1 m/s^2 off: fixes and keyframes to
    20 s, then nothing until keyframes again from 40 s (fixes from 60 s). The position's sigma
    grows monotonically from 20 s to the middle of the gap, is largest there, is back within
    the keyframes' own at the first keyframe after it; forward only (nothing after 20 s) it
    grows to the end. The true error stays within 2 sigma (each axis) at 95 % of the nodes."""
    t = np.arange(0.0, 80.0, 1.0)
    rng = np.random.default_rng(3)
    fixes = _line(t) + np.column_stack([sensors.gauss_markov(t, 2.5, 30.0, rng, 3)])
    use = (t <= 20.0) | (t >= 60.0)
    kt = np.arange(0.0, 80.0, 0.5)
    kt = kt[(kt <= 20.0) | (kt >= 40.0)]
    kp = _line(kt) + rng.normal(0.0, 0.1, (len(kt), 3))
    m = _felt(0.0, 80.0, lambda tt: np.zeros((len(tt), 3)))
    c = carry(m, t, fixes, None, use, kt, kp, InertialSettings(accuracy_m=2.5))
    sigma = c.sigma[:, 0]
    gap = (c.t > 20.0) & (c.t < 40.0)
    peak = int(np.argmax(sigma))
    assert 20.0 < c.t[peak] < 40.0 and sigma[peak] > 3.0 * sigma[c.t <= 20.0].max()
    rising = (c.t >= 20.0) & (c.t <= c.t[peak])
    assert (np.diff(sigma[rising]) >= 0).all()
    assert (np.diff(sigma[gap & (c.t >= c.t[peak])]) <= 0).all()
    assert sigma[c.t == 40.0][0] <= InertialSettings().key_sigma_m
    error = np.abs(c.p - _line(c.t))
    assert np.mean(error <= 2.0 * c.sigma) >= 0.95
    alone = carry(m, t, fixes, None, t <= 20.0, kt[kt <= 20.0], kp[kt <= 20.0], span_s=(0.0, 79.0))
    after = alone.t >= 20.0
    assert (np.diff(alone.sigma[after, 0]) >= 0).all() and alone.sigma[-1, 0] > 20.0


def test_without_an_accelerometer_the_track_is_carried_by_the_fixes_and_keyframes():
    """No accelerometer (a drone clip: Motion.none()): the acceleration's error is then no
    state and its spread stays 0, which left the smoother's predicted covariance singular (a
    LinAlgError on every DJI clip registered with its fixes). The straight 10 m/s flight's
    fixes to 20 s and from 40 s, keyframes through the gap: the track follows them there
    (within 0.5 m), and its sigma is finite, grows away from them and shrinks at them."""
    t = np.arange(0.0, 60.0, 1.0)
    rng = np.random.default_rng(5)
    fixes = _line(t) + rng.normal(0.0, 1.0, (len(t), 3))
    use = (t <= 20.0) | (t >= 40.0)
    kt = np.arange(0.0, 60.0, 0.5)
    kp = _line(kt) + rng.normal(0.0, 0.05, (len(kt), 3))
    c = carry(Motion.none(), t, fixes, None, use, kt, kp, span_s=(0.0, 59.0))
    assert not c.felt and np.isfinite(c.p).all() and np.isfinite(c.sigma).all()
    gap = (c.t > 20.0) & (c.t < 40.0)
    np.testing.assert_allclose(c.p[gap], _line(c.t[gap]), atol=0.5)
    sparse = carry(Motion.none(), t, fixes, None, use, kt[kt <= 20.0], kp[kt <= 20.0])
    middle = sparse.sigma[np.argmin(np.abs(sparse.t - 30.0)), 0]
    assert middle > 2.0 * sparse.sigma[np.argmin(np.abs(sparse.t - 10.0)), 0]


def test_a_frozen_stretch_nothing_registered_is_carried_by_the_imu():
    """A frozen fix from 30 s on a straight 6 m/s flight, no keyframe from 40 to 52 s: the
    rejected fixes are replaced by where an honest fix would have been (the position the IMU
    carries between the keyframes around, plus the GNSS's own error), the gap's positions
    within 0.5 m of the truth (holding the last one would leave them up to 36 m behind) and
    the honest fixes within the GNSS's 2 m offset of it; an outage is filled the same way."""
    t = np.arange(0.0, 90.0, 1.0)
    kt = np.arange(0.0, 90.0, 0.5)
    kt = kt[(kt <= 40.0) | (kt >= 52.0)]
    line = lambda tt: _line(tt, 6.0)  # noqa: E731
    fixes = Lie("frozen", 30.0).apply(t, line(t) + [1.5, -1.0, 1.0])
    check = check_fixes(t, fixes, np.full(len(t), 2.5), kt, line(kt))
    assert [found.kind for found in check.lies] == [FROZEN]
    m = _felt(0.0, 90.0, lambda tt: np.zeros((len(tt), 3)))
    rejected = check.status.rejected
    c = carry(m, t, fixes, np.full(len(t), 2.5), ~rejected, kt, line(kt))
    gap = (c.t > 40.0) & (c.t < 52.0)
    np.testing.assert_allclose(c.p[gap], line(c.t[gap]), atol=0.5)
    from app.camera.trajectory import PositionTrack
    from app.geodesy.enu import LocalFrame

    frame = LocalFrame(34.8, 113.5, 100.0)
    geo = frame.enu_to_geodetic(fixes)
    track = PositionTrack.from_fixes(t, geo[:, 0], geo[:, 1], geo[:, 2])
    moved = carried_positions(track, c, rejected, (0.0, 89.0), frame)
    honest = frame.geodetic_to_enu(moved.lat, moved.lon, moved.h)
    np.testing.assert_allclose(honest[rejected], line(t[rejected]), atol=2.5)
    np.testing.assert_array_equal(moved.lat[~rejected], track.lat[~rejected])
    out = ~((t > 60.0) & (t < 75.0))  # an outage: filled at the carried nodes, 4 a second
    track = PositionTrack.from_fixes(t[out], geo[out, 0], geo[out, 1], geo[out, 2])
    filled = carried_positions(track, c, rejected[out], (0.0, 89.0), frame)
    assert len(filled.t) > len(track.t) + 50 and np.diff(filled.t).max() <= 1.0


def test_two_witnesses_of_one_lie_are_said_once():
    """The scene's and the IMU's test of the same frozen fix: one lie, from the earlier start
    and alarm to the later end, named frozen, both witnesses said; a lie only one saw stays
    its own."""
    t = np.arange(0.0, 60.0, 1.0)
    off = np.array([1.0, 0.0, 0.0])
    scene = GnssCheck(
        FixStatus(t, t >= 31.0),
        (GnssLie(31.0, 33.0, 50.0, 120.0, 59.0, off, DISAGREES),),
        np.zeros((len(t), 3)),
    )
    imu = GnssCheck(
        FixStatus(t, (t >= 30.0) | ((t >= 5.0) & (t <= 7.0))),
        (
            GnssLie(5.0, 5.0, 6.0, 40.0, 7.0, np.zeros(3), DISAGREES, witness=IMU),
            GnssLie(30.0, 31.0, 40.0, 60.0, 59.0, np.zeros(3), FROZEN, witness=IMU),
        ),
        np.zeros((len(t), 3)),
    )
    both = merged(scene, imu)
    assert [(lie.kind, lie.witness) for lie in both.lies] == [(DISAGREES, IMU), (FROZEN, BOTH)]
    lie = both.lies[1]
    assert (lie.began_s, lie.caught_s, lie.ended_s, lie.worst_m) == (30.0, 31.0, 59.0, 120.0)
    np.testing.assert_array_equal(lie.offset, off)
    assert both.status.rejected.sum() == 33
    text = lie.said(0.0)
    assert re.match(r"GNSS frozen from t = 30\.0 s, 120 m behind the scene and the IMU's motion by t = 50\.0 s", text), text  # fmt: skip
    assert "the scene's registered keyframes and the IMU's motion there" in text
    assert GnssLie(5.0, 5.0, 6.0, 40.0, 7.0, off, witness=SCENE).said(0.0).startswith("GNSS disagrees with the scene from")  # fmt: skip
    # a drag-off both caught: it began where the scene's residual left the GNSS's own offset,
    # not where the IMU's, which is no distance walked, was read back to (survey seed 5's 5 m/s
    # drag from 15 s was said from 9 s); the fixes only the IMU's start took in are kept
    scene = GnssCheck(
        FixStatus(t, t >= 15.0),
        (GnssLie(16.0, 18.0, 50.0, 120.0, 59.0, off, DISAGREES),),
        np.zeros((len(t), 3)),
    )
    imu = GnssCheck(
        FixStatus(t, t >= 9.0),
        (GnssLie(9.0, 18.0, 40.0, 60.0, 59.0, np.zeros(3), DISAGREES, witness=IMU),),
        np.zeros((len(t), 3)),
    )
    [lie] = merged(scene, imu).lies
    assert (lie.began_s, lie.caught_s, lie.witness) == (16.0, 18.0, BOTH)
    assert list(t[merged(scene, imu).status.rejected][:2]) == [15.0, 16.0]
    # one the scene dates after the IMU's alarm begins no later than that alarm
    late = replace(scene, lies=(replace(scene.lies[0], began_s=20.0, caught_s=21.0),))
    assert merged(late, imu).lies[0].began_s == 18.0
    # a jump inside a stretch that registered nothing (fog over 12-30 s): the scene dates it
    # by the line across the stretch (11 s), the IMU caught the step at the fix it stepped at
    # (15 s): it began there, and the fixes before it are kept
    fog = GnssCheck(
        FixStatus(t, t >= 11.0),
        (GnssLie(11.0, 31.0, 31.0, 196.0, 59.0, off, DISAGREES),),
        np.where(((t >= 12.0) & (t < 31.0))[:, None], np.nan, 0.0) * np.ones((1, 3)),
    )
    step = GnssCheck(
        FixStatus(t, t >= 15.0),
        (GnssLie(15.0, 15.0, 15.0, 900.0, 59.0, np.zeros(3), DISAGREES, witness=IMU),),
        np.zeros((len(t), 3)),
    )
    both = merged(fog, step)
    assert [(lie.began_s, lie.caught_s) for lie in both.lies] == [(15.0, 15.0)]
    np.testing.assert_array_equal(both.status.rejected, t >= 15.0)
    # one the IMU caught only after it began is no step: the scene's start holds
    ramp = replace(step, lies=(replace(step.lies[0], caught_s=17.0),))
    assert merged(fog, ramp).lies[0].began_s == 11.0


def test_multipath_bursts_are_seeded_and_stated():
    """Lie('multipath'): the same bursts for the same seed, none outside the lie, at least one
    in a short track, the stated accuracy grown by half the pull in quadrature."""
    t = np.arange(0.0, 40.0, 1.0)
    lie = Lie("multipath", 10.0, seed=4)
    pull = lie.offset_enu(t)
    np.testing.assert_array_equal(pull, Lie("multipath", 10.0, seed=4).offset_enu(t))
    assert not pull[t < 10.0].any() and np.abs(pull).max() > 2.0
    acc = lie.accuracy(t, np.full(len(t), 2.5))
    h = np.linalg.norm(pull[:, :2], axis=1)
    np.testing.assert_allclose(acc, np.hypot(2.5, 0.5 * h), atol=1e-9)


def test_the_klv_says_what_positioned_each_frame():
    """ST 0601 item 124 (Positioning Method Source): the satellite bit where the fix was used,
    the INS bit alone where it was not and the IMU carried the track, no item where nothing
    fits (no IMU) or nothing is known."""
    assert klv.positioning(USED, True) == klv.positioning(USED, False) == klv.GPS_BIT == 2
    assert klv.positioning(REJECTED, True) == klv.positioning(MISSING, True) == klv.INS_BIT == 1
    assert klv.positioning(REJECTED, False) is None and klv.positioning(None, True) is None
    carried = SimpleNamespace(felt=True)
    reg = SimpleNamespace(keyframes=(SimpleNamespace(used=True),), carried=carried)
    assert klv.carried_by_imu(SimpleNamespace(source="registered", registration=reg))
    assert not klv.carried_by_imu(SimpleNamespace(source="offline", registration=reg))


def _carried_over_kept(t, fixes, acc, motion, check, kt=None, kp=None):
    kt = np.zeros(0) if kt is None else kt
    kp = np.zeros((0, 3)) if kp is None else kp
    return carry(motion, t, fixes, acc, ~check.status.rejected, kt, kp)


@pytest.mark.parametrize("seed", range(4))
def test_a_jump_whose_offset_holds_is_moved_back_and_carries_the_track(seed):
    """A 200 m jump east from 30 s and no scene at all: the IMU catches it, and its fixes, moved
    back by the jump, are honest again (the position plus the GNSS's own error): they are used
    from the jump on, the offset found within 2.5 sigma of the fixes' accuracy (2.5 m) of the
    200 m, and the track carried over them stays within 7.5 m (3 sigma) of the truth to the end;
    carried by the IMU alone over the same 30 s it drifts off by more (its 0.1 m/s^2 error)."""
    t, fixes, acc = _fixes(seed, Lie("jump", 30.0, size_m=200.0))
    m = _circle_motion(t[0], t[-1])
    check = check_against_imu(m, t, fixes, acc)
    assert [found.kind for found in check.lies] == [DISAGREES]
    alone = _carried_over_kept(t, fixes, acc, m, check)
    back = shifted_back(m, t, fixes, acc, check, alone)
    after = t >= 30.0
    assert back.use[after].mean() >= 0.95 and not back.use[~after].any()
    [lie] = back.check.lies
    assert np.linalg.norm(lie.shift - [200.0, 0.0, 0.0]) < 2.5 * 2.5
    assert lie.shifted_s[0] == pytest.approx(30.0, abs=1.0)
    np.testing.assert_allclose(back.enu[back.use], fixes[back.use] - lie.shift)
    carried = carry(m, t, back.enu, acc, ~check.status.rejected | back.use, [], np.zeros((0, 3)))
    end = carried.t >= 30.0
    error = np.linalg.norm(carried.p[end] - _circle(carried.t[end]), axis=1)
    drift = np.linalg.norm(alone.p[end] - _circle(alone.t[end]), axis=1)
    assert error.max() < 7.5 and drift.max() > error.max()
    said = lie.said(0.0)
    assert "not used as given" in said and re.search(r"moved back by (19\d|20\d) m \(E \+", said), (
        said
    )


def test_a_drag_off_and_a_frozen_fix_are_not_moved_back():
    """A drag-off has no step at its start and a frozen fix no steady offset: neither is moved
    back, both stay rejected and the track stands on the IMU (and the scene) there."""
    for lie in (Lie("drag", 30.0, speed_mps=5.0), Lie("frozen", 30.0)):
        t, fixes, acc = _fixes(1, lie)
        m = _circle_motion(t[0], t[-1])
        check = check_against_imu(m, t, fixes, acc)
        assert check.lies, lie
        back = shifted_back(m, t, fixes, acc, check, _carried_over_kept(t, fixes, acc, m, check))
        assert not back.use.any() and back.check is check
        np.testing.assert_array_equal(back.enu, fixes)
        # the drag-off's fixes are named for `carry` to learn its line; a frozen fix's are not
        after = check.status.rejected & (t >= check.lies[0].began_s)
        assert ((back.drags.lie[after] == 0) if lie.kind == "drag" else (back.drags.lie < 0)).all()
        assert (back.drags.lie[t < 25.0] < 0).all()
        assert back.drags.steady_s[0] == check.lies[0].caught_s


@pytest.mark.parametrize("seed", range(1, 5))
def test_a_drag_offs_fixes_less_its_line_carry_the_track_where_nothing_registers(seed):
    """A 5 m/s drag-off east from 20 s; keyframes every 0.5 s at the truth (0.1 m of noise) to
    35 s, then none for 24 s (a turn over grass). Carried by the IMU alone (its 0.1 m/s^2
    error) the track drifts 16-23 m off by the end, its sigma 54 m; carried on the drag's
    fixes less the drag's line (learnt from the keyframes under it, and the IMU), it stays
    closer all through the blind stretch, its sigma under half the IMU's and still covering
    the error (within the norm of the per-axis sigma)."""
    t, fixes, acc = _fixes(seed, Lie("drag", 20.0, speed_mps=5.0))
    m = _circle_motion(t[0], t[-1])
    kt = np.arange(0.0, 35.0, 0.5)
    kp = _circle(kt) + np.random.default_rng(seed).normal(0, 0.1, (len(kt), 3))
    check = merged(check_fixes(t, fixes, acc, kt, kp), check_against_imu(m, t, fixes, acc))
    assert [lie.kind for lie in check.lies] == [DISAGREES]
    alone = _carried_over_kept(t, fixes, acc, m, check, kt, kp)
    back = shifted_back(m, t, fixes, acc, check, alone, t_key=kt, enu_key=kp)
    assert not back.use.any() and (back.drags.lie[t > 25.0] == 0).all()
    dragged = carry(m, t, fixes, acc, ~check.status.rejected, kt, kp, drags=back.drags)
    blind = alone.t >= 35.0
    np.testing.assert_array_equal(dragged.t, alone.t)
    err = {
        name: np.linalg.norm(c.p[blind] - _circle(c.t[blind]), axis=1)
        for name, c in (("alone", alone), ("dragged", dragged))
    }
    sigma = {
        name: np.linalg.norm(c.sigma[blind], axis=1)
        for name, c in (("alone", alone), ("dragged", dragged))
    }
    assert err["alone"].max() > 15.0
    assert err["dragged"].max() < err["alone"].max()
    assert np.median(err["dragged"]) < np.median(err["alone"])
    assert sigma["dragged"][-1] < 0.5 * sigma["alone"][-1]
    assert (err["dragged"] <= sigma["dragged"]).all()


def test_a_jump_then_a_drag_off_uses_the_moved_fixes_only_until_the_drag_shows():
    """A 100 m jump at 30 s, then from 40 s a 3 m/s drag-off on top, keyframes every 0.5 s at
    the truth (0.1 m of noise): the jump's fixes moved back by the offset measured at its start
    against the track the keyframes hold (within the fixes' own error) are used from the jump until the drag shows against the scene; none is
    used once the drag has gone 5 m (the scene's floor) past its start, at 41.7 s."""
    t, fixes, acc = _fixes(2)
    fixes = fixes + np.where(t[:, None] >= 30.0, [100.0, 0.0, 0.0], 0.0)
    fixes[:, 1] += np.where(t >= 40.0, 3.0 * (t - 40.0), 0.0)
    m = _circle_motion(t[0], t[-1])
    kt = np.arange(0.0, t[-1], 0.5)
    kp = _circle(kt) + np.random.default_rng(2).normal(0, 0.1, (len(kt), 3))
    check = merged(check_fixes(t, fixes, acc, kt, kp), check_against_imu(m, t, fixes, acc))
    assert check.status.rejected[t >= 30.0].all()
    carried = _carried_over_kept(t, fixes, acc, m, check, kt, kp)
    back = shifted_back(m, t, fixes, acc, check, carried, t_key=kt, enu_key=kp)
    used = t[back.use]
    assert len(used) >= 6 and used[0] == pytest.approx(30.0, abs=1.0)
    assert used[-1] < 40.0 + 5.0 / 3.0 + 2.0 and not back.use[t >= 45.0].any()
    shift = [lie.shift for lie in back.check.lies if lie.shift is not None]
    # within the fixes' own error then (a multipath burst of 5-7 m at the jump on this track)
    bound = 2.5 * acc[(t >= 30.0) & (t <= 32.0)].max()
    assert len(shift) == 1 and np.linalg.norm(shift[0] - [100.0, 0.0, 0.0]) < bound


def test_a_tilted_attitude_is_turned_back_by_the_registered_rotation():
    """A platform at rest whose attitude errs by 2 deg of roll (the tilt an attitude filter
    takes from a turn's acceleration): its world acceleration errs by g sin 2 deg = 0.34 m/s^2
    sideways, 2.7 m over 4 s; turned by the rotation registration found (-2 deg about the same
    axis) it is zero again, over the span asked (a sample either side)."""
    t = np.linspace(0.0, 10.0, 1001)
    tilt = np.radians(2.0)
    q = np.tile([np.cos(tilt / 2), np.sin(tilt / 2), 0.0, 0.0], (len(t), 1))  # roll about east
    m = Motion.of(t, np.tile([0.0, 0.0, 9.80665], (len(t), 1)), [0.0, 10.0], q[:2])
    assert np.linalg.norm(m.acc[0, :2]) == pytest.approx(9.80665 * np.sin(tilt), rel=1e-6)
    assert np.linalg.norm(m.drift([2.0], [6.0])[0, :2]) == pytest.approx(
        0.5 * 9.80665 * np.sin(tilt) * 16.0, rel=1e-3
    )
    back = m.turned([-tilt, 0.0, 0.0], (2.0, 6.0))
    np.testing.assert_allclose(back.acc, 0.0, atol=1e-9)
    assert back.t[0] < 2.0 <= back.t[1] and back.t[-2] <= 6.0 < back.t[-1]
    assert Motion.none().turned([0.1, 0.0, 0.0]) is not None


def test_keyframes_are_chained_under_the_attitude_they_registered():
    """Keyframes on a straight 10 m/s line at 0-3 s, the IMU's attitude 2 deg off in roll from
    the start: chained to 7 s by that motion the position errs by the tilt's drift (0.34 m/s^2
    over the 4 s past the keyframes: metres); under the keyframes' registered rotation, which
    undoes the tilt, within 5 cm."""

    t = np.linspace(-1.0, 9.0, 1001)
    tilt = np.radians(2.0)
    q = np.tile([np.cos(tilt / 2), np.sin(tilt / 2), 0.0, 0.0], (2, 1))
    m = Motion.of(t, np.tile([0.0, 0.0, 9.80665], (len(t), 1)), [-1.0, 9.0], q)
    kt = np.array([0.0, 1.0, 2.0, 3.0])
    keys = [
        SimpleNamespace(time_s=k, registered=True, position=_line(np.array([k]))[0]) for k in kt
    ]
    start = Camera.create(Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0), np.zeros(3), [1, 0, 0, 0])
    want = _line(np.array([7.0]))[0]
    off = np.linalg.norm(_chained(keys, 7.0, start, 10.0, m).position - want)
    fix = Correction(kt, np.zeros((4, 3)), np.tile([-tilt, 0.0, 0.0], (4, 1)))
    on = np.linalg.norm(_chained(keys, 7.0, start, 10.0, m, fix).position - want)
    assert off > 1.0 and on < 0.05, (off, on)
