"""GNSS that lies in a live feed (issue 52, forward only): the fixes tested against the keyframes
live registration keeps, as they arrive. First the test on its own, fed keyframes by hand (its
alarm times derived by hand from the threshold and the one-sided median), then drone downlinks
whose KLV jumps 200 m or drags off at 2 m/s, sent over the loopback by the test and drawn by
`geofuse live`'s pipeline against the textured sample model: the alarm said once at the second
keyframe past the moment the lie exceeds the threshold, the frames after it `rejected`, and the
drawn pose standing on the scene, as close to the truth as before the lie. (A clean feed raises
no alarm: tests/test_live_register.py.) The recording of each, solved afterwards as a file,
rejects the frames drawn `used` before the alarm too."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.camera.fixes import MISSING, REJECTED, USED
from app.camera.intrinsics import Intrinsics
from app.camera.pinhole import Camera
from app.core.messages import Messages
from app.footage.clips import open_any
from app.geodesy import rotations
from app.io.mavlink import MavlinkTelemetry
from app.live.gnss_watch import JUMP_FAR, GnssWatch
from app.live.pose import JUMP_EDGE_S, JUMP_RUN
from app.live.register import LIE_FIT, Kept, LiveRegistration, shift_model
from app.live.run import LiveOptions, run_sent
from app.register.gnss import FROZEN, GnssLie
from app.register.keyframe import PoseFix
from app.simulate import drone, sensors
from app.simulate.downlink import SITE, sample_layer, write_downlinks
from app.simulate.lies import Lie
from app.solve.track import solve_track
from app.ui import gnss as viewer_gnss

NOT_USED = "not used (caught at t = {:.1f} s; the track stands on the scene's registered keyframes there)"  # fmt: skip


def _feed_keyframes(watch: GnssWatch, t: np.ndarray, fix: np.ndarray, scene: np.ndarray) -> list:
    return [watch.keyframe(t[i], fix[i], scene[i]) for i in range(len(t))]


def _circle(t: np.ndarray) -> np.ndarray:
    """A camera circling at 6 m/s (ENU m): the scene's positions."""
    a = 0.06 * t
    return np.column_stack([100 * np.cos(a), 100 * np.sin(a), np.full(len(t), 60.0)])


# --- the test on its own ---------------------------------------------------------------------------


def test_a_drag_is_said_as_it_walks_off_and_its_end_when_it_agrees():
    """Keyframes every second, the fix 2 m/s east of the scene from 20 s to 40 s, its stated
    accuracy 2 m: the threshold is max(5, 4.5 x 2) = 9 m, passed by the raw residual 2 (t - 20)
    at 24.5 s and by the median of the newest three one keyframe later (median(8, 10, 12) = 10
    at 26 s). The drift is caught before that, at 25 s: the median at the newest keyframe
    (window 5, shrunk to 23-25 s: 6, 8, 10 -> 8 m) lies 8 m farther from the GNSS's own offset
    (0) than the one 6 s before it (DRIFT_S; 19 s: 0), past max(6, 2.4 x 2) = 6 m, and each half
    moved it the same way by 4 m (the median at 22 s: 0, 2, 4, 6, 8 -> 4); at 24 s it
    had gone 6 m (4, 6, 8 -> 6), not past 6. The lie began at 20 s (where the test dates it).
    From 41 s the fix is back on the scene; the median says so at 42 s (median(40, 0, 0) = 0),
    and after merge_s (10 s) of agreeing keyframes, at 52 s, it is said and the fixes used
    again. The lie went farthest at 40 s: median(36, 38, 40) = 38 m."""
    t = np.arange(0.0, 60.0)
    scene = _circle(t)
    fix = scene.copy()
    fix[:, 0] += np.where((t >= 20) & (t < 41), 2.0 * (t - 20), 0.0)
    said = Messages()
    watch = GnssWatch(said)
    verdicts = [watch.keyframe(t[i], fix[i], scene[i], 2.0) for i in range(len(t))]
    lying = np.array([v.lying for v in verdicts])
    assert not lying[:25].any() and lying[25:52].all() and not lying[52:].any()
    # the raw test (where the drawn pose turns to the scene at once): from 25 s
    assert [v.disagrees for v in verdicts].index(True) == 25
    assert verdicts[0].threshold_m == 9.0
    assert said.items == [
        "GNSS disagrees with the scene from t = 20.0 s, 8 m by t = 25.0 s: " + NOT_USED.format(25.0),
        "GNSS agrees with the scene again from t = 42.0 s: used again",
    ]  # fmt: skip
    lie = watch.lies[0]
    assert (lie.began_s, lie.caught_s, lie.ended_s) == (20.0, 25.0, 41.0)
    assert lie.worst_m == pytest.approx(38.0) and lie.worst_s == 40.0


