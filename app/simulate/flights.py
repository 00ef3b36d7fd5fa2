"""How the simulated camera moves over the sample site: the walk (the bundled sample's: a phone
carried past the hall's south front), a survey (a drone's lawn-mower lines at 70 m with the
camera looking straight down, as for mapping) and an orbit (a drone circling the hall at 60 m,
the camera on its centre). Each is a position (ENU m of the site, app.simulate.stadium) and the
optical axis's heading, pitch and roll (deg, app.geodesy.rotations) at any time (s from the
start), smooth enough for the simulated IMU (app.simulate.phone differentiates them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

FLIGHTS = ("walk", "survey", "orbit")

SURVEY_HEIGHT_M = 70.0
SURVEY_SPEED = 10.0  # m/s
SURVEY_LINES_Y = (-75.0, -25.0, 25.0, 75.0)  # north of the hall's centre, m
SURVEY_X = (-90.0, 90.0)  # each line from west to east or back, m
ORBIT_RADIUS_M = 110.0
ORBIT_HEIGHT_M = 60.0
ORBIT_SPEED = 6.0  # m/s
ORBIT_TARGET = (0.0, 0.0, 10.0)  # the hall's middle, ENU m


@dataclass(frozen=True)
class Flight:
    """A camera's path: name (FLIGHTS), position(t) -> (N, 3) ENU m, hpr(t) -> (N, 3) deg;
    aircraft: flown (GNSS heights are the aircraft's, not the ground's plus a mount)."""

    name: str
    position: Callable[[np.ndarray], np.ndarray]
    hpr: Callable[[np.ndarray], np.ndarray]
    aircraft: bool


def _survey_path(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (N, 3), heading of travel (N,) deg) at arc length s (m) along the lawn-mower
    lines: straight legs east and west joined by half circles (radius half the line spacing),
    then back to the start along the west side (a quarter circle, a leg south, a quarter
    circle): a closed loop flown again and again without a jump."""
    x0, x1 = SURVEY_X
    y_first, y_last = SURVEY_LINES_Y[0], SURVEY_LINES_Y[-1]
    leg = x1 - x0
    r = (SURVEY_LINES_Y[1] - SURVEY_LINES_Y[0]) / 2
    turn, quarter = np.pi * r, np.pi * r / 2
    legs = len(SURVEY_LINES_Y)  # even: the last leg ends on the west side, flying west
    lines = legs * leg + (legs - 1) * turn
    back = (y_last - r) - (y_first + r)
    period = lines + 2 * quarter + back
    s = np.mod(np.asarray(s, np.float64), period)
    out = np.zeros((len(s), 3))
    heading = np.zeros(len(s))
    out[:, 2] = SURVEY_HEIGHT_M
    for i in range(legs):
        start = i * (leg + turn)
        on_leg = (s >= start) & (s < start + leg)
        east = i % 2 == 0
        u = s[on_leg] - start
        out[on_leg, 0] = x0 + u if east else x1 - u
        out[on_leg, 1] = SURVEY_LINES_Y[i]
        heading[on_leg] = 90.0 if east else 270.0
        if i == legs - 1:
            continue
        on_turn = (s >= start + leg) & (s < start + leg + turn)
        a = (s[on_turn] - start - leg) / r  # 0..pi
        side = 1.0 if east else -1.0
        out[on_turn, 0] = (x1 if east else x0) + side * r * np.sin(a)
        out[on_turn, 1] = SURVEY_LINES_Y[i] + r - r * np.cos(a)
        heading[on_turn] = np.degrees(np.arctan2(side * np.cos(a), np.sin(a))) % 360.0
    u = s - lines
    first = (u >= 0) & (u < quarter)  # west, turning left to the south
    a = u[first] / r
    out[first, 0] = x0 - r * np.sin(a)
    out[first, 1] = y_last - r + r * np.cos(a)
    heading[first] = np.degrees(np.arctan2(-np.cos(a), -np.sin(a))) % 360.0
    south = (u >= quarter) & (u < quarter + back)
    out[south, 0] = x0 - r
    out[south, 1] = y_last - r - (u[south] - quarter)
    heading[south] = 180.0
    last = u >= quarter + back  # south, turning left to the east: the first line again
    b = (u[last] - quarter - back) / r
    out[last, 0] = x0 - r * np.cos(b)
    out[last, 1] = y_first + r - r * np.sin(b)
    heading[last] = np.degrees(np.arctan2(np.sin(b), -np.cos(b))) % 360.0
    return out, heading


def _survey_position(t: np.ndarray) -> np.ndarray:
    return _survey_path(SURVEY_SPEED * np.asarray(t, np.float64))[0]


def _survey_hpr(t: np.ndarray) -> np.ndarray:
    """Looking straight down, the image's top along the track (a mapping drone's gimbal)."""
    t = np.asarray(t, np.float64)
    # the heading of travel, smoothed over a second so that the image turns without a jerk
    offsets = np.linspace(-0.5, 0.5, 11)
    h = np.stack([_survey_path(SURVEY_SPEED * (t + o))[1] for o in offsets])
    rad = np.radians(h)
    heading = np.degrees(np.arctan2(np.sin(rad).mean(0), np.cos(rad).mean(0))) % 360.0
    return np.column_stack([heading, np.full(len(t), -90.0), np.zeros(len(t))])


def _orbit_angle(t: np.ndarray) -> np.ndarray:
    """Counter-clockwise from east, starting south of the hall (rad)."""
    return -np.pi / 2 + ORBIT_SPEED / ORBIT_RADIUS_M * np.asarray(t, np.float64)


def _orbit_position(t: np.ndarray) -> np.ndarray:
    a = _orbit_angle(t)
    return np.column_stack(
        [
            ORBIT_TARGET[0] + ORBIT_RADIUS_M * np.cos(a),
            ORBIT_TARGET[1] + ORBIT_RADIUS_M * np.sin(a),
            np.full(len(a), ORBIT_HEIGHT_M),
        ]
    )


def _orbit_hpr(t: np.ndarray) -> np.ndarray:
    d = np.asarray(ORBIT_TARGET) - _orbit_position(t)
    heading = np.degrees(np.arctan2(d[:, 0], d[:, 1])) % 360.0
    pitch = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    return np.column_stack([heading, pitch, np.zeros(len(d))])


def survey() -> Flight:
    return Flight("survey", _survey_position, _survey_hpr, True)


def orbit() -> Flight:
    return Flight("orbit", _orbit_position, _orbit_hpr, True)
