"""Drone flights in the simulator (`geofuse simulate session --flight survey|orbit`): the paths
worked out by hand, and a short survey session whose video's centre pixel lands on the ground
straight under the aircraft."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli import main
from app.geodesy import rotations
from app.locate.location import locate
from app.simulate.flights import (
    ORBIT_HEIGHT_M,
    ORBIT_RADIUS_M,
    ORBIT_TARGET,
    SURVEY_HEIGHT_M,
    SURVEY_LINES_Y,
    SURVEY_SPEED,
    SURVEY_X,
    _survey_path,
    orbit,
    survey,
)
from app.simulate.sample import SAMPLE_SCENE
from app.simulate.session import (
    FLIGHT_OF,
    SYNC_ERROR_S,
    SampleConfig,
    quick_config,
    write_sample_session,
)


def _axis(hpr: np.ndarray) -> np.ndarray:
    """The optical axes (N, 3) ENU of headings, pitches, rolls (deg)."""
    return rotations.camera_matrix_from_hpr(*hpr.T)[:, :, 2] * -1.0


def test_the_survey_flies_lawn_mower_lines_at_70_m_looking_down():
    f = survey()
    t = np.arange(0.0, 250.0, 0.01)  # more than two rounds: the loop closes without a jump
    p = f.position(t)
    assert np.allclose(p[:, 2], SURVEY_HEIGHT_M)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert step.max() < SURVEY_SPEED * 0.01 * 1.001  # continuous, at its speed
    assert step.min() > SURVEY_SPEED * 0.01 * 0.98
    # the heading of travel is the direction it moves in, everywhere (turns included)
    v = np.diff(p, axis=0)
    moving = np.degrees(np.arctan2(v[:, 0], v[:, 1]))
    _, travel = _survey_path(SURVEY_SPEED * (t[:-1] + 0.005))
    assert np.abs((moving - travel + 180) % 360 - 180).max() < 0.5
    # the first leg runs east along the first line, the second west along the next
    assert p[0, :2] == pytest.approx([SURVEY_X[0], SURVEY_LINES_Y[0]])
    leg = (SURVEY_X[1] - SURVEY_X[0]) / SURVEY_SPEED
    turn = np.pi * (SURVEY_LINES_Y[1] - SURVEY_LINES_Y[0]) / 2 / SURVEY_SPEED
    assert f.position(np.array([leg + turn + 1.0]))[0, :2] == pytest.approx(
        [SURVEY_X[1] - SURVEY_SPEED, SURVEY_LINES_Y[1]]
    )
    axis = _axis(f.hpr(t))
    assert np.allclose(axis, [0.0, 0.0, -1.0], atol=1e-9)  # straight down
    # the image's top points along the track on the legs
    up = rotations.camera_matrix_from_hpr(*f.hpr(np.array([leg / 2, leg + turn + leg / 2])).T)[
        :, :, 1
    ]
    assert up[0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)
    assert up[1] == pytest.approx([-1.0, 0.0, 0.0], abs=1e-6)


def test_the_orbit_circles_the_hall_with_the_camera_on_it():
    f = orbit()
    t = np.linspace(0.0, 200.0, 400)
    p = f.position(t)
    r = np.hypot(p[:, 0] - ORBIT_TARGET[0], p[:, 1] - ORBIT_TARGET[1])
    assert np.allclose(r, ORBIT_RADIUS_M) and np.allclose(p[:, 2], ORBIT_HEIGHT_M)
    to_target = np.asarray(ORBIT_TARGET) - p
    to_target /= np.linalg.norm(to_target, axis=1, keepdims=True)
    assert np.allclose(_axis(f.hpr(t)), to_target, atol=1e-9)
    assert p[0, 1] == pytest.approx(-ORBIT_RADIUS_M)  # it starts south of the hall


def test_a_survey_session_sees_the_ground_straight_under_the_aircraft(tmp_path):
    """The session a survey writes (drone: no display rotation, GNSS heights its own): under its
    true pose, the centre pixel of a frame lies on the ground, straight under the aircraft."""
    manifest = write_sample_session(
        tmp_path, SAMPLE_SCENE, SampleConfig(**{**quick_config(2.0).__dict__, "flight": "survey"})
    )
    text = manifest.read_text()
    assert 'height = "gnss"' in text and "drone surveying" in text
    (loc,) = locate(manifest, 1.0, [[320.0, 180.0]], attitude="truth")
    # the manifest's start time is the sample's 80 ms late (SYNC_ERROR_S): the session's clock
    # puts the frame shown at 1 s that much later along the track, 10 m/s
    below = FLIGHT_OF["survey"].position(np.array([1.0 + SYNC_ERROR_S]))[0]
    assert loc.enu[2] == pytest.approx(0.0, abs=0.05)  # the ground
    assert np.hypot(loc.enu[0] - below[0], loc.enu[1] - below[1]) < 0.1
    assert loc.range_m == pytest.approx(SURVEY_HEIGHT_M, abs=0.3)


def test_an_orbit_session_on_the_sites_city_model(tmp_path):
    """`geofuse simulate session --flight orbit --city`: the manifest names the site's LoD2
    CityJSON written beside it (no up axis: the file's CRS places it), and the frame's centre
    under the true pose lies on the hall's roof or walls, named as the city object it is (the
    camera looks at the hall from 60 m: the centre ray meets the hall)."""
    out = tmp_path / "orbit"
    assert (
        main(
            [
                "simulate",
                "session",
                "--out",
                str(out),
                "--flight",
                "orbit",
                "--duration",
                "1",
                "--city",
            ]
        )
        == 0
    )
    text = (out / "session.toml").read_text()
    assert 'path = "site.city.json"' in text and "up_axis" not in text
    assert (out / "site.city.json").is_file()
    (loc,) = locate(out / "session.toml", 0.5, [[320.0, 180.0]], attitude="truth")
    assert loc.feature is not None and loc.feature.id == "hall"
    assert loc.feature.surface in ("roof", "wall")