def test_a_jump_is_said_at_its_first_keyframe():
    """A 200 m jump east at 20 s (accuracy stated by none: the default 5 m, threshold 22.5 m):
    the keyframe at 20 s has its own fix 200 m off, past 3 x 22.5 m (JUMP_FAR), the one before
    within: the alarm there, the lie dated from it (the median of the newest three, (0, 0, 200)
    -> 0, passes only at 21 s). Its message is GnssLie.said's, as files say it, with the feed's
    UTC. The same jump within the first three keyframes tested (before live registration's gate
    is on) waits for the median; a step after a keyframe already off is the median's, dated
    from that keyframe."""
    t = np.arange(0.0, 40.0)
    scene = _circle(t)
    fix = scene + np.where(t >= 20, 200.0, 0.0)[:, None] * [1.0, 0.0, 0.0]
    said = Messages()
    start = drone.START.timestamp()
    watch = GnssWatch(said, utc_of=lambda s: start + s)
    lying = [v.lying for v in _feed_keyframes(watch, t, fix, scene)]
    assert lying.index(True) == 20 and all(lying[20:])
    lie = watch.lies[0]
    assert (lie.began_s, lie.caught_s, lie.worst_m) == (20.0, 20.0, pytest.approx(200.0))
    want = GnssLie(20.0, 20.0, 20.0, 200.0, 20.0, np.zeros(3)).said(0.0, lambda s: start + s)
    assert said.items == [want]
    assert want.startswith("GNSS disagrees with the scene from 09:47:00 (t = 20.0 s), 200 m by")
    assert watch.line().endswith(
        "GNSS disagrees from t = 20.0 s (caught at t = 20.0 s, 200 m by t = 20.0 s), going on at the end"
    )
    early = scene + np.where(t >= 2, 200.0, 0.0)[:, None] * [1.0, 0.0, 0.0]  # the third keyframe
    watch = GnssWatch(Messages())
    assert [v.lying for v in _feed_keyframes(watch, t, early, scene)].index(True) == 3
    ramp = scene.copy()  # 30 m off at 19 s (past 22.5 m), then 200 m: the median's alarm at 20 s
    ramp[t == 19, 0] += 30.0  # (0, 30, 200 -> 30 m), dated from the first keyframe off, 19 s
    ramp[t >= 20, 0] += 200.0
    watch = GnssWatch(Messages())
    assert [v.lying for v in _feed_keyframes(watch, t, ramp, scene)].index(True) == 20
    assert watch.lies[0].began_s == 19.0


def test_a_frozen_fix_is_named_frozen_from_its_first_repeat():
    """The fix stops at 20 s while the scene flies on at 6 m/s: the residual grows 6 m a second
    (raw 12, 18, 24 m at 22-24 s). The drift is caught at 24 s: the newest median (22-24 s:
    18 m) is 18 m farther from the GNSS's own offset than 6 s before (0), past max(6, 2.4 x 5)
    = 12 m, each half the same way (the 21 s median: 0, 0, 6, 12, 18 -> 6); at 23 s, 12 m (6,
    12, 18), not past 12 (the level test, 4.5 x 5 = 22.5 m, one keyframe later). Every fix
    from 20 s repeats the one at 20 s (within 2 cm for 2 s and more): named frozen, from 20 s."""
    t = np.arange(0.0, 40.0)
    scene = _circle(t)
    fix = scene.copy()
    fix[t >= 20] = scene[20]
    said = Messages()
    watch = GnssWatch(said)
    lying = [v.lying for v in _feed_keyframes(watch, t, fix, scene)]
    assert lying.index(True) == 24
    assert watch.lies[0].kind == FROZEN and watch.lies[0].began_s == 20.0
    assert said.items[0].startswith("GNSS frozen from t = 20.0 s, ")


def test_clean_fixes_with_gnss_noise_raise_no_alarm():
    """Three 120 s tracks whose fixes wander as the simulator's GNSS does (2.5 m per axis,
    correlated over 30 s; 4 m in height), tested at their stated 2.5 m (11.25 m): no alarm
    (over 200 such tracks, one: docs/ACCURACY.md)."""
    t = np.arange(0.0, 120.0)
    for seed in (1, 2, 3):
        rng = np.random.default_rng(seed)
        noise = np.column_stack(
            [sensors.gauss_markov(t, 2.5, 30.0, rng, 2), sensors.gauss_markov(t, 4.0, 30.0, rng)]
        )
        scene = _circle(t) + rng.normal(0.0, 0.2, (len(t), 3))
        watch = GnssWatch(Messages(), 2.5)
        for i in range(len(t)):
            assert not watch.keyframe(t[i], _circle(t[i : i + 1])[0] + noise[i], scene[i]).lying
        assert watch.lies == [] and watch.line().endswith("no lie")


