"""Registration of a live feed, forward only: a drone's downlink over the sample site whose KLV
puts the camera 3 m and 2 deg off (a GNSS and gimbal bias), sent over the loopback by the test,
drawn by `geofuse live`'s pipeline against the textured sample model. Once keyframes register,
every frame is drawn within 0.5 m and 0.5 deg of where the camera truly was."""

from __future__ import annotations

import numpy as np
import pytest

from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.misb import camera_set
from app.live.run import LiveOptions, run_sent
from app.simulate import drone
from app.simulate.downlink import sample_layer
from app.simulate.stadium import SITE_ORIGIN

pytestmark = pytest.mark.gl

SECONDS = 12.0
SIZE = (480, 270)
OFF_ENU = np.array([2.0, -2.0, 1.0])  # the KLV's position error (3 m)
OFF_HPR = np.array([1.5, -1.2, 0.0])  # and its angles' (1.9 deg)
SITE = LocalFrame(*SITE_ORIGIN)


def _truth(t: float) -> tuple[np.ndarray, np.ndarray]:
    """(ENU m about the site, camera -> ENU quaternion) of the drone's camera at flight time t."""
    pos, heading = drone.flight(np.array([t]))
    return pos[0], rotations.camera_quat_from_hpr(heading[0], drone.PITCH_DEG, 0.0)


@pytest.fixture(scope="module")
def downlink(tmp_path_factory):
    sets = []
    for t in np.arange(0.0, SECONDS, 1 / 30):
        pos, heading = drone.flight(np.array([t]))
        lat, lon, h = SITE.enu_to_geodetic(pos + OFF_ENU)[0]
        hpr = (heading[0] + OFF_HPR[0], drone.PITCH_DEG + OFF_HPR[1], 0.0)
        sets.append(
            (float(t), camera_set(float(t), (lat, lon, h), hpr, drone.HFOV_DEG, SITE_ORIGIN[2]))
        )
    path = tmp_path_factory.mktemp("reg") / "downlink.ts"
    return drone.write_video(path, SECONDS, SIZE, klv=sets)


def test_a_biased_feed_is_registered_live_and_drawn_where_the_camera_was(downlink):
    drawn = []
    run = run_sent(
        downlink,
        LiveOptions(silence_s=2.0, size=(160, 90), layers=(sample_layer(),)),
        lambda d, c: drawn.append((d, c)),
        lockstep=True,  # the same frames drawn with the same corrections on a busy machine
    )
    said = " ".join(run.messages.items)
    reg = run.registration
    assert reg is not None and reg.registered >= 3, (reg, said, run.summary())
    assert "registered live from" in said
    # its GNSS, 3 m off throughout (under the 22.5 m a fix stating no accuracy is held to), is
    # tested against the keyframes and never accused: every frame `used` (issue 52)
    assert run.gnss is not None and run.gnss.tested >= 3 and not run.gnss.lies, said
    assert {d.gnss for d, _ in drawn} == {"used"} and "GNSS " not in said
    first_pts = run.origin_s  # the stream's first frame is flight time 0 once joined at its start
    # what registration found is the bias planted in the KLV: 3 m and 1.9 deg
    assert np.linalg.norm(reg.shift_m) == pytest.approx(np.linalg.norm(OFF_ENU), abs=0.2)
    assert np.degrees(np.linalg.norm(reg.rotvec)) == pytest.approx(1.9, abs=0.2)

    def error(d, cam) -> tuple[float, float, float]:
        t = d.pts_s + first_pts
        pos, q = _truth(t)
        want = run.frame.geodetic_to_enu(*SITE.enu_to_geodetic(pos[None]).T)[0]
        metres = np.linalg.norm(np.asarray(cam.position) - want)
        return t, metres, np.degrees(rotations.angle_between(np.asarray(cam.orientation), q))

    # from the first frame drawn with the correction (however long the keyframe took on this
    # machine: latency is the live bench's), every frame is drawn where the camera was
    errors = [error(d, c) for d, c in drawn if d.pts_s >= reg.since_s]
    first = next(i for i, (_, metres, _) in enumerate(errors) if metres < 1.0)
    late = errors[first:]
    assert len(late) > 60, said
    for t, metres, degrees in late:
        assert metres < 0.5 and degrees < 0.5, (t, metres, degrees)
