"""DJI .SRT telemetry on the real files in ../shared/data/real/dji (values read from the files)."""

import numpy as np
import pytest

from app.core.errors import DataFormatError
from app.core.messages import Messages
from app.io.dji_srt import check_duration, read_srt

pytestmark = pytest.mark.shared_data

EXPECT = {
    # file: (entries, first (lat, lon, height), last (lat, lon, height), heights relative to take-off)
    "air2s.srt": (17, (41.424724, 2.234156, 117.0), (41.424730, 2.234102, 117.1), False),
    "mavic_air2.srt": (25, (41.420684, 2.162162, 27.3), (41.420686, 2.162162, 29.2), False),
    "matrice_300.srt": (381, (36.6146, -6.1120, 0.3), (36.6146, -6.1120, 0.0), True),
    "mavic_pro.SRT": (468, (-20.2533, 149.0251, 1.9), (-20.2532, 149.0251, 0.0), True),
    "p4_rtk.SRT": (55, (-34.237922, -58.851745, 85.8), (-34.232349, -58.849196, 85.8), True),
    "p4p_sample.SRT": (5, (47.4692, 8.2090, 45.6), (47.4692, 8.2090, 45.6), True),
}


@pytest.mark.parametrize("name", sorted(EXPECT))
def test_layouts_positions_and_heights(shared_data, name):
    n, first, last, relative = EXPECT[name]
    t = read_srt(shared_data / "real" / "dji" / name)
    ok = t.has_position
    assert len(t.t) == n and ok.all()
    np.testing.assert_allclose((t.lat[0], t.lon[0], t.height[0]), first, atol=1e-9)
    np.testing.assert_allclose((t.lat[-1], t.lon[-1], t.height[-1]), last, atol=1e-9)
    assert t.height_relative is relative
    assert np.all(np.diff(t.t) > 0)


def test_gimbal_attitude_and_wall_clock(shared_data):
    p4 = read_srt(shared_data / "real" / "dji" / "p4_rtk.SRT")
    assert p4.has_gimbal
    np.testing.assert_allclose(p4.gimbal_pry[-1], [-24.4, 0.0, 111.9])
    np.testing.assert_allclose(p4.aircraft_pry[-1], [8.4, -20.1, 109.2])
    air = read_srt(shared_data / "real" / "dji" / "air2s.srt")
    assert not air.has_gimbal
    assert air.wall_clock[1] - air.wall_clock[0] == pytest.approx(
        0.033356, abs=1e-6
    )  # microseconds kept
    assert air.t[1] == pytest.approx(0.033)  # one entry per frame


def test_broken_files(shared_data):
    folder = shared_data / "real" / "dji"
    with pytest.raises(DataFormatError, match="broken_empty.SRT: empty subtitle file"):
        read_srt(folder / "broken_empty.SRT")
    w = Messages()
    t = read_srt(folder / "broken_incomplete.SRT", w)
    assert len(t.t) == 19 and "the last entry is cut short" in w.items[0]


def test_synthetic_traps(tmp_path):
    p = tmp_path / "mixed.srt"
    p.write_bytes(
        "\ufeff1\r\n00:00:00,000 --> 00:00:01,000\r\n[latitude: 10.5] [longtitude: 20.25] [rel_alt: 3.0 abs_alt: 120.5]\r\n\r\n"
        "2\r\n00:00:01,000 --> 00:00:02,000\r\nGPS(20.30,10.51,5) BAROMETER:3.5\r\n\r\n"
        "3\r\n00:00:02,000 --> 00:00:03,000\r\nISO:100\r\n\r\n".encode("utf-8")
    )
    w = Messages()
    t = read_srt(p, w)
    np.testing.assert_allclose(t.lat[:2], [10.5, 10.51])
    np.testing.assert_allclose(t.lon[:2], [20.25, 20.30])
    assert not np.isfinite(t.lat[2])
    assert t.height_relative and t.height[0] == 3.0
    text = " ".join(w.items)
    assert "1 entries without a position" in text and "mixes layouts" in text
    nopos = tmp_path / "nopos.srt"
    nopos.write_text("1\n00:00:00,000 --> 00:00:01,000\nISO:100\n")
    with pytest.raises(DataFormatError, match="none of the 1 entries has a position"):
        read_srt(nopos)
    with pytest.raises(DataFormatError, match="span 0-3.0 s but the video lasts 100.0 s"):
        check_duration(t, 100.0)
    check_duration(t, 3.0)