def test_a_burst_of_multipath_the_receiver_states_raises_no_alarm_as_it_ends():
    """Multipath pulls the fix 12 m west for 4 s (keyframes at 20-23 s), the receiver stating
    4.6 m then (its threshold 4.5 x 4.6 = 20.7 m), 2.5 m before and after (11.25 m). At 24 s the
    fix is back, but the median of the newest three (12, 12, 0 -> 12 m) still carries the burst:
    held to the newest fix's 2.5 m it passed 11.25 m (seen on 4 of 100 simulated 120 s feeds
    with the simulator's bursts); held to the least sure fix it was taken over (4.6 m) it does
    not. At 25 s: median(12, 0, 0) = 0."""
    t = np.arange(0.0, 40.0)
    scene = _circle(t)
    fix = scene.copy()
    burst = (t >= 20) & (t < 24)
    fix[burst, 0] -= 12.0
    acc = np.where(burst, 4.6, 2.5)
    watch = GnssWatch(Messages())
    verdicts = [watch.keyframe(t[i], fix[i], scene[i], acc[i]) for i in range(len(t))]
    assert not any(v.lying for v in verdicts) and watch.lies == []
    assert verdicts[20].threshold_m == pytest.approx(20.7) and verdicts[24].threshold_m == 11.25


@pytest.mark.parametrize("kind", ["drag", "jump"])
def test_a_lie_begun_where_no_keyframe_registered_is_said_so(kind):
    """Fog from 12 to 26 s: no keyframe registers, so nothing tests the fixes, and the viewer
    says so while it lasts. A 2 m/s drag-off east from 15 s (accuracy 2 m, threshold 9 m) is
    22 m off at the first keyframe after the fog and caught at the second (the median of the
    newest three, 0, 22, 24 m: 22 m): it began unseen, some time between the last keyframe before the
    fog and the first after it, and is said so (not "from 26 s"). A 200 m jump at 15 s is
    caught at 26 s (JUMP_FAR), but the telemetry's own step was held off from the frame at
    15 s (app.live.register: drawn rejected from there), which dates it. The summary names the
    untested span either way."""
    said = Messages()
    watch = GnssWatch(said)
    lie = {"drag": lambda t: 2.0 * max(t - 15.0, 0.0), "jump": lambda t: 200.0 * (t >= 15.0)}[kind]
    keyframes = [float(t) for t in range(0, 13)] + [float(t) for t in range(26, 40)]
    for t in np.arange(0.0, 40.0, 0.1).round(1):
        if t in keyframes:
            scene = _circle(np.array([t]))[0]
            watch.keyframe(t, scene + [lie(t), 0.0, 0.0], scene, 2.0)
        held = 200.0 if kind == "jump" and 15.0 <= t < 26.0 else 0.0
        watch.frame(float(t), 0.0, held)
        if t == 20.0:
            assert watch.said_now(t)[0] == (
                "GNSS untested since t = 12.0 s (8 s): no keyframe has registered, so a lie "
                "would not be seen",
                USED,
            )
    assert len(watch.lies) == 1
    got = watch.lies[0]
    untested = "GNSS untested from t = 12.0 to 26.0 s (14 s: no keyframe registered)"
    assert untested in watch.line()
    if kind == "drag":
        assert (got.unseen_from_s, got.began_s, got.caught_s) == (12.0, 26.0, 27.0)
        assert said.items[0].startswith(
            "GNSS disagrees with the scene from some time between t = 12.0 s and t = 26.0 s "
            "(no keyframe registered between), 22 m by t = 27.0 s"
        ), said.items
        assert (
            "GNSS disagrees from between t = 12.0 and 26.0 s (caught at t = 27.0 s" in watch.line()
        )
    else:
        assert (got.unseen_from_s, got.began_s, got.caught_s) == (None, 15.0, 26.0)
        assert said.items[0].startswith("GNSS disagrees with the scene from t = 15.0 s, 200 m")


def _watched(lie, keyframes, fix_age=lambda t: 0.0, held=lambda t: 0.0) -> GnssWatch:
    """A watch fed frames at 10 Hz over 0-100 s and keyframes at `keyframes` (s) on the circle,
    their fixes lie(t) m east of the scene (accuracy 2 m), each frame's fix fix_age(t) s old and
    held_off(t) m of the telemetry held off."""
    watch = GnssWatch(Messages())
    for t in np.arange(0.0, 100.0, 0.1).round(1):
        if t in keyframes:
            scene = _circle(np.array([t]))[0]
            watch.keyframe(t, scene + [lie(t), 0.0, 0.0], scene, 2.0)
        watch.frame(float(t), fix_age(t), held(t))
    return watch


