"""The bundled sample session (ground truth) and the accuracy measurement in metres."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from app.session import open_session
from app.session.camera_track import camera_track
from app.simulate import session as sample
from app.simulate.sample import SAMPLE_DIR, SAMPLE_SCENE
from app.solve.accuracy import Poses, ProjectionProbe, evaluate, true_frame_times

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def session():
    return open_session(SAMPLE_DIR / "session.toml")


def test_generation_is_reproducible(tmp_path):
    digests = []
    for name in ("a", "b"):
        sample.write_sample_session(tmp_path / name, SAMPLE_SCENE, sample.quick_config(2.0))
        digests.append(
            {
                p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted((tmp_path / name).iterdir())
            }
        )
    assert digests[0] == digests[1]
    assert {
        "clip.mp4",
        "acc.csv",
        "gyr.csv",
        "mag.csv",
        "gnss.csv",
        "session.toml",
        "truth_frames.csv",
    } <= set(digests[0])


def test_committed_sample_is_small_and_opens(session):
    total = sum(p.stat().st_size for p in SAMPLE_DIR.iterdir())
    assert total < 8e6
    assert len(session.frame_times) == 2400 and session.video.display_size == (640, 360)
    assert session.rotation_cw == 180  # landscape, phone top to the right
    assert session.video.variable_rate  # +-3 ms presentation-time jitter, as phones record
    assert session.sources == [
        "gd-ahrs",
        "gd-imu",
        "cf-ahrs",
        "cf-imu",
        "offline",
        "phone",
        "registered",
        "truth",
    ]
    assert any("hard-iron offset" in w for w in session.messages.items)
    # The manifest's start time is 80 ms late, as the generator documents.
    np.testing.assert_allclose(
        session.frame_times - true_frame_times(session), sample.SYNC_ERROR_S, atol=1e-4
    )


def test_sensor_error_model_is_what_it_says(tmp_path):
    manifest = sample.write_sample_session(
        tmp_path, SAMPLE_SCENE, sample.SampleConfig(duration_s=20.0, render_video=False)
    )
    from app.io import csvlog

    g = csvlog.read_vector(tmp_path / "gyr.csv", "gyr")
    t = g.t - sample.START_UNIX_S
    true_rates = sample.body_rates(sample.device_motion(), t)
    err = g.values - true_rates
    assert 0.02 < np.degrees(np.linalg.norm(err.mean(axis=0))) < 0.6  # a 0.1 deg/s-per-axis bias
    dt = np.diff(g.t)
    assert 0.006 < dt.min() and dt.max() < 0.05 and np.std(dt) > 0.001  # jittered 100 Hz, drops
    gnss = csvlog.read_gnss(tmp_path / "gnss.csv")
    from app.geodesy.enu import LocalFrame

    frame = LocalFrame(*sample.SITE_ORIGIN)
    e = frame.geodetic_to_enu(gnss.lat, gnss.lon, gnss.h) - sample.walk_position(
        gnss.t - sample.START_UNIX_S
    )
    assert 0.5 < np.sqrt(np.mean(e[:, :2] ** 2)) < 6.0  # metre-level, correlated
    assert manifest.exists()


def test_truth_pose_projects_within_centimetres(session):
    """The truth track (interpolated 100 Hz truth, slerp, device -> camera mounting) against the
    exact simulated camera: pixels land within centimetres on the model."""
    t_true = true_frame_times(session)[::120]
    enu, _, q = camera_track(session, "truth").poses.at(t_true)
    rel = t_true - sample.START_UNIX_S
    exact = Poses(sample.walk_position(rel), sample.camera_attitude(rel))
    probe = ProjectionProbe(session, (64, 36))
    try:
        d, _ = probe.errors(Poses(enu, q), exact)
    finally:
        probe.release()
    d = d[np.isfinite(d)]
    assert len(d) > 10_000
    assert np.median(d) < 0.02 and np.percentile(d, 95) < 0.05


@pytest.fixture(scope="module")
def reports(session):
    return {
        r.name: r
        for r in evaluate(
            session, ["gd-ahrs", "gd-imu", "cf-ahrs", "offline"], every=60, grid=(32, 18)
        )
    }


def test_filters_within_stated_bounds_on_the_sample(reports):
    for name in ("gd-ahrs", "gd-imu", "offline"):
        heading, pitch, roll, total = reports[name].attitude
        assert max(heading, pitch, roll) < 2.5 and total < 3.0, (name, reports[name].attitude)
    assert reports["cf-ahrs"].attitude[3] < 3.5
    for name in ("gd-ahrs", "gd-imu", "cf-ahrs", "offline"):
        assert reports[name].total.centre_median < 4.5, (name, reports[name].total)


def test_our_attitude_beats_the_papers_pipeline(reports):
    ours = reports["gd-ahrs"]
    paper = reports["paper pipeline"]
    assert ours.attitude[0] < paper.attitude[0] / 2  # declination + calibration + slerp
    assert ours.by_cause["attitude"].centre_median < paper.by_cause["attitude"].centre_median
    assert ours.by_cause["time"].centre_median > 0.05  # the 80 ms late start shows
