"""A DJI clip with its subtitle's fixes (no IMU: the gimbal's angles are its attitude)
registered against a georeferenced scene, straight from its files: every frame within the
registration's usual error of the flight, and through a stretch where the subtitle has no fix
(DJI writes 0, 0: jammed) the keyframes carry the track where a straight line between the fixes
around would cut the weave's curve by 12 m. Such a clip used to end in a LinAlgError (the
smoother's covariance without an accelerometer was singular)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from app.cli import main
from app.geodesy.enu import LocalFrame
from app.simulate import drone
from app.simulate.stadium import SITE_ORIGIN
from app.simulate.tileset import write_site
from tests.test_cold_start_dji import TOLERANCE_M

SECONDS = 8.0
OUTAGE = (1.0, 7.0)  # s of the clip without a fix (longer than the gap rule's 5 s), through the
# weave's swing 14 m north and back


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """(video, the site's tileset): the weave's first 8 s."""
    folder = tmp_path_factory.mktemp("dji-fixed")
    video = drone.write_video(folder / "DJI_0001.MP4", SECONDS, (320, 180))
    return video, write_site(folder / "site")


def _solved(clip, tmp_path, outage=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`geofuse solve CLIP --scene SITE --source registered` with the subtitle beside the clip:
    (clip times s, each frame's distance m from the flight, its gnss status)."""
    video, site = clip
    srt = video.with_suffix(".SRT")
    srt.write_text(drone.srt_text(SECONDS, 0.0, gimbal=True, outage=outage), encoding="utf-8")
    out = tmp_path / "track.csv"
    args = ["solve", str(video), "--scene", str(site), "--source", "registered", "--out", str(out)]
    assert main(args) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows])
    got = LocalFrame(*SITE_ORIGIN).geodetic_to_enu(
        *(np.array([[float(r[k]) for r in rows] for k in ("latitude", "longitude", "height")]))
    )
    truth, _ = drone.flight(t)
    return t, np.linalg.norm(got - truth, axis=1), np.array([r["gnss"] for r in rows])


def test_a_dji_clip_registers_with_its_fixes(clip, tmp_path):
    t, error, gnss = _solved(clip, tmp_path)
    assert len(t) == int(SECONDS * drone.FPS)
    assert set(gnss) == {"used"}
    assert error.max() < TOLERANCE_M and np.median(error) < TOLERANCE_M / 4


def test_a_stretch_without_a_fix_is_carried_by_the_keyframes(clip, tmp_path, capsys):
    t, error, gnss = _solved(clip, tmp_path, OUTAGE)
    inside = (t >= OUTAGE[0]) & (t < OUTAGE[1])
    assert set(gnss[inside]) == {"missing"} and set(gnss[~inside]) == {"used"}
    assert error.max() < TOLERANCE_M and np.median(error[inside]) < TOLERANCE_M / 2
    # what a straight line between the fixes around the stretch would have missed by
    ends, _ = drone.flight(np.array(OUTAGE))
    line = ends[0] + (ends[1] - ends[0]) * ((t[inside] - OUTAGE[0]) / np.diff(OUTAGE))[:, None]
    truth, _ = drone.flight(t[inside])
    assert np.linalg.norm(line - truth, axis=1).max() > 5 * TOLERANCE_M
    said = capsys.readouterr().err
    assert "no GNSS from t = 1.0 s to 7.0 s (6 s): the registered keyframes carry the track" in said