def test_what_dates_a_lie_after_a_blind_stretch_and_what_does_not():
    """An outage is no blind stretch: fixes missing 12-26 s, then 40 m off from their return
    (jammed, then spoofed), is said from the fixes' return, and no span is said untested. A fog
    longer than the watch's history (12-80 s) still dates a drag-off within it. A glitch held
    off and let go before the fog ended (0.3 s at 14 s) does not date a drag-off from 20 s."""
    before, after = [float(t) for t in range(0, 13)], [float(t) for t in range(26, 40)]
    spoofed = _watched(
        lambda t: 40.0 * (t >= 26.0),
        before + after,
        fix_age=lambda t: t - 12.0 if 12.0 <= t < 26.0 else 0.0,
    )
    assert spoofed.outages == [(12.0, 26.0)] and spoofed.unseen == []
    got = spoofed.lies[0]
    assert got.unseen_from_s is None and got.began_s == 26.0, got
    assert "untested" not in spoofed.line()
    long_fog = _watched(lambda t: 2.0 * max(t - 15.0, 0.0), before + [float(t) for t in range(80, 95)])  # fmt: skip
    got = long_fog.lies[0]
    assert (got.unseen_from_s, got.began_s) == (12.0, 80.0), got
    glitch = _watched(
        lambda t: 2.0 * max(t - 20.0, 0.0),
        before + after,
        held=lambda t: 50.0 if 14.0 <= t < 14.3 else 0.0,
    )
    got = glitch.lies[0]
    assert (got.unseen_from_s, got.began_s) == (12.0, 26.0), got


def test_frames_say_used_rejected_and_missing_and_an_outage_when_it_ends():
    """Frames at 10 Hz: fixes fresh to 30 s, none from 30 s to 42 s (the frame's newest fix
    ever older: missing once 5 s old, GAP_MIN_S), then a lie: keyframes at 43, 44 and 45 s
    whose fixes jump 30 m at 44 s (past 4.5 x 5 m: the alarm at 45 s, median(0, 30, 30)). The
    summary counts the frames, the outage is shown going on while it lasts and said with its
    span when a fix comes again, and the viewer's band covers the frames by status."""
    said = Messages()
    watch = GnssWatch(said)
    statuses = {}
    for t in np.arange(0.0, 50.0, 0.1).round(1):
        if t in (43.0, 44.0, 45.0):
            watch.keyframe(t, [30.0 if t >= 44 else 0.0, 0.0, 50.0], [0.0, 0.0, 50.0])
        age = t - 30.0 if 30.0 <= t < 42.0 else 0.0
        statuses[t] = watch.frame(float(t), age)
        if t == 40.0:
            assert viewer_gnss.live_said(watch, statuses[t], t) == [
                (f"GNSS this frame: missing ({viewer_gnss.LIVE_MEANING[MISSING]})", MISSING),
                ("no GNSS since t = 30.0 s (10 s so far)", MISSING),
            ]
    assert statuses[35.0] == USED and statuses[35.1] == MISSING and statuses[42.0] == USED
    assert statuses[45.0] == REJECTED
    assert "no GNSS from t = 30.0 s to 42.0 s (12 s)" in said.items
    assert watch.frames == {USED: 381, MISSING: 69, REJECTED: 50}  # of 500
    assert watch.line().startswith(
        "GNSS against the scene (3 keyframes): 381 frames used, 50 rejected, 69 missing; "
        "GNSS disagrees from t = 44.0 s (caught at t = 45.0 s, 30 m by t = 45.0 s), going on "
        "at the end; no GNSS from t = 30.0 s to 42.0 s (12 s)"
    )
    runs = viewer_gnss.live_runs(watch, (10.0, 50.0))  # the recorded span: 10 to 50 s
    assert [(r.status, r.start_s, r.end_s) for r in runs] == [
        (USED, 0.0, pytest.approx(25.0)),
        (MISSING, pytest.approx(25.1), pytest.approx(31.9)),
        (USED, pytest.approx(32.0), pytest.approx(34.9)),
        (REJECTED, pytest.approx(35.0), pytest.approx(39.9)),
    ]
    said_now = viewer_gnss.live_said(watch, REJECTED, 46.0)
    assert said_now[1] == (watch.lies[0].said(0.0), REJECTED)
    assert viewer_gnss.live_said(None, None, 0.0)[0][1] is None


def test_under_a_frozen_fix_the_shift_moves_as_the_last_two_keyframes_do():
    """A frozen fix: the shift (scene - fix) moves as the platform does, 9 m/s east, then it
    turns north (keyframes at 0-3 s: shifts 0, 9, 18 east, then 18 east 9 north). As a drag,
    four keyframes off one line are no line: their median held (13.5 m east, no rate), 4.5 m
    and more behind; frozen, the newest with the last two's rate (9 m/s north): where the
    platform goes on."""
    shifts = [[0, 0, 0], [9, 0, 0], [18, 0, 0], [18, 9, 0]]
    kept = [Kept(float(t), np.array(p, float), np.zeros(3), True) for t, p in enumerate(shifts)]
    shift, rate = shift_model(kept)
    np.testing.assert_allclose(shift, [13.5, 0, 0])
    np.testing.assert_allclose(rate, 0.0)
    shift, rate = shift_model(kept, frozen=True)
    np.testing.assert_allclose(shift, [18, 9, 0])
    np.testing.assert_allclose(rate, [0, 9, 0])


