"""GoPro GPMF: the decoder on raw payloads, and the MAX sample MP4 as a session."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from app.attitude.gopro import read_gopro
from app.cli import main
from app.core.errors import DataFormatError
from app.io.gopro import orin_map
from app.io.gpmf import Counts, chunks, parse

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def gopro(shared_data):
    return shared_data / "real" / "gopro"


@pytest.mark.parametrize(
    "name, device, accl, gyro, has_mag",
    [
        ("hero5", "Camera", 199, 399, False),
        ("hero6", "Hero6 Black", 204, 204, False),
        ("Fusion", "Fusion", 197, 3300, True),
    ],
)
def test_raw_payloads(gopro, name, device, accl, gyro, has_mag):
    counts = Counts()
    streams = {
        c.key: c
        for c in chunks(parse((gopro / f"{name}.raw").read_bytes(), name, counts), 0.0, 1.0)
    }
    assert streams["ACCL"].device == device
    assert len(streams["ACCL"].samples) == accl and len(streams["GYRO"].samples) == gyro
    assert ("MAGN" in streams) == has_mag
    a = np.linalg.norm(streams["ACCL"].samples, axis=1)
    assert 8.5 < np.median(a) < 11.0  # scaled by SCAL into m/s^2
    gps = streams["GPS5"].samples
    assert np.all(np.abs(gps[:, 0]) <= 90) and np.all(
        np.abs(gps[:, 1]) <= 180
    )  # lat, lon in degrees
    assert counts.skipped == {}


def test_cut_payload_is_a_clear_error(gopro):
    data = (gopro / "hero6.raw").read_bytes()
    with pytest.raises(DataFormatError, match=r"GPMF payload cut short: 'DEVC' at byte 0"):
        parse(data[: len(data) // 2], "hero6.raw")


def test_orin_axis_order():
    v = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(orin_map("XzY", v), [[1.0, 3.0, -2.0]])
    np.testing.assert_array_equal(orin_map("ZXY", v), [[2.0, 3.0, 1.0]])


@pytest.fixture(scope="module")
def max_recording(gopro):
    return read_gopro(gopro / "max-heromode.mp4")


def test_gravity_on_an_upright_camera(max_recording):
    """The camera is carried upright: the accelerometer's mean points along device +y (up)."""
    a = max_recording.acc.values.mean(axis=0)
    assert a[1] > 9.0 and abs(a[0]) < 1.0 and abs(a[2]) < 3.0
    assert max_recording.raw.model == "GoPro Max"
    assert 190 < 1 / np.median(np.diff(max_recording.gyr.t)) < 205


def test_gyroscope_agrees_with_the_cameras_own_orientation(max_recording):
    """The fitted axis mapping makes the gyro integrate to the camera's own orientation (CORI)."""
    from app.geodesy import rotations

    cam = max_recording.camera
    g = max_recording.gyr
    k = (cam.t > 1.0) & (cam.t < 9.0)
    q = cam.q[k]
    dq = rotations.multiply(rotations.conjugate(q[:-1]), q[1:])
    w = rotations.to_scipy(dq).as_rotvec() / np.diff(cam.t[k])[:, None]
    tm = (cam.t[k][:-1] + cam.t[k][1:]) / 2
    gi = np.column_stack([np.interp(tm, g.t, g.values[:, j]) for j in range(3)])
    assert np.median(np.linalg.norm(gi - w, axis=1)) < 0.2 * np.median(np.linalg.norm(w, axis=1))


def test_timing_spreads_samples_over_payload_spans(max_recording):
    t = max_recording.gyr.t
    assert 0.0 < t[0] < 0.01 and 10.4 < t[-1] < 10.6  # a 10.5 s clip
    assert np.all(np.diff(t) > 0)


def test_solve_every_source_one_row_per_frame(gopro, tmp_path, capsys):
    clip = gopro / "max-heromode.mp4"
    from app.footage.clips import open_clip

    session = open_clip(clip)
    assert "magnetometer reads" in " ".join(session.messages.items)  # 521 uT: rejected
    assert (
        session.mag is None
        and session.heading_from_course
        and session.heading_note.startswith("heading from the GNSS course")
    )
    track = session.positions()
    for source in session.sources:
        out = tmp_path / f"{source}.csv"
        assert main(["solve", str(clip), "--source", source, "--out", str(out)]) == 0
        with out.open() as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == 315, source
        heading = np.array([float(r["heading"]) for r in rows])
        # Walking south-east (GPS course about 150 deg): the camera looks where it goes.
        assert abs(((np.median(heading) - 150.0) + 180) % 360 - 180) < 20, (
            source,
            np.median(heading),
        )
        lat = np.array([float(r["latitude"]) for r in rows])
        assert (
            track.lat.min() - 1e-5 <= lat.min() and lat.max() <= track.lat.max() + 1e-5
        )  # on the GPS track


