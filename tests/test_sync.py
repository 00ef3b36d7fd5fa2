"""Automatic video <-> gyroscope sync (issue 13): the sample session's video shifted by known
offsets (either way, whole frames and fractions of one) is put back within 10 ms."""

from __future__ import annotations

import numpy as np
import pytest

from app.geodesy import rotations
from app.simulate.sample import SAMPLE_DIR
from app.sync import (
    bearings_of,
    estimate_offset,
    frame_rotation,
    gyro_rates,
    synced_offset,
    video_rates,
)


@pytest.fixture(scope="module")
def sample_rates():
    from app.session import open_session

    s = open_session(SAMPLE_DIR / "session.toml")
    return s, video_rates(s.video, bearings_of(s), s.rotation_cw), gyro_rates(s)


@pytest.fixture(scope="module")
def offset_at(sample_rates):
    """estimate_offset of the sample's rates for a clip start (s), each found once: the offset
    tests and the drift test read the same estimate of the sample as recorded."""
    s, rates, gyro = sample_rates
    found = {}

    def at(clip_start: float):
        if clip_start not in found:
            found[clip_start] = estimate_offset(rates, gyro, clip_start)
        return found[clip_start]

    return at


def test_frame_rotation_recovers_a_known_turn():
    rng = np.random.default_rng(5)
    b1 = rng.normal(size=(80, 3)) + [0, 0, 4]
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    r = rotations.to_matrix(rotations.from_rotvec([0.01, -0.02, 0.005]))
    b2 = b1 @ r.T
    b2[:10] = rng.normal(size=(10, 3))  # a few bad tracks
    b2 /= np.linalg.norm(b2, axis=1, keepdims=True)
    np.testing.assert_allclose(frame_rotation(b1, b2), r, atol=1e-3)


@pytest.mark.parametrize("shift_s", [0.0, 0.25, -0.4, 0.1, -1 / 30, 0.017])
def test_known_offsets_are_recovered_within_10_ms(sample_rates, offset_at, shift_s):
    """The video is made `shift_s` late on the session clock (its start time moved): sync must
    find the sample's own error (its start time is 80 ms off, truth_frames.csv says exactly how
    much) plus the shift."""
    s, rates, gyro = sample_rates
    truth = float(np.mean(s.truth_frame_times - s.frame_times))
    clip_start = float(s.frame_times[0] - s.video.pts_s[0]) - shift_s
    result = offset_at(clip_start)
    assert result.offset_s == pytest.approx(truth + shift_s, abs=0.010)
    assert result.confidence > 0.9 and len(result.windows) >= 10


def test_sync_write_keeps_the_offset_for_an_auto_manifest(tmp_path, capsys):
    from app.cli import main
    from app.session import open_session

    text = (SAMPLE_DIR / "session.toml").read_text()
    for name in (
        "scene.glb",
        "clip.mp4",
        "acc.csv",
        "gyr.csv",
        "mag.csv",
        "phone_orientation.csv",
        "gnss.csv",
        "truth_orientation.csv",
        "truth_position.csv",
        "truth_frames.csv",
    ):
        text = text.replace(f'"{name}"', f'"{SAMPLE_DIR / name}"')
    manifest = tmp_path / "walk.toml"
    manifest.write_text(text.replace("time_offset_s = 0.0", 'time_offset_s = "auto"'))
    assert main(["sync", str(manifest), "--write"]) == 0
    out = capsys.readouterr().out
    assert "the video's times need" in out and "walk.geofuse.toml" in out
    offset = synced_offset(manifest)
    s = open_session(manifest)
    truth = float(np.mean(s.truth_frame_times - s.frame_times))
    assert abs(truth) < 0.010 and offset == pytest.approx(
        -0.080, abs=0.010
    )  # the offset was applied
    assert any("walk.geofuse.toml" in w for w in s.messages.items)


def test_a_clock_drift_is_fitted_on_a_long_clip(sample_rates, offset_at):
    """The video clock running 300 ppm fast over the 80 s sample (24 ms from end to end) is seen
    as a drift of that size; the sample as recorded shows none (its per-window lags trend by
    ~-40 ppm from the walk's translation, under the 5 ms significance)."""
    from app.sync import RateCurve

    s, rates, gyro = sample_rates
    clip_start = float(s.frame_times[0] - s.video.pts_s[0])
    plain = offset_at(clip_start)  # as the offset test with no shift found it
    assert plain.drift_ppm == 0.0  # below what moves the clip's ends by 5 ms: not a drift
    fast = RateCurve(
        rates.t * (1 - 300e-6), rates.omega
    )  # video times read too short: its clock runs fast
    drifted = estimate_offset(fast, gyro, clip_start)
    assert drifted.drift_ppm == pytest.approx(
        300, abs=100
    )  # the estimator's error on this walk: ~70 ppm (5 ms over 80 s)


def test_without_a_gyroscope_the_recorded_attitude_times_the_video(sample_rates):
    """The sample with its gyroscope taken away: the phone's own attitude stream, differentiated,
    finds the same offset (the sample's 80 ms) within 10 ms."""
    from dataclasses import replace

    s, rates, _ = sample_rates
    no_gyro = replace(s, gyr=None)
    truth = float(np.mean(s.truth_frame_times - s.frame_times))
    result = estimate_offset(rates, gyro_rates(no_gyro), float(s.frame_times[0] - s.video.pts_s[0]))
    assert result.offset_s == pytest.approx(truth, abs=0.010)
    with pytest.raises(Exception, match="no gyroscope, no recorded attitude and no course"):
        gyro_rates(replace(s, gyr=None, recorded={}))


@pytest.fixture(scope="module")
def drone_video(tmp_path_factory, gl_ctx):
    """24 s of a drone weaving over the sample site (app.simulate.drone), rendered here; its
    subtitle (no gimbal angles) is written by each test."""
    from app.simulate import drone

    return drone.write_video(tmp_path_factory.mktemp("drone") / "DJI_0001.MP4")


@pytest.mark.gl
@pytest.mark.parametrize("lag_s", [0.3, -0.2])
def test_a_drone_without_gimbal_angles_is_timed_by_its_course(drone_video, lag_s, capsys):
    """The subtitle's GNSS track lags the video by lag_s: `geofuse sync` finds it from how the
    course turns against how the video turns (bench sync: errors up to 70 ms on this flight)."""
    import re

    from app.cli import main
    from app.simulate import drone

    drone_video.with_suffix(".SRT").write_text(drone.srt_text(24.0, lag_s), encoding="utf-8")
    assert main(["sync", str(drone_video)]) == 0
    out = capsys.readouterr().out
    found = float(re.search(r"need ([-+][0-9.]+) ms", out).group(1)) / 1000
    assert found == pytest.approx(lag_s, abs=0.1) and "the aircraft's course" in out


@pytest.mark.gl
def test_a_straight_flight_cannot_be_timed_by_its_course(drone_video, capsys):
    from app.cli import main
    from app.simulate import drone

    drone_video.with_suffix(".SRT").write_text(
        drone.srt_text(24.0, 0.0, drone.straight), encoding="utf-8"
    )
    assert main(["sync", str(drone_video)]) == 2
    err = capsys.readouterr().err
    assert "turns faster than 3 deg/s for only 0.0 s" in err and "cannot be estimated" in err