class _Registered:
    """A stand-in for the live registrar: each keyframe registers where the test says (ENU m),
    turned by the angle it says (deg, about the camera's z) from the telemetry's attitude."""

    def __init__(self) -> None:
        self.at: tuple[np.ndarray, float] = (np.zeros(3), 0.0)

    def keyframe(self, rgb, start: Camera):
        where, turn_deg = self.at
        q = rotations.multiply(np.asarray(start.orientation), rotations.from_rotvec([0, 0, np.radians(turn_deg)]))  # fmt: skip
        solved = Camera.create(start.intrinsics, where, q, start.near, start.far)
        return PoseFix(True, "", 80, 60, 0.5), solved, None


def _gated(after: list[tuple[float, np.ndarray, float]]) -> tuple[LiveRegistration, list[bool]]:
    """Keyframes of a flight east at 10 m/s (70 m up) registered where it was at 0-3 s under a
    clean fix, then none (a fog) while the fix drags north at 2 m/s from 5 s, then `after`:
    (media s, offset from the truth (ENU m), turned (deg)) each; whether each of those was kept."""
    truth = lambda t: np.array([10.0 * t, 0.0, 70.0])  # noqa: E731
    fix = lambda t: truth(t) + [0.0, 2.0 * max(t - 5.0, 0.0), 0.0]  # noqa: E731
    reg = LiveRegistration(None, Messages(), fix_at=fix)  # never started: no scene
    registrar, planes = _Registered(), (np.zeros((8, 8), np.uint8), np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8))  # fmt: skip
    intrinsics = Intrinsics.from_fov(64, 36, 60.0)
    kept = []
    for t, off, turn in [(float(t), np.zeros(3), 0.0) for t in range(4)] + after:
        registrar.at = (truth(t) + off, turn)
        before = reg.state.registered
        reg._keyframe(registrar, t, planes, Camera.create(intrinsics, fix(t), [1.0, 0, 0, 0]))
        kept.append(reg.state.registered > before)
    assert kept[:4] == [True] * 4
    return reg, kept[4:]


def test_after_a_blind_stretch_the_second_keyframe_is_kept_and_one_astray_leads_nothing():
    """After 11 s with no keyframe the drawn camera is 20 m off (the drag), no chain is left:
    the first keyframe is set aside (it agrees with nothing), the second kept where it lies
    within reach of where the first leads carried by the fix's own motion (2 m off: the drag's
    second). One registered astray and turned (5 deg: a GNSS lie never turns the camera) leads
    no chain: the keyframe after it is kept on the first's lead, two seconds on. One astray but
    not turned, 15 m off that lead, is still set aside. (On the code before, the second needed
    a third, and the one astray took the chain with it: 17 s kept nothing.)"""
    on = np.zeros(3)  # registered where the camera was
    _, kept = _gated([(15.0, on, 0.0), (16.0, on, 0.0)])
    assert kept == [False, True]
    astray = np.array([30.0, -40.0, -70.0])
    _, kept = _gated([(15.0, on, 0.0), (16.0, astray, 5.0), (17.0, on, 0.0)])
    assert kept == [False, False, True]
    _, kept = _gated([(15.0, on, 0.0), (16.0, np.array([0.0, 15.0, 0.0]), 0.0)])
    assert kept == [False, False]


