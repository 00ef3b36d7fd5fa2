"""Live feeds: the jitter buffer and the forward-only poses with injected times, then a drone's
downlink (app.simulate.feed) sent over the loopback by the test itself, with lost and reordered
datagrams, a pause, and a port already in use. The end-to-end tests run in real time (the sender
paces the stream) but assert only what must hold whatever the machine's speed."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from app.camera.intrinsics import Intrinsics
from app.cli import main
from app.core.messages import Messages
from app.footage.clips import open_clip
from app.geodesy.enu import LocalFrame
from app.io.misb import parse
from app.live.buffer import Arrival, JitterBuffer
from app.live.pose import FRESH, NONE, STALE, LivePoses
from app.live.receiver import Receiver, protocols_missing, stream_url
from app.live.run import LiveOptions, run_live
from app.simulate.feed import (
    LockstepClock,
    Orbit,
    Sender,
    free_udp_port,
    orbit_set,
    port_held,
    sending_clock,
    write_feed,
)
from tests.waiting import wait_until

ORBIT = Orbit()


def test_the_buffer_shows_each_frame_at_its_own_pace_after_the_delay():
    """Frames 1/30 s apart arrive with jitter (the fastest 0.5 s after its time stamp): each is
    due at pts + 0.5 + 0.1, whatever its own delay; reordered arrivals are put back in order."""
    buf = JitterBuffer(delay_s=0.1)
    jitter = [0.0, 0.04, 0.01, 0.08, 0.02]
    for k in (0, 2, 1, 3, 4):  # frame 2 overtakes frame 1
        buf.push(Arrival(k / 30, k / 30 + 0.5 + jitter[k], k))
    assert buf.link_s == pytest.approx(0.5)
    assert buf.take(0.599) is None  # frame 0 is due at 0.6
    assert buf.take(0.6).payload == 0
    assert buf.take(0.6 + 1 / 30 + 1e-9).payload == 1
    # the display was held up: frames 2 and 3 are both due; the newest is shown, one skipped
    assert buf.take(0.6 + 3 / 30 + 1e-9).payload == 3 and buf.skipped == 1
    buf.push(Arrival(2.5 / 30, 1.0, "late"))  # older than what was shown: late, dropped
    assert buf.late == 1 and [f.payload for f in buf.pending] == [4]
    # an encoder restarting its clock: the link starts afresh instead of freezing the display
    buf.push(Arrival(0.0, 100.0, "restart"))
    assert buf.resyncs == 1 and buf.take(100.1).payload == "restart"


def test_the_burst_of_a_joined_stream_is_played_out_catching_up_not_skipped():
    """Joining, the demuxer hands over half a second of frames at once: the display starts from
    the first and plays 25 % fast until it reaches the live edge; nothing is skipped."""
    buf = JitterBuffer(delay_s=0.1)
    for k in range(15):  # frames 0..14 all handed over at 10.0 s
        buf.push(Arrival(k / 30, 10.0, k))
    shown, now = [], 10.0
    for k in range(15, 120):  # then one a frame, on time
        buf.push(Arrival(k / 30, 10.0 + (k - 14) / 30, k))
        while (f := buf.take(now)) is not None or now < 10.0 + (k - 14) / 30:
            if f is not None:
                shown.append(f.payload)
            now += 1 / 240  # a display that polls often
    assert shown == list(range(len(shown))) and buf.skipped == 0  # in order, none skipped
    # The 0.47 s backlog is caught up at 0.25 s a second: 3.5 s later a frame is due the
    # buffer's 0.1 s after its arrival, as if the stream had been joined without a burst.
    assert buf.due_at(Arrival(119 / 30, 0.0)) - (10.0 + 105 / 30) == pytest.approx(0.1, abs=0.01)


def test_poses_are_forward_only_and_stale_past_the_buffer():
    poses = LivePoses(stale_after_s=0.1)
    frame = LocalFrame(ORBIT.lat_deg, ORBIT.lon_deg, ORBIT.ground_h_m)
    intr = Intrinsics.from_fov(320, 180, 50.0)
    assert poses.at(0.0, frame, intr, 1000.0).state == NONE
    for t in (0.0, 0.2):
        assert poses.add(t, parse(orbit_set(ORBIT, t, 30.0)))
    mid = poses.at(0.1, frame, intr, 1000.0)  # between two arrived sets: interpolated
    want = ORBIT.position(0.1)
    assert mid.state == FRESH
    assert np.linalg.norm(np.asarray(mid.camera.position)[:2] - want[:2]) < 0.01
    held = poses.at(0.35, frame, intr, 1000.0)  # past the newest set by 0.15 s: held, stale
    assert held.state == STALE and held.age_s == pytest.approx(0.15)
    assert np.allclose(held.camera.position[:2], ORBIT.position(0.2)[:2], atol=0.01)


def test_the_lockstep_clock_stands_at_its_cap_and_goes_on_from_there():
    """The tests' clock (app.simulate.feed.LockstepClock) on a real clock the test moves: free,
    it keeps pace; capped, it goes as far as the cap and stands, however much real time passes;
    let go, it goes on from where it stood (no jump); standing limit_s, it lets go."""
    real, cap = [100.0], [math.inf]
    clock = LockstepClock(lambda now: cap[0], limit_s=20.0, real=lambda: real[0])
    assert clock() == 100.0
    real[0] = 101.0
    assert clock() == 101.0
    cap[0] = 101.5  # a frame due at 101.5 not yet drawn
    real[0] = 103.0
    assert clock() == 101.5
    real[0] = 110.0
    assert clock() == 101.5 and clock.stood_s == pytest.approx(8.5)
    cap[0] = math.inf  # drawn: time goes on from 101.5
    real[0] = 111.0
    assert clock() == pytest.approx(102.5)
    cap[0] = 0.0  # a cap in the past: it stands where it is, never back
    real[0] = 115.0
    assert clock() == pytest.approx(102.5)
    real[0] = 135.0  # stood 20 s: let go
    assert clock() == pytest.approx(122.5)


def _up(ecef: np.ndarray) -> np.ndarray:
    """The local vertical (unit, ECEF) at a point, near enough for a 0.1 m test."""
    lat, lon = np.radians([ORBIT.lat_deg, ORBIT.lon_deg])
    return np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


@pytest.fixture(scope="module")
def feed(tmp_path_factory) -> Path:
    """3 s of the orbit at 320x180, 30 fps, a KLV set per frame."""
    return write_feed(tmp_path_factory.mktemp("live") / "feed.ts", 3.0, (320, 180))


def _run_with_sender(feed: Path, tmp_path: Path, sender_kwargs: dict, **options):
    port = free_udp_port()
    url = f"udp://127.0.0.1:{port}"
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port), **sender_kwargs)
    cameras = []

    def on_drawn(d, camera):
        cameras.append((d, camera))

    opts = LiveOptions(silence_s=2.0, size=(160, 90), record=tmp_path / "rec.ts", **options)

    run = run_live(url, opts, clock=sending_clock(sender, port), on_drawn=on_drawn)
    sender.stop()
    return run, sender, cameras


def test_a_lossy_downlink_is_drawn_frame_by_frame_with_each_frames_own_pose(feed, tmp_path):
    run, sender, cameras = _run_with_sender(
        feed, tmp_path, {"loss": 0.05, "reorder": 0.02, "seed": 3}
    )
    assert sender.dropped > 0 and run.drawn
    # Every frame that arrived is accounted for: drawn, or counted as dropped by geofuse
    # (behind, late, overflow) or drawn without a pose; none vanishes.
    accounted = len(run.drawn) + run.skipped + run.late + run.overflow + run.without_pose
    assert accounted <= run.received <= accounted + 3  # at most the buffer's tail at the end
    # What the network lost is counted as lost: every frame from the first that reached the
    # receiver (its socket may open after the sender began) is received or counted missing,
    # but for lost frames at the very end, which no later frame reveals.
    sent_after_first = 90 - round(run.origin_s * 30)
    assert sent_after_first - 3 <= run.received + run.missing <= sent_after_first
    assert "silent for 2 s" in run.ended
    # Each frame drawn with the pose of its own time: the orbit at that frame's time (a pose one
    # frame off would be 0.52 m away along the circle; the KLV's positions are mm-exact).
    frame = ORBIT.frame()
    fresh = [(d, c) for d, c in cameras if d.pose == FRESH]
    assert len(fresh) >= 0.9 * len(cameras)
    for d, cam in fresh:
        t = d.pts_s + run.origin_s
        got = run.frame.enu_to_ecef(np.asarray(cam.position))
        want = frame.enu_to_ecef(ORBIT.position(t))
        assert np.linalg.norm(got - want) < 0.35, (t, got - want)  # heights in 0.3 m steps
        along = got - want - (got - want) @ _up(want) * _up(want)
        assert np.linalg.norm(along) < 0.1, (t, along)
    # and the times are the stream's: arrival before due before drawn
    assert all(d.arrival_s <= d.drawn_s and d.due_s <= d.drawn_s for d, _ in cameras)
    # The recording is a clip like any other: its KLV gives the pose source `telemetry`.
    clip = open_clip(tmp_path / "rec.ts")
    assert "telemetry" in clip.recorded
    assert len(clip.video.pts_s) >= run.received - 2


def test_a_feed_that_pauses_is_reopened_and_drawn_again(feed, tmp_path):
    """The sender stops for 3 s mid-flight (longer than the read timeout) then resumes: the
    receiver says the stream dropped, reconnects, and frames after the pause are drawn."""
    data = feed.read_bytes()
    half = (len(data) // 188 // 2) * 188
    port = free_udp_port()
    first = Sender(data[:half], ("127.0.0.1", port))
    second = Sender(data[half:], ("127.0.0.1", port))
    drawn = []

    def resume():
        first.join()
        time.sleep(3.0)
        second.start()

    first.start()
    threading.Thread(target=resume, daemon=True).start()
    run = run_live(
        f"udp://127.0.0.1:{port}",
        LiveOptions(silence_s=5.0, size=(160, 90)),
        on_drawn=lambda d, c: drawn.append(d),
    )
    second.stop()
    said = " ".join(run.messages.items)
    assert "reading stopped (nothing arrived for 2 s)" in said
    assert run.reconnects >= 1
    late = [d for d in drawn if d.pts_s > 1.6]  # frames of the second half
    assert late, said


def test_a_port_already_in_use_is_said_and_the_receiver_keeps_trying():
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    messages = Messages()
    r = Receiver(f"udp://127.0.0.1:{port}", JitterBuffer(), LivePoses(0.1), messages).start()
    try:
        assert wait_until(lambda: r.counts.failed_opens >= 1)
        assert r.alive  # it retries with back-off instead of ending
        assert any(
            "already in use" in m and "another program holds the port" in m for m in messages.items
        )
    finally:
        r.stop()
        holder.close()


def test_stream_urls_and_what_this_ffmpeg_cannot_open():
    assert "overrun_nonfatal=1" in stream_url("udp://239.0.0.1:5600")
    assert stream_url("rtsp://cam/live") == "rtsp://cam/live"
    assert protocols_missing("udp://127.0.0.1:1") is None
    missing = protocols_missing("nosuch://x")
    assert missing is None or "built without nosuch://" in missing


def test_live_refuses_a_file_path_naming_what_it_expects(tmp_path, capsys):
    assert main(["live", str(tmp_path / "flight.ts")]) == 2
    assert "expected a stream URL" in capsys.readouterr().err


def test_view_refuses_a_stream_beside_files_and_a_protocol_this_ffmpeg_lacks(capsys):
    """(The window receiving a stream: tests/test_live_viewer.py.)"""
    assert main(["view", "udp://127.0.0.1:5600", "other.mp4"]) == 2
    assert "a stream opens alone" in capsys.readouterr().err
    if protocols_missing("srt://127.0.0.1:9000") is not None:
        assert main(["view", "srt://127.0.0.1:9000"]) == 2
        assert "was built without srt://" in capsys.readouterr().err


def test_a_recording_killed_mid_flight_is_still_a_clip(tmp_path):
    """`geofuse live --record` killed with SIGKILL while the feed is arriving: what it wrote
    opens as a clip with its KLV poses (a transport stream needs no trailer; each packet is
    flushed as it is muxed)."""
    feed = write_feed(tmp_path / "long.ts", 10.0, (320, 180))
    port = free_udp_port()
    record = tmp_path / "killed.ts"
    proc = subprocess.Popen(
        [sys.executable, "-m", "app", "live", f"udp://127.0.0.1:{port}", "--record", str(record)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port))
    try:
        assert proc.stdout.readline().startswith("receiving")  # it is about to listen
        assert wait_until(lambda: port_held(port), 60.0)
        sender.start()
        assert wait_until(lambda: record.is_file() and record.stat().st_size > 40_000, 60.0)
        proc.kill()
        proc.wait(10)
    finally:
        sender.stop()
        if proc.poll() is None:
            proc.kill()
    clip = open_clip(record)
    assert len(clip.video.pts_s) >= 10 and "telemetry" in clip.recorded


def test_rolling_segments_start_at_keyframes_and_each_opens_as_a_clip(feed, tmp_path):
    """The viewer's recording: a new segment at the first keyframe a segment's length after the
    last began (the feed has a keyframe a second); every frame kept once, each segment a clip
    with its KLV poses, and `holding` names the segment of a moment."""
    import av

    from app.io.klv_track import klv_streams
    from app.live.recorder import SegmentRecorder

    rec = SegmentRecorder(tmp_path / "live", segment_s=1.0)
    with av.open(str(feed)) as c:
        video, klv = c.streams.video[0], klv_streams(c)[0]
        rec.add_input(video, klv)
        for packet in c.demux(video, klv):
            if packet.size:
                rec.write(packet, "video" if packet.stream is video else "klv")
    rec.close()
    assert len(rec.segments) == 3
    frames = 0
    for k, segment in enumerate(rec.segments):
        clip = open_clip(segment.path)
        assert "telemetry" in clip.recorded
        frames += len(clip.video.pts_s)
        assert segment.first_s == pytest.approx(clip.video.origin_s, abs=1e-6)
        assert rec.holding(segment.first_s + 0.5) is segment, k
    assert frames == 90


def test_live_positions_that_jump_are_not_followed():
    """A set whose latitude flicks to the pole is dropped (counted) and the next set is judged
    against the last one kept; ten in a row that agree with each other are believed."""
    poses = LivePoses(stale_after_s=0.1)
    frame = LocalFrame(ORBIT.lat_deg, ORBIT.lon_deg, ORBIT.ground_h_m)
    intr = Intrinsics.from_fov(320, 180, 50.0)
    sets = [parse(orbit_set(ORBIT, t, 30.0)) for t in np.arange(0.0, 1.0, 0.1)]
    pole = replace(sets[3], values={**sets[3].values, "sensor_latitude_deg": 89.9})
    for k, s in enumerate(sets):
        assert poses.add(k * 0.1, pole if k == 3 else s) is (k != 3)
    assert poses.jumps == 1
    at = poses.at(0.3, frame, intr, 1000.0).camera.position
    assert np.linalg.norm(np.asarray(at)[:2] - ORBIT.position(0.3)[:2]) < 1.0
    moved = [replace(s, values={**s.values, "sensor_latitude_deg": 10.0}) for s in sets]
    kept = [poses.add(1.0 + 0.1 * k, s) for k, s in enumerate(moved)]
    assert kept == [False] * 9 + [True] and poses.jumps == 10
    # between the last set kept (0.9 s) and the jumped one believed (1.9 s) the frames are drawn
    # where the last kept set put them, never part of the way to latitude 10 (a keyframe
    # registered there would find a shift no fix had); the jumped set's own time: the jump
    before = np.asarray(poses.at(0.9, frame, intr, 1000.0).camera.position)
    for t in (1.0, 1.5, 1.89):
        assert np.allclose(poses.at(t, frame, intr, 1000.0).camera.position, before, atol=1e-6)
    after = poses.at(1.9, frame, intr, 1000.0).camera.position
    want = frame.geodetic_to_enu(*(np.array([v]) for v in poses.geodetic[-1]))[0]
    assert np.allclose(after, want, atol=1e-3)


class _Kept:
    """A sink that keeps what it is given (app.share.hub.Sink)."""

    name = "kept"

    def __init__(self):
        self.frames, self.marks, self.closed = [], [], False

    def send_frame(self, frame):
        self.frames.append(frame)

    def send_marks(self, marks):
        self.marks.append(marks)

    def close(self):
        self.closed = True


def test_a_feed_shares_each_drawn_frames_pose_and_point_of_interest(feed, tmp_path):
    """`live` with a sink (issue 53): the frames shared are frames drawn, each with the pose it
    was drawn with, its point of interest on its own optical axis, the pose source said, the
    stream named and a picture; the sink is closed at the end."""
    kept = _Kept()
    run, _, cameras = _run_with_sender(feed, tmp_path, {}, sinks=(lambda messages: kept,))
    assert kept.closed and kept.frames
    assert len(kept.frames) <= len(cameras)
    drawn = {round(d.pts_s, 6): cam for d, cam in cameras}
    for f in kept.frames:
        cam = drawn[round(f.media_s, 6)]
        sensor = run.frame.geodetic_to_enu(*f.sensor)
        assert np.linalg.norm(sensor - np.asarray(cam.position)) < 0.01
        axis = cam.pixel_rays(np.array([[cam.intrinsics.width / 2, cam.intrinsics.height / 2]]))[0]
        to_centre = run.frame.geodetic_to_enu(*f.centre) - np.asarray(cam.position)
        off_deg = np.degrees(np.arccos(axis @ to_centre / np.linalg.norm(to_centre)))
        assert off_deg < 0.05
        assert (f.source, f.clip) == ("klv", run.url)
    assert kept.frames[0].thumbnail[:2] == b"\xff\xd8"


BINDER = """
import socket, sys
port, failed = int(sys.argv[1]), 0
for _ in range(int(sys.argv[2])):
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("", port))
    except OSError:
        failed += 1
print(failed)
"""


def test_asking_whether_a_port_is_held_never_takes_it():
    """port_held says a bound UDP port is held and a released one is not, and asking it over
    and over never makes another process's bind of that port fail: a probe that bound the port
    itself made 19 % of 20000 binds fail (EADDRINUSE), a receiver's now and then on a loaded
    machine (a flaky test of the receiver's garbage datagrams)."""
    port = free_udp_port()
    assert not port_held(port)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("", port))
        assert port_held(port)
    assert not port_held(port)
    asking = threading.Event()

    def ask() -> None:
        while not asking.is_set():
            port_held(port)

    thread = threading.Thread(target=ask, daemon=True)
    thread.start()
    try:
        binder = [sys.executable, "-c", BINDER, str(port), "5000"]
        failed = subprocess.run(binder, capture_output=True, text=True, timeout=120, check=True)
    finally:
        asking.set()
        thread.join(5.0)
    assert failed.stdout.strip() == "0"
