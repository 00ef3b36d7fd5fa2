"""MAVLink telemetry as camera poses: the message conventions against hand-worked cases (pure),
then a drone's video without KLV and its autopilot's telemetry sent over the loopback by the test
itself, the telemetry 0.3 s ahead of the video: `geofuse live --mavlink` estimates that lag from
the camera's turns and draws each frame with the pose of its own time."""

from __future__ import annotations

import functools
import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from app.footage.clips import open_clip
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geoid import undulation
from app.io.mavlink import MavlinkTelemetry, camera_quat, gimbal_angles
from app.live.pose import MavlinkPoses
from app.live.run import LiveOptions, run_live
from app.session.camera_track import camera_track
from app.simulate import autopilot, drone
from app.simulate.feed import Sender, free_udp_port, port_held
from app.simulate.stadium import SITE_ORIGIN


def _hpr(q: np.ndarray) -> np.ndarray:
    return rotations.hpr_from_camera_quat(np.asarray(q)[None])[0]


def _axis(q: np.ndarray) -> np.ndarray:
    """The optical axis (ENU) of a camera -> ENU quaternion (the camera looks down its -z)."""
    return rotations.rotate(q, [0.0, 0.0, -1.0])


def _quat_zyx(yaw: float, pitch: float, roll: float) -> list[float]:
    """[w, x, y, z] of Rz(yaw) Ry(pitch) Rx(roll), degrees (MAVLink's gimbal quaternion)."""
    y, p, r = (math.radians(a) / 2 for a in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = (f(a) for a in (y, p, r) for f in (math.cos, math.sin))
    return [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]


def test_a_camera_along_the_nose_looks_where_the_vehicle_points():
    """No gimbal: yaw 45, pitch 10 up, roll 0: the optical axis is north-east, 10 deg up:
    (sin 45 cos 10, cos 45 cos 10, sin 10) in ENU, and the image's right is south-east."""
    q = camera_quat((45.0, 10.0, 0.0), None)
    c10, s10, r2 = math.cos(math.radians(10)), math.sin(math.radians(10)), math.sqrt(0.5)
    np.testing.assert_allclose(_axis(q), [r2 * c10, r2 * c10, s10], atol=1e-9)
    np.testing.assert_allclose(rotations.rotate(q, [1.0, 0.0, 0.0]), [r2, -r2, 0.0], atol=1e-9)


def test_a_gimbal_levelled_against_the_horizon_ignores_the_vehicles_pitch_and_roll():
    """GIMBAL_DEVICE_ATTITUDE_STATUS with its yaw in the vehicle frame: the vehicle's heading
    plus the gimbal's yaw; the gimbal's own pitch and roll (against the horizon)."""
    yaw, pitch, roll, relative = gimbal_angles(
        _quat_zyx(10.0, -30.0, 0.0), mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    )
    assert (yaw, pitch, roll) == pytest.approx((10.0, -30.0, 0.0)) and relative
    q = camera_quat((80.0, -7.0, 12.0), (yaw, pitch, roll), relative)
    np.testing.assert_allclose(_hpr(q), [90.0, -30.0, 0.0], atol=1e-9)
    # the axis: due east, 30 deg down
    c30 = math.cos(math.radians(30))
    np.testing.assert_allclose(_axis(q), [c30, 0.0, -0.5], atol=1e-9)


@pytest.mark.parametrize(
    "flags",
    [
        mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME,
        mavlink.GIMBAL_DEVICE_FLAGS_YAW_LOCK,  # older gimbals: locked yaw is the earth's
    ],
)
def test_a_gimbal_yaw_in_the_earth_frame_is_a_heading(flags):
    yaw, pitch, roll, relative = gimbal_angles(_quat_zyx(30.0, -45.0, 5.0), flags)
    assert not relative
    q = camera_quat((200.0, 0.0, 0.0), (yaw, pitch, roll), relative)
    np.testing.assert_allclose(_hpr(q), [30.0, -45.0, 5.0], atol=1e-9)


def test_positions_heights_home_and_the_clock_link():
    tel = MavlinkTelemetry()
    lat, lon = 34.8, 113.53
    n = float(undulation(lat, lon))
    fix = {"lat": int(lat * 1e7), "lon": int(lon * 1e7), "alt": 150_000, "relative_alt": 40_000}
    assert not tel.add(
        "GLOBAL_POSITION_INT", {**fix, "lat": 0, "lon": 0, "time_boot_ms": 900}, 10.15
    )
    assert tel.counts.no_fix == 1  # no fix: a gap, not a position at (0, 0)
    assert tel.add("GLOBAL_POSITION_INT", {**fix, "time_boot_ms": 1000}, 10.3)
    assert tel.add("ATTITUDE", {"time_boot_ms": 1000, "roll": 0, "pitch": 0, "yaw": 0}, 10.2)
    # the fastest message sets the link: arrival - boot = 10.2 - 1.0
    assert tel.link_s == pytest.approx(9.2)
    assert tel.home_h == pytest.approx(110.0 + n)  # alt - relative_alt, to the ellipsoid
    # MOUNT_STATUS has no time: placed at its arrival through the link (boot 1.3 s)
    assert tel.add("MOUNT_STATUS", {"pointing_a": -9000, "pointing_b": 0, "pointing_c": 0}, 10.5)
    pose = tel.at(1.0)
    assert pose.geodetic[2] == pytest.approx(150.0 + n)
    np.testing.assert_allclose(_axis(pose.q), [0.0, 0.0, -1.0], atol=1e-9)  # straight down
    assert tel.at(1.5).age_s == pytest.approx(0.5)


def test_a_position_step_no_aircraft_makes_is_found_on_both_clocks():
    """Positions at 5 Hz moving 2 m a message (10 m/s north), then 200 m east between boot 1.4
    and 1.6 s (1000 m/s: a jump), then on as before: MavlinkTelemetry.jumps_between finds that
    pair (boot s) where its end lies in the span asked or the step is under way at its end, and
    nothing else; MavlinkPoses puts it on the media clock (video link 0 s, telemetry link 50
    s: boot = media - 50 s)."""
    tel = MavlinkTelemetry()
    lat0, lon0 = 34.8, 113.53
    m_per_deg = 111_195.0
    for k in range(12):
        boot = 0.6 + 0.2 * k
        east = 200.0 if boot > 1.5 else 0.0
        lat = lat0 + 2.0 * k / m_per_deg
        lon = lon0 + east / (m_per_deg * np.cos(np.radians(lat0)))
        fix = {"lat": round(lat * 1e7), "lon": round(lon * 1e7), "alt": 150_000}
        assert tel.add(
            "GLOBAL_POSITION_INT", {**fix, "time_boot_ms": round(1000 * boot)}, boot + 50.0
        )
    assert tel.jumps_between(0.0, 3.0) == [pytest.approx((1.4, 1.6))]
    assert tel.jumps_between(1.5, 1.55) == [pytest.approx((1.4, 1.6))]  # under way
    assert tel.jumps_between(1.6, 3.0) == [] and tel.jumps_between(0.0, 1.4) == []
    poses = MavlinkPoses(tel, lambda: 0.0, 1.0)
    assert poses.jumps_between(50.0, 53.0) == [pytest.approx((51.4, 51.6))]


def test_attitudes_interpolate_the_short_way_round_north():
    tel = MavlinkTelemetry()
    tel.add("GLOBAL_POSITION_INT", {"time_boot_ms": 0, "lat": 1, "lon": 1, "alt": 0}, 0.0)
    for ms, yaw in ((0, 358.0), (1000, 4.0)):
        tel.add(
            "ATTITUDE", {"time_boot_ms": ms, "roll": 0, "pitch": 0, "yaw": math.radians(yaw)}, 0
        )
    assert _hpr(tel.at(0.5).q)[0] % 360.0 == pytest.approx(1.0)


FLIGHT_S = 18.0
LEAD_S = 0.3  # the telemetry leaves this much before the video of the same moment
# A weave of 6 s, 30 deg either side: turns that change fast enough to time the video by (the
# sample's 12 s weave times it within ~0.1 s from 8 s of video; this one within ~25 ms).
FLIGHT = functools.partial(drone.flight, period_s=6.0, weave_deg=30.0)


@pytest.fixture(scope="module")
def downlink(tmp_path_factory):
    """The drone's weave over the sample site: 320x180 at 30 fps, MPEG-TS, no KLV."""
    return drone.write_video(
        tmp_path_factory.mktemp("mav") / "downlink.ts", FLIGHT_S, (320, 180), path_of=FLIGHT
    )


def test_live_video_posed_by_mavlink_with_its_lag_estimated_while_flying(downlink, tmp_path):
    video_port, mav_port = free_udp_port(), free_udp_port()
    sender = Sender(downlink.read_bytes(), ("127.0.0.1", video_port))
    telemetry: list[autopilot.MavlinkSender] = []
    drawn = []

    def clock() -> float:  # both senders start once the receivers listen
        now = time.monotonic()
        if not telemetry:
            end = now + 30.0
            while not port_held(video_port) and time.monotonic() < end:
                time.sleep(0.01)
            now = time.monotonic()
            sender.start()
            telemetry.append(
                autopilot.MavlinkSender(
                    ("127.0.0.1", mav_port), FLIGHT_S, now, LEAD_S, path_of=FLIGHT
                ).start()
            )
        return now

    run = run_live(
        f"udp://127.0.0.1:{video_port}",
        LiveOptions(
            silence_s=2.0,
            size=(160, 90),
            mavlink=f"udp:127.0.0.1:{mav_port}",
            hfov_deg=drone.HFOV_DEG,
            origin=None,
            record=tmp_path / "flight.ts",
        ),
        clock=clock,
        on_drawn=lambda d, c: drawn.append((d, c)),
    )
    sender.stop()
    telemetry[0].stop()
    said = " ".join(run.messages.items)
    assert run.mavlink is not None and run.mavlink.gimbal, said
    assert run.mavlink.used.get("ATTITUDE", 0) > 0.9 * 25 * FLIGHT_S
    # The lag the senders made: the video's frames left (sender.sent) later than the telemetry
    # of the same flight time by this much (both clocks linked by their fastest, as geofuse
    # links them); receiving adds up to a frame (the demuxer hands a frame over when the next
    # one begins) and a few ms.
    first = min(sender.sent)  # the PTS (90 kHz) of flight time 0
    video_late = min(s - (p - first) / 90000.0 for p, s in sender.sent.items())
    # media time 0 is the first frame received (the receiver may join after the first second)
    joined_s = run.origin_s - first / 90000.0
    true_lag = video_late - (telemetry[0].start_s - LEAD_S)
    assert run.mavlink.lag_s is not None, said
    # The lag that matters is the receiver's (its demuxer hands a frame over when the next one
    # begins, its decoder and clock add their own): a little more than the senders made. What
    # must be exact is what it does to the poses drawn (below).
    assert true_lag - 0.03 < run.mavlink.lag_s < true_lag + 0.12, said
    # Frames drawn once the lag is applied (two agreeing fits of 10 s windows) wear the pose of their
    # own flight time: heading within 1 deg (uncorrected, the lag would put it several off),
    # the position within 0.5 m (9 m/s: a 0.3 s lag would be 2.7 m).
    late = [(d, c) for d, c in drawn if d.pts_s >= 14.0]
    assert len(late) > 60, said
    frame = run.frame
    heading_err, uncorrected, position_err = [], [], []
    for d, cam in late:
        t = d.pts_s + joined_s  # the frame's flight time
        pos, heading = FLIGHT(np.array([t, t + true_lag]))
        got = _hpr(np.asarray(cam.orientation))
        heading_err.append(abs((got[0] - heading[0] + 180) % 360 - 180))
        uncorrected.append(abs((heading[1] - heading[0] + 180) % 360 - 180))
        want = frame.geodetic_to_enu(*LocalFrame(*SITE_ORIGIN).enu_to_geodetic(pos[:1]).T)[0]
        position_err.append(np.linalg.norm(np.asarray(cam.position) - want))
        assert got[1] == pytest.approx(drone.PITCH_DEG, abs=0.2)  # the gimbal's, not the vehicle's
    assert np.median(heading_err) < 0.3 and max(heading_err) < 1.0, (heading_err, said)
    assert max(uncorrected) > 3.0  # what the test would miss without the lag
    assert np.median(position_err) < 0.5, position_err
    assert "the video lags the telemetry by" in said
    # The recording is a clip with poses: the MAVLink pose of each frame written beside it as a
    # Local Set (with the lag as estimated then), so that solve, export and index take it.
    clip = open_clip(tmp_path / "flight.ts")
    track = camera_track(clip, "telemetry")
    recorded_late = [
        k
        for k, t in enumerate(clip.video.pts_s)
        if t + clip.video.origin_s - first / 90000.0 >= 14.0
    ]
    assert len(recorded_late) > 60
    for k in recorded_late:
        t = clip.video.pts_s[k] + clip.video.origin_s - first / 90000.0
        _, heading = FLIGHT(np.array([t]))
        got = _hpr(np.asarray(track.frame_camera(k).orientation))
        assert abs((got[0] - heading[0] + 180) % 360 - 180) < 0.6, (t, got, heading)