def test_a_jump_in_the_telemetry_is_held_off_until_a_keyframe_past_it():
    """The telemetry steps 200 m east at 6 s (a set believed after JUMP_RUN), the newest
    keyframe kept at 5 s: frames from 6 s are drawn without the step (the correction less it)
    and counted `rejected`, with a line saying why; a keyframe kept at 6.5 s ends the hold."""
    track = {5.0: [0.0, 0.0, 60.0], 6.0 - JUMP_EDGE_S: [6.0, 0.0, 60.0], 6.0: [206.0, 0.0, 60.0]}
    jumps = [(6.0 - JUMP_EDGE_S, 6.0)]  # (from, to): LivePoses.jumps_between's
    reg = LiveRegistration(
        None, Messages(), fix_at=lambda t: np.array(track[t]),  # never started: no scene
        jumps_between=lambda a, b: jumps if a < 6.0 <= b else [],
    )  # fmt: skip
    assert reg.held_off(7.0) is None  # no correction yet: the telemetry as it is
    reg.state.shift_m, reg.state.rotvec, reg.state.at_s = np.array([1.0, 0, 0]), np.zeros(3), 5.0
    assert reg.held_off(5.9) is None
    np.testing.assert_allclose(reg.held_off(7.0), [200.0, 0.0, 0.0])
    camera = Camera.create(Intrinsics.from_fov(64, 36, 60.0), [206.0, 0.0, 60.0], [1.0, 0, 0, 0])
    np.testing.assert_allclose(reg.correct(camera, 7.0).position, [7.0, 0.0, 60.0])
    reg.state.at_s = 6.5
    assert reg.held_off(7.0) is None
    # MAVLink draws the step as a line between two messages (6.0 to 6.2 s): held off as far as
    # it is drawn (half of it at 6.1 s), all of it after
    ramp = LiveRegistration(
        None, Messages(), fix_at=lambda t: np.array([6.0 + 1000.0 * min(max(t - 6.0, 0.0), 0.2), 0.0, 60.0]),
        jumps_between=lambda a, b: [(6.0, 6.2)] if a < 6.2 and b > 6.0 else [],
    )  # fmt: skip
    ramp.state.shift_m, ramp.state.rotvec, ramp.state.at_s = np.zeros(3), np.zeros(3), 5.0
    np.testing.assert_allclose(ramp.held_off(6.1), [100.0, 0.0, 0.0])
    np.testing.assert_allclose(ramp.held_off(7.0), [200.0, 0.0, 0.0])
    watch = GnssWatch(Messages())
    assert watch.frame(6.9, 0.1) == USED and watch.frame(7.0, 0.0, 200.0) == REJECTED
    assert watch.said_now(7.0) == [
        ("GNSS jumped 200 m as no aircraft moves: not drawn until a keyframe past it registers", REJECTED)
    ]  # fmt: skip
    assert watch.frame(7.1, 0.1) == USED and watch.said_now(7.1) == []


def test_the_drawn_shift_follows_a_drag_on_its_line_and_holds_a_jump():
    """The correction while the fix disagrees: the line through the last LIE_FIT disagreeing
    keyframes (a drag's -2 m/s east, to be carried on), one or two: the newest held; while it agrees, the
    median of the agreeing run (a clean keyframe before the lie does not pull it)."""
    clean = [Kept(float(k), np.array([1.0, 0.0, 0.0]), np.zeros(3), False) for k in range(3)]
    drag = [Kept(3.0 + k, np.array([-2.0 * k, 0.0, 0.0]), np.zeros(3), True) for k in range(6)]
    shift, rate = shift_model(clean + drag)
    assert shift == pytest.approx([-10.0, 0.0, 0.0]) and rate == pytest.approx([-2.0, 0.0, 0.0])
    assert len(drag[-LIE_FIT:]) == LIE_FIT
    shift, rate = shift_model(clean + drag[:1])  # one keyframe on the scene: held
    assert shift == pytest.approx([0.0, 0.0, 0.0]) and rate == pytest.approx([0.0, 0.0, 0.0])
    astray = [drag[0], Kept(3.5, np.array([3.0, 0.0, 0.0]), np.zeros(3), True)]
    shift, rate = shift_model(clean + astray)  # two: the newest held, no line through them
    assert shift == pytest.approx([3.0, 0.0, 0.0]) and not rate.any()
    shift, rate = shift_model(clean + drag[:3])  # three: the line
    assert shift == pytest.approx([-4.0, 0.0, 0.0]) and rate == pytest.approx([-2.0, 0.0, 0.0])
    # one keyframe whose fix was taken mid-jump (160 of 200 m) before two past it: Theil-Sen's
    # line through three would be 20 m/s (the median of their slopes); they are not on it: held
    step = [Kept(5.0 + k, np.array([-v, 0.0, 0.0]), np.zeros(3), True) for k, v in enumerate((160.0, 200.0, 200.0))]  # fmt: skip
    shift, rate = shift_model(clean + step)
    assert shift == pytest.approx([-200.0, 0.0, 0.0]) and not rate.any()
    # four on a 2 m/s drag, one of them 3 m astray: the line through the other three
    astray = [Kept(5.0 + k, np.array([-2.0 * k - 3.0 * (k == 1), 0.0, 0.0]), np.zeros(3), True) for k in range(4)]  # fmt: skip
    shift, rate = shift_model(clean + astray)
    assert rate[0] == pytest.approx(-2.0, abs=0.5) and shift[0] == pytest.approx(-6.0, abs=0.8)
    back = [Kept(9.0 + k, np.array([1.2, 0.0, 0.0]), np.zeros(3), False) for k in range(2)]
    shift, rate = shift_model(clean + drag + back)
    assert shift == pytest.approx([1.2, 0.0, 0.0]) and not rate.any()