def test_mp4_without_telemetry_and_truncated_mp4(gopro, tmp_path, capsys):
    from app.simulate.phone import write_video

    plain = write_video(tmp_path / "plain.mp4", np.arange(10) / 30, (64, 32), 0)
    assert main(["solve", str(plain), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err
    assert "no GoPro telemetry track" in err and "--srt" in err and "manifest" in err
    data = (gopro / "max-heromode.mp4").read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 3])  # MP4 keeps its index at the end: nothing can be read
    assert main(["telemetry", str(cut)]) == 2
    err = capsys.readouterr().err
    assert "cut.mp4" in err and "Traceback" not in err


def test_lens_field_of_view_from_the_metadata(gopro):
    from app.io.gopro import global_settings, lens_hfov

    settings = global_settings(gopro / "max-heromode.mp4")
    assert settings["VFOV"] == "W"  # the recorded lens mode: wide
    assert float(settings["ZFOV"].ravel()[0]) == pytest.approx(
        137.39, abs=0.01
    )  # diagonal, degrees
    hfov = lens_hfov(settings, 848, 480)
    # tan(h/2) = tan(d/2) * 848 / hypot(848, 480)
    assert hfov == pytest.approx(
        np.degrees(2 * np.arctan(np.tan(np.radians(137.39) / 2) * 848 / np.hypot(848, 480))),
        abs=0.01,
    )
    assert lens_hfov({}, 848, 480) is None


@pytest.mark.parametrize(
    "name, model, expected",
    [("hero5", "Camera", "ZXY"), ("hero6", "Hero6 Black", "ZXY"), ("Fusion", "Fusion", "yXZ")],
)
def test_axis_order_without_orin_comes_from_gravity(shared_data, name, model, expected):
    """Raw payloads of cameras that write no ORIN (and no CORI): a HERO5 names itself 'Camera',
    so its documented order cannot be found by name; the order under which gravity points up
    for a camera held level is chosen instead. (HERO6's documented 'YxZ' put gravity along the
    lens axis here: the camera would have come out turned on its back.)"""
    from app.attitude.gopro import LEVEL_TOLERANCE_DEG, choose_axis_order
    from app.io.gpmf import Counts, chunks, parse

    tree = parse((shared_data / "real" / "gopro" / f"{name}.raw").read_bytes(), name, Counts())
    parts = chunks(tree, 0.0, 1.0)
    acc = np.concatenate([c.samples for c in parts if c.key == "ACCL"])
    gyr = np.concatenate([c.samples for c in parts if c.key == "GYRO"])
    assert "ORIN" not in next(c for c in parts if c.key == "ACCL").modifiers
    order, angle = choose_axis_order(acc, gyr, model)
    assert order == expected and angle < LEVEL_TOLERANCE_DEG


def test_a_time_lapse_is_recognised_by_its_gps_clock(shared_data):
    """Real time against video time from GPSU: the real MAX clip runs at 1x; a TimeWarp whose
    GPS clock advances 10 s per video second is refused (by the same ratio)."""
    from app.io.gopro import TIMELAPSE_RATIO, gpsu_times, read_payloads, real_time_ratio
    from app.io.gpmf import Counts, chunks, parse

    by_key: dict = {}
    path = shared_data / "real" / "gopro" / "max-heromode.mp4"
    for i, (payload, t0, t1) in enumerate(read_payloads(path)):
        for c in chunks(parse(payload, str(i), Counts()), t0, t1):
            by_key.setdefault(c.key, []).append(c)
    pairs = gpsu_times(by_key)
    assert real_time_ratio(pairs) == pytest.approx(1.0, abs=0.15)
    warped = [(v, pairs[0][1] + 10.0 * (v - pairs[0][0])) for v, _ in pairs]
    assert (
        real_time_ratio(warped) == pytest.approx(10.0) and real_time_ratio(warped) > TIMELAPSE_RATIO
    )
