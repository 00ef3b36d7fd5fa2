"""The world of an open clip in the viewer, built in the background (app.world.background)
while the frame loop draws the flat ground: the coarse level replaces it as soon as it is had,
then the full level, as a 3D Tiles layer refines. Each level's scene (the session's other
layers with the world's DEM and buildings, in its ENU frame) is made and laid out for the GPU
on the builder's thread (app.render.staging.prepare); the frame loop only uploads it, in pieces
within its per-frame budget, and swaps it in whole (app.render.gpu_scene.GpuScene.stage).

A clip whose heights are above a take-off not known (a DJI subtitle's) opened on the flat ground
at the assumed take-off height; its terrain is drawn with its ground under the first position
there (moved, and said), so that the drape stays right and the track keeps its heights. Once a
level is drawn, the session's scene is the world's (exports, locate, the world named among its
layers); from the full level on, the registration's too: the video is registered against the
world once it is whole, not against the flat ground meanwhile. The Stats panel and a script's
`state` say where the build stands; `wait world` holds a script until it is done. Closing the
session cancels it.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np

from app.core.messages import INFO
from app.render.staging import PreparedPrimitive, prepare
from app.scene.ground import ellipsoidal_ground
from app.scene.mesh import MeshData
from app.session.assemble import load_scene_layers
from app.session.model import Session
from app.world.background import WorldBuilder, WorldLevel
from app.world.build import WorldRequest

WORLD_WAIT_S = 600.0  # `wait world` gives up after this long (real seconds)
FRAMES_KEPT = 5000  # frame times kept of each phase (streaming, after), for a script's `state`


def world_scene_of(
    session: Session, requests: list[WorldRequest], resolved: dict[int, tuple]
) -> MeshData:
    """The session's scene with the worlds built so far (resolved: request index -> its layers):
    its other layers (not its worlds, nor its 3D Tiles, which stream on their own) and theirs,
    in the session's frame; a world over heights above take-off moved so that its ground under
    the first fix is at the assumed take-off height (said in the session's messages)."""
    others = [layer for layer in session.layers if layer.kind not in ("world", "tileset")]
    layers = tuple(others) + tuple(x for k in sorted(resolved) for x in resolved[k])
    first = requests[0]
    mesh = load_scene_layers(
        layers, session.frame, session.gnss, session.messages, first.ground_h, first.reach_m
    )
    if not any(r.above_takeoff for r in requests):
        return mesh
    lat, lon = float(session.gnss.lat[0]), float(session.gnss.lon[0])
    takeoff = ellipsoidal_ground(mesh, session.frame, lat, lon)
    if takeoff is None:
        return mesh
    dz = first.ground_h - takeoff
    text = (
        f"heights above take-off: the world's terrain is drawn with its ground under the first position at the take-off height "
        f"the clip opened with ({first.ground_h:.2f} m; moved {dz:+.1f} m), as the flat ground was; "
        "`geofuse render`/`export` raise the track onto the terrain instead"
    )
    session.messages.add_once("world-takeoff", text, INFO)
    shift = np.array([0.0, 0.0, dz], np.float32)
    prims = [replace(p, positions=p.positions + shift) for p in mesh.primitives]
    return MeshData(prims, mesh.tilesets, mesh.features)


class ViewerWorld:
    """One session's worlds on their way to the screen (see the module docstring). The builder's
    thread calls `_made`; the frame loop calls `update` (module function) each frame."""

    def __init__(self, requests: list[WorldRequest], session: Session) -> None:
        self.requests = requests
        self.session = session
        self.names = ", ".join(r.world.name for r in requests)
        self._lock = threading.Lock()
        self._resolved: dict[int, tuple] = {}
        self._ready: tuple[WorldLevel, MeshData, list[PreparedPrimitive]] | None = None
        self.staging: WorldLevel | None = None  # handed to the GPU scene, not swapped in yet
        self.shown: WorldLevel | None = None  # drawn now
        self.staged_mesh: MeshData | None = None  # the scene of the level staging
        self.started_at = time.monotonic()  # monotonic s: when the build began (the first frame)
        self.shown_at: dict[str, float] = {}  # monotonic s each level was first drawn
        # seconds each frame took, while the world streams in and once it is drawn in full
        self.frame_s: dict[str, list[float]] = {"streaming": [], "after": []}
        self.builder = WorldBuilder(requests, session.messages, self._made)

    def start(self) -> ViewerWorld:
        self.builder.start()
        return self

    def cancel(self) -> None:
        self.builder.cancel()

    def _made(self, level: WorldLevel) -> None:
        """A level built (the builder's thread): its scene made and laid out, for the frame loop."""
        if not level.layers:  # none had at this level: what is drawn stays
            return
        self._resolved[level.index] = level.layers
        mesh = world_scene_of(self.session, self.requests, dict(self._resolved))
        prepared = prepare(mesh)
        with self._lock:
            self._ready = (level, mesh, prepared)  # a newer level replaces one not taken yet

    def take(self) -> tuple[WorldLevel, MeshData, list[PreparedPrimitive]] | None:
        with self._lock:
            ready, self._ready = self._ready, None
        return ready

    @property
    def done(self) -> bool:
        """Built (or given up) and drawn: nothing more will change."""
        with self._lock:
            waiting = self._ready is not None
        return self.builder.finished and not waiting and self.staging is None

    def status(self) -> str:
        """One line: what is being fetched, uploaded or drawn."""
        p = self.builder.progress
        shown = "" if self.shown is None else "coarse level drawn; " if self.shown.coarse else ""
        if p.level in ("coarse", "full") and not self.builder.finished:
            if not p.tiles:
                return f"world {self.names}: {shown}opening its sources"
            what = "the coarse level: " if p.level == "coarse" else ""
            return f"world {self.names}: {shown}fetching {what}{p.tiles} tiles ({p.done} done)"
        if self.staging is not None:
            return f"world {self.names}: {shown}uploading the {'coarse' if self.staging.coarse else 'full'} level"
        if self.shown is None:
            return f"world {self.names}: none of its tiles could be had: the flat ground stays (the Session panel says why)"
        return f"world {self.names}: {'coarse level drawn (the full one could not be had)' if self.shown.coarse else 'drawn in full'}"


def _adopt(v, level: WorldLevel, mesh: MeshData) -> None:
    """A level drawn: the session's scene is the world's from now on (exports, locate, its
    layers named with their attribution); at the full level the solvers' too (registration)."""
    L = v.loaded
    w: ViewerWorld = L.world
    kept = tuple(layer for layer in L.session.layers if layer.kind != "world")
    L.session = replace(L.session, mesh=mesh, layers=(*kept, *(r.layer for r in w.requests)))
    if not level.coarse:
        L.library.use_session(L.session)


def start(loaded, requests: list[WorldRequest]) -> None:
    """Build the open session's worlds in the background (loaded: app.ui.sessions.Loaded)."""
    if requests:
        loaded.world = ViewerWorld(requests, loaded.session).start()


def update(v) -> None:
    """Each frame: hand a level built to the GPU scene, and note when it is swapped in."""
    L = v.loaded
    w = L.world if L is not None else None
    if w is None:
        return
    if v.stats.frame_times:  # the frame before this one
        kept = w.frame_s["after" if w.done else "streaming"]
        kept.append(v.stats.frame_times[-1])
        del kept[:-FRAMES_KEPT]
    scene = L.renderer.scene
    ready = w.take()
    if ready is not None:
        level, mesh, prepared = ready
        scene.stage(mesh, prepared)
        w.staging, w.staged_mesh = level, mesh
    if w.staging is not None and scene.staged is None and scene.stage_error:
        L.session.messages.add_once(scene.stage_error, f"world {w.names}: {scene.stage_error}")
        w.staging = None
    if w.staging is not None and scene.staged is None:  # swapped in by a frame's draw
        w.shown, w.staging = w.staging, None
        w.shown_at.setdefault("coarse" if w.shown.coarse else "full", time.monotonic())
        _adopt(v, w.shown, w.staged_mesh)


def wait(v) -> None:
    """Hold the script until the world is built and drawn (a script's `wait world`; nothing to
    wait for without one)."""
    L = v.loaded
    if L is not None and L.world is not None:
        names = L.world.names
        v.hold_script(lambda: drawn(L), f"the world {names} to be built", WORLD_WAIT_S)


def drawn(loaded) -> bool:
    """Whether nothing more of the open session's world is to come (True without one)."""
    return loaded is None or loaded.world is None or loaded.world.done


def close(loaded) -> None:
    if loaded.world is not None:
        loaded.world.cancel()


def state(loaded) -> dict | None:
    """For a script's `state`: the level drawn, where the build stands, the status line."""
    w = loaded.world
    if w is None:
        return None
    p = w.builder.progress
    return {
        "shown": None if w.shown is None else "coarse" if w.shown.coarse else "full",
        "building": p.level,
        "tiles": p.tiles,
        "done": p.done,
        "levels_handed": p.handed,
        "swaps": loaded.renderer.scene.swaps,
        "status": w.status(),
        "done_all": w.done,
        "started_at": w.started_at,
        "shown_at": w.shown_at,
        "frame_ms": {k: _summary(ts) for k, ts in w.frame_s.items()},
    }


def _summary(seconds: list[float]) -> dict:
    """Frame times (s) as {"median", "p95" (ms), "frames"}."""
    ms = np.asarray(seconds, np.float64) * 1000.0
    if not len(ms):
        return {"median": None, "p95": None, "frames": 0}
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "frames": len(ms)}