def test_mavlink_states_its_fixes_accuracy_in_gps_raw_int():
    """GPS_RAW_INT's h_acc (mm), placed at its arrival through the clock link; 0 is none."""
    tel = MavlinkTelemetry()
    tel.add("ATTITUDE", {"time_boot_ms": 1000, "roll": 0, "pitch": 0, "yaw": 0}, 10.0)
    assert tel.accuracy_at(1.0) is None
    assert not tel.add("GPS_RAW_INT", {"time_usec": 5, "h_acc": 0}, 10.5)
    assert tel.add("GPS_RAW_INT", {"time_usec": 5, "h_acc": 1500}, 10.5)  # boot 1.5 s
    assert tel.add("GPS_RAW_INT", {"time_usec": 6, "h_acc": 800}, 11.5)  # boot 2.5 s
    assert tel.accuracy_at(2.0) == 1.5 and tel.accuracy_at(3.0) == 0.8
    assert tel.accuracy_at(0.0) == 1.5  # before the first: the first


# --- drone downlinks that lie, received live -------------------------------------------------------

LIES = {"jump": Lie("jump", from_s=4.5, size_m=200.0), "drag": Lie("drag", from_s=5.0, speed_mps=2.0)}  # fmt: skip
SECONDS = {"jump": 10.0, "drag": 13.0}
ACCURACY_M = 1.0  # the accuracy given for the feed's fixes (KLV states none): a 5 m threshold
THRESHOLD_M = max(5.0, 4.5 * ACCURACY_M)
# Flight seconds from which a keyframe's fix lies beyond the threshold: the jump's, once the
# receiver follows it (it holds the last fix for JUMP_RUN sets, a set per frame, before it
# takes a step no aircraft can make); the drag's, once it has gone 5 m. A keyframe within
# BOUNDARY_S of it may fall either side (its registration's own error, a few centimetres to
# decimetres, is 0.5 m of the drag).
EXCEEDS_S = {"jump": 4.5 + JUMP_RUN / drone.FPS, "drag": 5.0 + THRESHOLD_M / 2.0}
BOUNDARY_S = 0.25
CAUGHT = re.compile(r"GNSS disagrees with the scene from .*?t = (\d+\.\d) s\), (\d+) m by .*?caught at t = (\d+\.\d) s")  # fmt: skip


@pytest.fixture(scope="module")
def downlinks(tmp_path_factory):
    """The drone's weave over the sample site, 320x180, its KLV jumping or dragging off."""
    folder = tmp_path_factory.mktemp("lying-downlinks")
    kinds = list(LIES)
    paths = write_downlinks(folder, [(LIES[k], SECONDS[k]) for k in kinds], (320, 180))
    return dict(zip(kinds, paths, strict=True))


def _received(path, record=None):
    drawn = []
    options = LiveOptions(
        silence_s=1.0,
        size=(160, 90),
        layers=(sample_layer(),),
        gnss_accuracy_m=ACCURACY_M,
        record=record,
    )
    return run_sent(path, options, lambda d, c: drawn.append((d, c)), lockstep=True), drawn


def _error_m(run, d, camera) -> float:
    """The drawn camera's distance (m) from where the drone's camera was at the frame's time."""
    pos, _ = drone.flight(np.array([d.pts_s + run.origin_s]))
    want = run.frame.geodetic_to_enu(*SITE.enu_to_geodetic(pos).T)[0]
    return float(np.linalg.norm(np.asarray(camera.position) - want))


