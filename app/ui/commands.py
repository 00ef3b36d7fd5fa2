"""The viewer's actions by name: one table that the script, the keyboard and the panels share.
Each command takes the viewer, its text argument and the clock's `now` (seconds)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from app.export.painting import DEFAULT_EVERY_S
from app.share.web import DEFAULT_BIND, parse_bind
from app.ui import archive, clips, control_points, live, measure, memory, share, world

OPEN_WAIT_S = 600.0  # a script's `open` waits at most this long for the reading (real seconds)
LIVE_WAIT_S = 120.0  # `wait live N` gives up after this long (real seconds)
SHARE_WAIT_S = 120.0  # `share wait` gives up after this long (real seconds)


@dataclass(frozen=True)
class Command:
    run: Callable[..., None]  # (viewer, arg, now)
    needs_session: bool
    takes_arg: bool
    help: str


def _on(arg: str | None) -> bool:
    if arg not in ("on", "off"):
        raise ValueError(f"expected on or off, got {arg!r}")
    return arg == "on"


def _number(arg: str | None) -> float:
    try:
        return float(arg)
    except (TypeError, ValueError):
        raise ValueError(f"expected a number, got {arg!r}") from None


def _clock(v, arg, now) -> None:
    if arg == "wall":
        v.use_wall_clock()
    else:
        v.use_fixed_clock(_number(arg))


def _control(v, arg, now) -> None:
    """video [X,Y] | model [X,Y] | solve | clear: control points (app.ui.control_points); X,Y in
    [0, 1] of the 3D view, default the mouse cursor."""
    words = arg.split()
    what = words[0] if words else ""
    picks = v.ui.control
    if what in ("video", "model"):
        xy = tuple(float(t) for t in words[1].split(",")) if len(words) > 1 else v.cursor_in_view()
        if xy is None or len(xy) != 2:
            raise ValueError("expected X,Y in [0, 1] of the 3D view")
        (control_points.pick_video if what == "video" else control_points.pick_model)(v, picks, xy)
    elif what == "solve":
        control_points.solve(v, picks)
    elif what == "clear":
        v.ui.control = control_points.ControlPicks()
    else:
        raise ValueError(f"expected video, model, solve or clear, got {arg!r}")


def _measure(v, arg, now) -> None:
    """point | line | polygon | pick [X,Y] | mark [LABEL] | undo | clear | goto N | delete N |
    export PATH: point, measure and mark (app.ui.measure); X,Y in [0, 1] of the 3D view, default
    the mouse cursor."""
    what, _, rest = (arg or "").strip().partition(" ")
    rest = rest.strip()
    if what in ("point", "line", "polygon"):
        measure.set_kind(v, what)
    elif what == "pick":
        xy = tuple(float(t) for t in rest.split(",")) if rest else v.cursor_in_view()
        if xy is None or len(xy) != 2:
            raise ValueError("expected X,Y in [0, 1] of the 3D view")
        measure.pick(v, xy)
    elif what == "mark":
        measure.keep(v, rest or v.ui.measure.label)
    elif what == "undo":
        v.ui.measure.picks = v.ui.measure.picks[:-1]
        measure.refresh(v)
    elif what == "clear":
        v.ui.measure.picks = []
        measure.refresh(v)
    elif what in ("goto", "delete"):
        n = int(_number(rest))
        measure.goto(v, n, now) if what == "goto" else measure.remove(v, n)
    elif what == "export":
        if not rest:
            raise ValueError("expected a path ending in .geojson or .kml")
        v.ui.info.append(f"marks exported to {measure.export(v, Path(rest))}")
    else:
        raise ValueError(
            f"expected point, line, polygon, pick, mark, undo, clear, goto, delete or export, got {arg!r}"
        )


def _archive(v, arg, now) -> None:
    """load PATH | open [X,Y]: an archive's footprints on the scene; open the clip that saw the
    point under X,Y (in [0, 1] of the 3D view, default the cursor) at that moment."""
    what, _, rest = (arg or "").strip().partition(" ")
    rest = rest.strip()
    if what == "load" and rest:
        archive.load(v, Path(rest))
    elif what == "open":
        xy = tuple(float(t) for t in rest.split(",")) if rest else v.cursor_in_view()
        if xy is None or len(xy) != 2:
            raise ValueError("expected X,Y in [0, 1] of the 3D view")
        archive.open_at(v, xy, now)
    else:
        raise ValueError(f"expected 'load PATH' or 'open [X,Y]', got {arg!r}")


def _clip(v, arg, now) -> None:
    """add PATH | N on|off | N offset S | N priority P: further clips on the timeline
    (app.ui.clips); N counts the further clips from 1."""
    words = (arg or "").split(maxsplit=2)
    if len(words) == 2 and words[0] == "add":
        clips.add(v, Path(words[1]))
        return
    if len(words) < 2 or not words[0].isdigit():
        raise ValueError(
            f"expected 'add PATH', 'N on|off', 'N offset S' or 'N priority P', got {arg!r}"
        )
    n = int(words[0])
    if words[1] in ("on", "off"):
        clips.set_visible(v, n, words[1] == "on")
    elif words[1] == "offset" and len(words) == 3:
        clips.set_offset(v, n, _number(words[2]))
    elif words[1] == "priority" and len(words) == 3:
        v.loaded.others[n - 1].priority = _number(words[2])
    elif words[1] == "alpha" and len(words) == 3:
        clips.set_alpha(v, n, _number(words[2]))
    elif words[1] == "source" and len(words) == 3:
        clips.set_source(v, n, words[2])
    else:
        raise ValueError(
            f"expected 'N on|off', 'N offset S', 'N priority P', 'N alpha A' or 'N source NAME', got {arg!r}"
        )


def _wait(v, arg, now) -> None:
    if arg == "solved":
        v.wait_until_solved()
    elif arg == "registered":
        v.wait_until_solved(registered=True)
    elif arg == "exported":
        v.wait_until_exported()
    elif arg == "synced":
        v.wait_until_synced()
    elif arg == "tiles":
        v.wait_until_tiles_loaded()
    elif arg == "painted":
        memory.wait_painted(v)
    elif arg == "world":
        world.wait(v)
    elif arg.split()[:1] in (["live"], ["arrived"]) and len(arg.split()) <= 2:
        words = arg.split()
        n = int(_number(words[1])) if len(words) == 2 else 1
        if v.live is None:
            raise ValueError("no stream is open")
        feed = v.live.feed
        if words[0] == "live":
            v.hold_script(
                lambda: v.live is not None and v.live.run.frames_drawn >= n,
                f"{n} frames of {feed.url} shown",
                LIVE_WAIT_S,
            )
        else:
            until = feed.receiver.counts.frames + n
            v.hold_script(
                lambda: feed.receiver.counts.frames >= until,
                f"{n} more frames of {feed.url} to arrive",
                LIVE_WAIT_S,
            )
    else:
        raise ValueError(
            f"expected 'solved', 'registered', 'exported', 'synced', 'tiles', 'painted', 'world', 'live [N]' or 'arrived [N]', got {arg!r}"
        )


def _open(v, arg, now) -> None:
    """A session, clip, layer or stream, read in the background; the script waits for it."""
    v.open_input(arg)
    if v.ui.opening is not None:
        v.hold_script(lambda: v.ui.opening is None, f"{arg} to open", OPEN_WAIT_S)


def _memory(v, arg, now) -> None:
    """paint [RULE [EVERY_S [MAX_TEXELS]]] | model | memory | seen | changed: the scene memory
    (app.ui.memory)."""
    words = (arg or "").split()
    if words[:1] == ["paint"] and len(words) <= 4:
        every_s = _number(words[2]) if len(words) >= 3 else DEFAULT_EVERY_S
        texels = int(_number(words[3])) if len(words) == 4 else memory.DEFAULT_MAX_TEXELS
        memory.start(v, words[1] if len(words) >= 2 else "newest", every_s, texels)
    elif len(words) == 1:
        memory.set_view(v, words[0])
    else:
        raise ValueError(f"expected paint [RULE], model, memory, seen or changed, got {arg!r}")


def _export(v, arg, now) -> None:
    what, _, path = (arg or "").partition(" ")
    if not path.strip():
        raise ValueError(
            "expected WHAT PATH (footprints, fmv-csv, klv or video, and the output file)"
        )
    v.start_export(what, Path(path.strip()))


def _live(v, arg, now) -> None:
    if v.live is None:
        raise ValueError("no stream is open")
    words = (arg or "").split()
    what = words[0] if words else ""
    if what == "edge":
        live.review(v, None)
    elif what == "close":
        live.close(v)
    elif what in ("back", "at") and len(words) == 2:
        t = _number(words[1])
        span = v.live.recorded_span()
        edge = span[1] if span is not None else 0.0
        live.review(v, edge - t if what == "back" else t)
    else:
        raise ValueError(f"expected 'back S', 'at S', 'edge' or 'close', got {arg!r}")


def _share(v, arg, now) -> None:
    """on [HOST:PORT] | off | wait: the browser map (app.ui.share.start_web), bound to the
    loopback unless HOST:PORT says otherwise; stopped; wait: hold the script until a browser has
    been sent the frame shown (on a stream, any frame)."""
    words = (arg or "").split()
    what = words[0] if words else ""
    if what == "on" and len(words) <= 2:
        bind = parse_bind(words[1]) if len(words) == 2 else DEFAULT_BIND
        try:
            share.start_web(v, bind)
        except OSError as exc:
            raise ValueError(
                f"the browser map cannot listen on {bind[0]}:{bind[1]}: {exc.strerror or exc}"
            ) from exc
    elif what == "off" and len(words) == 1:
        share.stop_web(v)
    elif what == "wait" and len(words) == 1:
        server = v.share.web
        if server is None:
            raise ValueError("the browser map is off (share on)")
        v.hold_script(
            lambda: (
                server.delivered_index is not None
                and (v.live is not None or server.delivered_index == v.current_index)
            ),
            "a browser to be sent the frame shown",
            SHARE_WAIT_S,
        )
    else:
        raise ValueError(f"expected 'on [HOST:PORT]', 'off' or 'wait', got {arg!r}")


def _record(v, arg, now) -> None:
    action, _, path = (arg or "").partition(" ")
    if action == "start":
        v.start_recording(Path(path.strip() or v.ui.record_path))
    elif action == "stop":
        v.stop_recording()
    else:
        raise ValueError(f"expected 'start [PATH]' or 'stop', got {arg!r}")


def _view(v, arg, now) -> None:
    if arg == "reset":
        v.nav.reset()
    elif arg == "orbit":
        v.orbit_pick()  # as the O key: around the point under the cursor
    elif arg in ("free", "phone", "follow"):
        v.nav.mode = arg
    else:
        raise ValueError(f"expected free, orbit, phone, follow or reset, got {arg!r}")


def _look(v, arg, now) -> None:
    values = [float(x) for x in (arg or "").replace(",", " ").split()]
    if len(values) != 6 or not all(np.isfinite(values)):
        raise ValueError(f"expected E,N,U E,N,U (eye and target, ENU metres), got {arg!r}")
    v.nav.look_at(np.array(values[:3]), np.array(values[3:]))


def _set_ui(**changes) -> Callable:
    def run(v, arg, now) -> None:
        on = _on(arg)
        for key, fields in changes.items():
            setattr(
                v.ui, key, replace(getattr(v.ui, key), **{f: on for f in fields}) if fields else on
            )

    return run


COMMANDS: dict[str, Command] = {
    "quit": Command(lambda v, a, n: setattr(v.ui, "quit", True), False, False, "close the viewer"),
    "open": Command(
        _open,
        False,
        True,
        "open a manifest or clip, or receive a stream (udp://, rtp://, rtsp://, srt://)",
    ),
    "live": Command(
        _live,
        False,
        True,
        "back S | at S | edge | close: an open stream: show the moment S seconds behind the live edge, or at media time S, from the recording; back to the live edge; stop receiving",
    ),
    "screenshot": Command(
        lambda v, a, n: setattr(v.ui, "screenshot_request", Path(a)),
        False,
        True,
        "save the window as PNG",
    ),
    "state": Command(
        lambda v, a, n: setattr(v.ui, "state_request", Path(a)),
        False,
        True,
        "write the viewer's state as JSON",
    ),
    "panels": Command(_set_ui(show_panels=()), False, True, "show or hide the panels"),
    "project": Command(
        _set_ui(settings=("enabled",)), False, True, "on | off: drape the video (the live view)"
    ),
    "lines": Command(
        _set_ui(overlays=("frustum", "trajectory")), False, True, "frustum and trajectory lines"
    ),
    "clock": Command(_clock, False, True, "STEP: a fixed-step clock (seconds per frame), or wall"),
    "wait": Command(
        _wait,
        False,
        True,
        "solved | registered | exported | synced | tiles | painted | world | live [N] | arrived [N]: hold the clock until every source but the registered one is solved, the registered one too, the export or sync has finished, or the 3D Tiles this view needs are loaded; painted: hold the script until the scene memory is painted and shown; world: until the clip's world is built and drawn in full; live N: hold the script until N frames of the stream have been shown; arrived N: until N more have arrived",
    ),
    "memory": Command(
        _memory,
        True,
        True,
        "paint [newest|best|first [EVERY_S [MAX_TEXELS]]] | model | memory | seen | changed: paint what the clips saw onto the scene in the background (in one atlas of at most MAX_TEXELS, 2,000,000 by default, or in pages where the video's sampling asks for more), and show the model, the memory, when each part was seen or what changed, as at the timeline's moment",
    ),
    "export": Command(
        _export,
        True,
        True,
        "WHAT PATH: export the session (footprints, fmv-csv, klv, video) in the background",
    ),
    "record": Command(_record, True, True, "start [PATH] | stop: record what the window shows"),
    "share": Command(
        _share,
        False,
        True,
        "on [HOST:PORT] | off | wait: the browser map of what is shown (its URL, with its access token, among the notes), bound to the loopback unless HOST:PORT says otherwise; stop it; wait: hold the script until a browser has been sent the frame shown",
    ),
    "lens": Command(
        lambda v, a, n: v.use_lens(None if a == "auto" else Path(a)),
        True,
        True,
        "PROFILE.json | auto: reopen the clip through this lens profile",
    ),
    "sync": Command(
        lambda v, a, n: v.start_sync(),
        True,
        False,
        "find the video <-> gyroscope offset and apply it",
    ),
    "play": Command(lambda v, a, n: v.loaded.clock.set_paused(False, n), True, False, "play"),
    "pause": Command(lambda v, a, n: v.loaded.clock.set_paused(True, n), True, False, "pause"),
    "toggle": Command(
        lambda v, a, n: v.loaded.clock.set_paused(not v.loaded.clock.paused, n),
        True,
        False,
        "play / pause",
    ),
    "seek": Command(
        lambda v, a, n: v.loaded.player.seek(_number(a), n), True, True, "media seconds"
    ),
    "step": Command(
        lambda v, a, n: v.loaded.player.step(int(_number(a)), n), True, True, "frames, either way"
    ),
    "speed": Command(
        lambda v, a, n: v.loaded.clock.set_speed(_number(a), n), True, True, "playback speed"
    ),
    "faster": Command(lambda v, a, n: v.change_speed(+1, n), True, False, "next playback speed"),
    "slower": Command(
        lambda v, a, n: v.change_speed(-1, n), True, False, "previous playback speed"
    ),
    "source": Command(lambda v, a, n: v.set_source(a), True, True, "attitude source"),
    "ahrs": Command(
        lambda v, a, n: v.toggle_ahrs(None if a is None else _on(a)), True, False, "AHRS / IMU"
    ),
    "alpha": Command(
        lambda v, a, n: setattr(v.ui, "settings", replace(v.ui.settings, alpha=_number(a))),
        False,
        True,
        "video opacity 0..1",
    ),
    "offset": Command(
        lambda v, a, n: v.set_time_offset(_number(a)), True, True, "time offset, seconds"
    ),
    "pitch": Command(
        lambda v, a, n: v.set_course_pitch(_number(a)),
        True,
        True,
        "assumed camera pitch of a drone clip",
    ),
    "detail": Command(
        lambda v, a, n: v.set_tile_detail(_number(a)),
        False,
        True,
        "3D Tiles: the screen-space error in pixels above which tiles refine (default 16)",
    ),
    "overlay": Command(
        lambda v, a, n: setattr(v.ui, "overlays", replace(v.ui.overlays, error_map=_on(a))),
        False,
        True,
        "projection-error colours",
    ),
    "view": Command(
        _view, False, True, "free | orbit | phone | follow (behind the projector) | reset"
    ),
    "look": Command(
        _look,
        False,
        True,
        "E,N,U E,N,U: the window camera at an eye looking at a target (ENU metres)",
    ),
    "control": Command(
        _control,
        True,
        True,
        "video [X,Y] | model [X,Y] | solve | clear: control points by hand (a feature in the draped video, then on the model; X,Y in [0, 1] of the 3D view, default the cursor)",
    ),
    "clip": Command(
        _clip,
        True,
        True,
        "add PATH | N on|off | N offset S | N priority P | N alpha A | N source NAME: further clips played with this one on one timeline (hidden: decoder released)",
    ),
    "archive": Command(
        _archive,
        True,
        True,
        "load PATH | open [X,Y]: an archive's footprints on the scene (geofuse index); open the clip that saw the point under X,Y most head-on, at that moment (G: under the cursor)",
    ),
    "measure": Command(
        _measure,
        True,
        True,
        "point | line | polygon | pick [X,Y] | mark [LABEL] | undo | clear | goto N | delete N | export PATH: where the video's points lie, distances, heights and areas, and marks kept beside the input",
    ),
    "help": Command(
        lambda v, a, n: setattr(v.ui, "show_help", not v.ui.show_help),
        False,
        False,
        "help and shortcuts",
    ),
}


def run_command(viewer, name: str, arg: str | None, now: float) -> None:
    """Run one command; ValueError for an unknown name, a missing argument or no open session."""
    command = COMMANDS.get(name)
    if command is None:
        raise ValueError(f"unknown action {name!r}")
    if command.takes_arg and arg is None:
        raise ValueError(f"{name} needs an argument")
    if command.needs_session and viewer.loaded is None:
        raise ValueError("no session is open")
    command.run(viewer, arg, now)
