"""Readers on good and bad input: every error names the file and the line or field."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from app.core.errors import DataFormatError, VideoError
from app.core.messages import Messages
from app.geodesy import rotations
from app.io import csvlog, video
from app.io.gpx import read_gpx
from app.io.sensorlogger import read_sensorlogger
from app.io.video import decode, frames_at, probe, read_frame
from app.simulate.phone import write_video


def write(path, text):
    path.write_text(text)
    return path


def test_vector_csv_units_and_repairs(tmp_path):
    p = write(
        tmp_path / "gyr.csv",
        "time_ns,x[deg/s],y[deg/s],z[deg/s]\n1000000000,90,0,0\n1010000000,nan,0,0\n1020000000,0,oops,0\n995000000,0,0,0\n1030000000,0,0,180\n",
    )
    w = Messages()
    s = csvlog.read_vector(p, "gyr", w)
    np.testing.assert_allclose(s.t, [1.0, 1.03])
    np.testing.assert_allclose(s.values, [[np.pi / 2, 0, 0], [0, 0, np.pi]])
    text = " | ".join(w.items)
    assert "1 rows with missing or unparsable numbers dropped (first at line 4)" in text
    assert "1 rows with NaN values dropped (first at line 3)" in text
    assert "goes backwards 1 times" in text and "line 5" in text


def test_gyroscope_in_degrees_without_units_is_detected(tmp_path):
    rows = "\n".join(f"{i / 100},{30 * np.sin(i / 10):.3f},0,0" for i in range(200))
    w = Messages()
    s = csvlog.read_vector(write(tmp_path / "g.csv", "t,x,y,z\n" + rows), "gyr", w)
    assert np.abs(s.values).max() < 0.6
    assert any("look like deg/s" in m for m in w.items)


def test_missing_column_names_file_and_column(tmp_path):
    with pytest.raises(DataFormatError) as err:
        csvlog.read_vector(write(tmp_path / "acc.csv", "t,x,y\n0,1,2\n"), "acc")
    assert "acc.csv:1 field 'z'" in str(err.value)
    with pytest.raises(DataFormatError, match="no time column"):
        csvlog.read_vector(write(tmp_path / "a2.csv", "when,x,y,z\n0,1,2,3\n"), "acc")
    with pytest.raises(DataFormatError, match="unknown unit 'furlong'"):
        csvlog.read_vector(
            write(tmp_path / "a3.csv", "t,x[furlong],y,z\n0,1,2,3\n1,1,2,3\n"), "acc"
        )
    with pytest.raises(DataFormatError, match="does not exist"):
        csvlog.read_vector(tmp_path / "nope.csv", "acc")


def test_gnss_csv_with_speed_and_bearing(tmp_path):
    p = write(
        tmp_path / "gnss.csv",
        "t,lat,lon,h,speed,bearing\n0,34.8,113.53,110,2,90\n1,34.8,113.53002,110,2,90\n",
    )
    g = csvlog.read_gnss(p)
    np.testing.assert_allclose(g.vel_enu[0], [2, 0, 0], atol=1e-12)
    messages = Messages()
    g = csvlog.read_gnss(
        write(tmp_path / "some.csv", "t,lat,lon,h\n0,134.8,113,0\n1,34,113,0\n2,34,113.00001,0\n"),
        messages,
    )
    assert list(g.t) == [1, 2] and any("1 out of range" in w for w in messages.items)
    with pytest.raises(DataFormatError, match="no fix has a latitude in"):
        csvlog.read_gnss(write(tmp_path / "bad.csv", "t,lat,lon,h\n0,134.8,113,0\n1,95,113,0\n"))


def test_orientation_csv_must_hold_unit_quaternions(tmp_path):
    with pytest.raises(DataFormatError, match="not unit length"):
        csvlog.read_orientation(write(tmp_path / "o.csv", "t,qw,qx,qy,qz\n0,1,0,0,0\n1,2,0,0,0\n"))


# --- GPX from real receivers (../shared/data/real/gpx) -----------------------------------------

GPX_EXPECT = {
    # file: (points, first (lat, lon), last (lat, lon)), read from the files by eye
    "around-visnjan-with-car.gpx": (
        104,
        (45.273518851, 13.7142099626),
        (45.2733349521, 13.7139970623),
    ),
    "track_with_speed.gpx": (3, (52.330848, 5.541371), (52.331014, 5.541333)),
    "track-with-empty-segment.gpx": (9, (50.7772126, 6.0819695), (50.7776715, 6.0827203)),
}


@pytest.mark.shared_data
@pytest.mark.parametrize("name", sorted(GPX_EXPECT))
def test_gpx_tracks(shared_data, name):
    n, first, last = GPX_EXPECT[name]
    g = read_gpx(shared_data / "real" / "gpx" / name)
    assert len(g.t) == n
    assert (g.lat[0], g.lon[0]) == pytest.approx(first) and (g.lat[-1], g.lon[-1]) == pytest.approx(
        last
    )
    assert np.all(np.diff(g.t) > 0)


@pytest.mark.shared_data
def test_gpx_traps(shared_data):
    folder = shared_data / "real" / "gpx"
    w = Messages()
    read_gpx(folder / "track-with-empty-segment.gpx", w)
    assert any("segment 2 is empty" in m for m in w.items)
    with pytest.raises(DataFormatError, match="track point 1 has no <time>") as err:
        read_gpx(folder / "cerknicko-without-times.gpx")
    assert "cerknicko-without-times.gpx" in str(err.value)
    with pytest.raises(DataFormatError, match="1901-12-13.*broken logger clock"):
        read_gpx(folder / "Mojstrovka.gpx")


# --- Sensor Logger exports, written as the app documents them -----------------------------------


def _sensorlogger_folder(folder, platform, q_true, t):
    """A recording of a static phone at attitude q_true, iOS or Android conventions."""
    folder.mkdir()
    ns = (1_700_000_000 + t) * 1e9
    inv = rotations.conjugate(q_true)
    g_dev = rotations.rotate(inv, [0, 0, 9.80665])  # specific force, +up at rest (Android)
    m_dev = rotations.rotate(inv, [0.0, 30.0, -40.0])

    def put(name, header, cols):
        data = np.column_stack([ns, t, *cols])
        np.savetxt(folder / name, data, delimiter=",", header=header, comments="", fmt="%.9f")

    zyx = "time,seconds_elapsed,z,y,x"
    put("Gyroscope.csv", zyx, [np.zeros_like(t)] * 3)
    put(
        "Magnetometer.csv",
        zyx,
        [np.full_like(t, m_dev[2]), np.full_like(t, m_dev[1]), np.full_like(t, m_dev[0])],
    )
    (folder / "Metadata.csv").write_text(
        f"version,device name,recording time,platform\n3,phone,2023-11-14,{platform}\n"
    )
    if platform == "android":
        put(
            "TotalAcceleration.csv",
            zyx,
            [np.full_like(t, g_dev[2]), np.full_like(t, g_dev[1]), np.full_like(t, g_dev[0])],
        )
        q_logged = q_true  # Android rotation vector: device -> ENU
    else:  # iOS: user acceleration + gravity, both with the opposite sign; attitude in x-north
        put("Accelerometer.csv", zyx, [np.zeros_like(t)] * 3)
        put(
            "Gravity.csv",
            zyx,
            [np.full_like(t, -g_dev[2]), np.full_like(t, -g_dev[1]), np.full_like(t, -g_dev[0])],
        )
        q_logged = rotations.multiply(rotations.about_z(-90.0), q_true)  # ENU -> NWU reference
    q = np.tile(q_logged, (len(t), 1))
    put(
        "Orientation.csv",
        "time,seconds_elapsed,qz,qy,qx,qw,roll,pitch,yaw",
        [q[:, 3], q[:, 2], q[:, 1], q[:, 0], *[np.zeros_like(t)] * 3],
    )
    (folder / "Location.csv").write_text(
        "time,seconds_elapsed,bearingAccuracy,speedAccuracy,verticalAccuracy,horizontalAccuracy,speed,bearing,altitude,longitude,latitude\n"
        f"{ns[0]:.0f},0,1,1,2,4,1.5,90,120.5,113.53,34.8\n{ns[-1]:.0f},{t[-1]},1,1,2,4,1.5,90,120.5,113.53002,34.8\n"
    )


@pytest.mark.parametrize("platform", ["android", "ios"])
def test_sensorlogger_folder_and_zip(tmp_path, platform):
    t = np.arange(0, 2, 0.01)
    q_true = rotations.camera_quat_from_hpr(40.0, 15.0, -5.0)
    folder = tmp_path / "Recording"
    _sensorlogger_folder(folder, platform, q_true, t)
    archive = tmp_path / "Recording.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in folder.iterdir():
            z.write(f, f"Recording/{f.name}")
    for src in (folder, archive):
        w = Messages()
        rec = read_sensorlogger(src, messages=w)
        assert rec.platform == platform
        up = rotations.rotate(q_true, rec.acc.values[0])
        np.testing.assert_allclose(
            up / np.linalg.norm(up), [0, 0, 1], atol=1e-6
        )  # +up specific force
        assert np.degrees(rotations.angle_between(rec.orientation.q[0], q_true)) < 1e-3
        np.testing.assert_allclose(rec.gnss.vel_enu[0], [1.5, 0, 0], atol=1e-9)
        assert rec.gnss.h[0] == pytest.approx(120.5)


def test_sensorlogger_errors(tmp_path):
    with pytest.raises(DataFormatError, match="not a Sensor Logger recording"):
        read_sensorlogger(write(tmp_path / "x.txt", "hello"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="no Gyroscope.csv"):
        read_sensorlogger(tmp_path / "empty")


# --- Video metadata --------------------------------------------------------------------------------


def test_probe_reads_variable_frame_times_and_rotation(tmp_path):
    rng = np.random.default_rng(0)
    pts = np.cumsum(np.concatenate([[0.0], rng.uniform(0.025, 0.042, 29)]))
    path = write_video(
        tmp_path / "vfr.mp4", pts, (64, 36), rotation_cw=90, creation_time="2023-11-14T22:13:20Z"
    )
    info = probe(path)
    np.testing.assert_allclose(info.pts_s, pts - pts[0], atol=1.5e-5)
    assert info.rotation_cw == 90 and info.display_size == (36, 64)
    assert info.variable_rate
    assert info.creation_time == pytest.approx(1_700_000_000.0)
    frame = read_frame(path, 5, info)
    assert frame.shape == (64, 36, 3)  # turned to portrait for display


def test_bad_videos(tmp_path):
    with pytest.raises(VideoError, match="does not exist"):
        probe(tmp_path / "none.mp4")
    junk = write(tmp_path / "junk.mp4", "not a video at all")
    with pytest.raises(VideoError, match="junk.mp4"):
        probe(junk)
    good = write_video(tmp_path / "ok.mp4", np.arange(20) / 30, (64, 36), 0)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    try:
        info = probe(cut)  # a truncated file: what can be read, or a clear error
        assert len(info.pts_s) <= 20
    except VideoError as exc:
        assert "cut.mp4" in str(exc)


@pytest.mark.parametrize("suffix", [".mp4", ".ts"])
def test_frames_late_in_a_video_are_sought_not_decoded_up_to(tmp_path, suffix, monkeypatch):
    """Frames wanted 15 s into a 20 s clip: the same pixels as decoding it from the start, from
    the keyframe before them (an MP4's index; a transport stream's timestamps) rather than
    through the 450 frames before them."""
    times = np.arange(600) / 30.0
    path = write_video(tmp_path / f"clip{suffix}", times, (96, 64), 0)
    info = probe(path)
    late = list(range(450, 600, 7))
    from_start = dict(frames_at(info, [0, *late]))
    decoded = []

    def counted(container, stream, skipped=None):
        for frame in decode(container, stream, skipped):
            decoded.append(frame.pts)
            yield frame

    monkeypatch.setattr(video, "decode", counted)
    sought = dict(frames_at(info, late))
    assert sorted(sought) == late
    for i in late:
        np.testing.assert_array_equal(sought[i], from_start[i])
    assert len(decoded) < 600 - 450 + 260, len(decoded)  # at most a GOP before (x264's 250)


def test_a_seek_that_lands_past_the_frames_wanted_backs_off(tmp_path, monkeypatch):
    """FFmpeg's search in a file without an index may land past the time asked: the first seek
    here lands 3 s late (its frames before that dropped), so decoded_at seeks 2 s earlier, and
    gives the same pixels as a decode from the start; seeks that always land past the first
    frame wanted (15 s) back off 2 s, then 10 s, and end in a decode from the start."""
    path = write_video(tmp_path / "clip.ts", np.arange(600) / 30.0, (96, 64), 0)
    info = probe(path)
    late = list(range(450, 600, 7))
    from_start = dict(frames_at(info, [0, *late]))
    timed, asked = video._timed, []

    def landing_late(container, stream, origin_s, from_s=None, always=False):
        asked.append(from_s)
        frames = timed(container, stream, origin_s, from_s)
        if from_s is None or (len(asked) > 1 and not always):
            yield from frames
            return
        lands = 16.0 if always else from_s + 3.0  # (always: past the first frame wanted)
        yield from ((t, f) for t, f in frames if t >= lands)

    monkeypatch.setattr(video, "_timed", landing_late)
    sought = dict(frames_at(info, late))
    assert asked == pytest.approx([14.983, 12.983], abs=1e-3)  # the second, 2 s back, lands
    for i in late:
        np.testing.assert_array_equal(sought[i], from_start[i])
    asked.clear()
    monkeypatch.setattr(video, "_timed", lambda *args, **kw: landing_late(*args, **kw, always=True))
    assert sorted(dict(frames_at(info, late))) == late
    assert asked[:3] == pytest.approx([14.983, 12.983, 4.983], abs=1e-3) and asked[3:] == [None]