@pytest.mark.gl
@pytest.mark.parametrize("kind", list(LIES))
def test_a_lying_downlink_is_caught_live_and_not_followed(downlinks, kind, tmp_path):
    run, drawn = _received(downlinks[kind], tmp_path / "recorded.ts")
    said = "\n".join(run.messages.items)
    watch, reg = run.gnss, run.registration
    assert watch is not None and reg is not None and reg.registered >= 3, (said, run.summary())
    alarms = [m for m in run.messages.items if m.startswith("GNSS ")]
    assert len(alarms) == 1, said  # said once
    began, far, caught = (float(x) for x in CAUGHT.search(alarms[0]).groups())
    lie, flight = LIES[kind], run.origin_s  # media time + origin_s: the flight's time
    keys = [t + flight for t in watch.keyframe_times]  # the keyframes tested, flight s
    # The alarm: a jump's at the first keyframe tested past the step (its own fix 200 m off,
    # past JUMP_FAR thresholds, the one before within); a drag's at the second keyframe past the
    # moment it exceeds the threshold (the median of the newest three), so within two keyframe
    # spacings of it, or at the first where a single keyframe was tested before it (the median
    # of two). The message says tenths of a second.
    past = [[k for k in keys if k > EXCEEDS_S[kind] + d] for d in (-BOUNDARY_S, BOUNDARY_S)]
    second = [p[1] for p in past]
    alarms_at = second + [p[0] for p in past if sum(k < p[0] for k in keys) == 1]
    if kind == "jump":
        alarms_at = [p[0] for p in past]
    assert any(caught + flight == pytest.approx(k, abs=0.06) for k in alarms_at), (keys, said)
    at_second = any(caught + flight == pytest.approx(k, abs=0.06) for k in second)
    before = max(k for k in keys if k < caught + flight - 0.06)
    if kind == "jump":  # said from the first fix past the step, 200 m off then
        assert JUMP_FAR * THRESHOLD_M < far <= 200.5, (keys, said)
        assert any(began + flight == pytest.approx(p[0], abs=0.06) for p in past), (keys, said)
    else:  # how far it had gone by the keyframe before the alarm (the median's): 2 m/s; said
        # from half-way back in time to where it was half as far, or (keyframes too far apart
        # to tell a drag from a step) from the first keyframe that saw it
        if at_second:
            assert far == pytest.approx(2.0 * (before - lie.from_s), abs=0.7), (keys, said)
        assert lie.from_s - 2.0 <= began + flight <= past[1][0] + 0.06, (keys, said)
    # The frames after the lie are rejected to the end, none before: a drag's from the first the
    # drawing loop saw rejected, not before the keyframe that raised the alarm; a jump's from the
    # first set the receiver followed it with (its step held off, not drawn, until the keyframe
    # past it registers: LiveRegistration.held_off), before the alarm or with it.
    status = [d.gnss for d, _ in drawn]
    first = status.index(REJECTED)
    since = EXCEEDS_S[kind] - flight - 0.05 if kind == "jump" else caught
    assert drawn[first][0].pts_s >= since and set(status[first:]) == {REJECTED}
    if kind == "jump":
        assert drawn[first][0].pts_s <= caught + 0.05, (drawn[first][0].pts_s, caught)
    assert set(status[:first]) == {USED}
    assert len(status) - first >= 30, (first, len(status))  # a second of frames at least
    # The drawn pose during the lie stands on the scene from the alarm on (two keyframes past
    # the lie by then: a jump's shift held, a drag's on the line through them), as close to
    # where the camera was as the frames corrected before the lie (the clean run's error): 1.5x,
    # give or take 0.15 m (what a keyframe's registration at 320x180 may differ from the median
    # of those the clean frames stand on).
    errors = [(d.pts_s + flight, _error_m(run, d, c), d.gnss) for d, c in drawn]
    clean = [e for t, e, _ in errors if reg.since_s + flight + 0.5 <= t < lie.from_s]
    during = [e for _, e, s in errors if s == REJECTED]
    assert len(clean) >= 5 and len(during) >= 10, (len(clean), len(during), keys)
    ref = np.median(clean)
    assert np.median(during) <= max(1.5 * ref, ref + 0.15), (np.median(during), ref)
    # the summary's line counts the frames by status and says the lie with its times
    summary = run.summary()
    assert (
        f"{status.count(USED)} frames used, {status.count(REJECTED)} rejected, 0 missing; "
        f"GNSS disagrees from t = {began:.1f} s (caught at t = {caught:.1f} s, " in summary
    ), summary
    assert summary.endswith("going on at the end; ended: the stream was silent for 1 s"), summary
    # The recording (`geofuse live --record`), solved afterwards as a file (`geofuse solve
    # REC.ts --scene ... --gnss-accuracy 1`), forward and backward: the same lie said once,
    # from where it began (a drag: within 2 s; a jump: at its step), and every frame of the
    # recording from where it exceeds the threshold `rejected`, those drawn `used` before the
    # live alarm too; none before it began (but the fixes of the median's window at a jump's
    # edge), and the track there on the scene.
    session = open_any(tmp_path / "recorded.ts", layers=(sample_layer(),), accuracy_m=ACCURACY_M)
    track = solve_track(session, "registered")
    [again] = track.registration.gnss.lies
    to_flight = session.utc_of(0.0) - drone.START.timestamp()  # session s -> flight s
    assert abs(again.began_s + to_flight - lie.from_s) <= (2.0 if kind == "drag" else 0.1), again
    frames = np.arange(track.frame_count)
    poses = track.poses_at(track.clock.media_s[frames], frames)
    t = poses.time_s + to_flight
    live_used = [d.pts_s + flight for d, _ in drawn if d.gnss == USED and d.pts_s + flight > EXCEEDS_S[kind]]  # fmt: skip
    assert kind == "jump" or live_used, "the live drawing used none after the threshold"
    assert (poses.gnss[t > EXCEEDS_S[kind] + BOUNDARY_S] == REJECTED).all()
    assert (poses.gnss[t < lie.from_s - 0.5] == USED).all()
    pos, _ = drone.flight(t)
    want = session.frame.geodetic_to_enu(*SITE.enu_to_geodetic(pos).T)
    during = np.linalg.norm(poses.enu - want, axis=1)[t > EXCEEDS_S[kind]]
    assert np.median(during) <= max(1.5 * ref, ref + 0.15), (np.median(during), ref)
