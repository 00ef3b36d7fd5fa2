"""Scripted viewer sessions: a text file of timed UI actions, one per line, for tests and the
README's screenshots. Times are seconds on the viewer's clock since it opened: wall time, or a
fixed-step clock that the script sets (`clock STEP`: every drawn frame advances it by STEP s), on
which a run does the same thing on a fast machine and on a loaded one.

    # comment
    0.0  clock 0.0333       # a fixed-step clock (or: clock wall)
    0.0  wait solved        # hold the clock until every pose source but `registered` is solved
    0.0  wait registered    # ... and until the registered one is too (about the clip's length)
    1.0  export footprints out/fp.geojson   # footprints | fmv-csv | klv | video, in the background
    1.0  wait exported      # hold the clock until the export has finished
    1.5  record start out/rec.mp4           # record what the window shows (record stop)
    0.0  play
    2.0  pause
    2.1  seek 12.5          # media seconds from the first frame
    2.5  step 1             # frames, either way
    3.0  speed 2
    3.2  source gd-imu      # any attitude source the session offers
    3.4  ahrs off           # the AHRS / IMU toggle
    3.5  alpha 0.5
    3.55 overlay on         # the projection-error colours (sessions with ground truth)
    3.58 offset 0.08        # the session's time offset, seconds
    3.59 pitch -45          # a drone clip without gimbal attitude: the assumed camera pitch
    3.6  view phone         # free | orbit | phone | reset
    3.65 look -150,-170,70 0,0,10   # the window camera at an eye looking at a target (ENU m)
    3.66 detail 32          # 3D Tiles: refine above this screen-space error (px; default 16)
    3.67 wait tiles         # hold the clock until the tiles this view and the projector need are loaded
    3.7  open path/to/other.toml
    3.8  panels off         # hide the panels (a scene-only screenshot)
    3.9  lines off          # hide the frustum and trajectory lines
    4.0  screenshot out.png
    4.1  state out.json     # the viewer's state (camera, frame, source, errors) as JSON
    4.5  quit
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from app.core.errors import DataFormatError
from app.ui.commands import COMMANDS

ACTIONS = {name: int(c.takes_arg) for name, c in COMMANDS.items()}


@dataclass(frozen=True)
class Action:
    at_s: float
    name: str
    arg: str | None
    line: int


def parse_script(path: str | Path) -> list[Action]:
    """Actions sorted by time. Errors name the file and line."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "script file does not exist")
    out = []
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataFormatError(
            path, f"not UTF-8 text (byte {exc.start}): expected lines of 'TIME ACTION [ARGUMENT]'"
        ) from exc
    for number, raw in enumerate(text.splitlines(), start=1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.split(None, 2)
        try:
            at = float(parts[0])
        except ValueError:
            raise DataFormatError(
                path, f"expected a time in seconds, got {parts[0]!r}", line=number
            ) from None
        if len(parts) < 2 or parts[1] not in ACTIONS:
            raise DataFormatError(
                path,
                f"unknown action {parts[1] if len(parts) > 1 else ''!r} (expected one of {sorted(ACTIONS)})",
                line=number,
            )
        name = parts[1]
        arg = parts[2].strip() if len(parts) > 2 else None
        if ACTIONS[name] and arg is None:
            raise DataFormatError(path, f"{name} needs an argument", line=number)
        out.append(Action(at, name, arg, number))
    return sorted(out, key=lambda a: a.at_s)
