"""The viewer's sessions: opening a manifest or clip (or adding a scene layer to the open clip),
closing it, reopening it through another lens, the tiles and sources it waits for, and its
messages shown as they come. A mixin of app.ui.viewer.Viewer (uses its ui, options, window,
stats and nav); the commands (app.ui.commands) call these methods on the viewer."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from app.core.errors import GeofuseError
from app.core.messages import ERROR, WARNING
from app.core.worker import OneShot
from app.footage.clips import open_any
from app.playback.clock import PlaybackClock
from app.playback.library import SolverLibrary
from app.playback.player import Player
from app.render.renderer import FusionRenderer
from app.scene.ground import ground_heights
from app.scene.layers import Layer, layer_kind
from app.scene.mesh import MeshData
from app.session.model import REGISTERED, Session
from app.session.timeline import Timeline
from app.simulate.sample import SAMPLE_DIR
from app.ui import archive, clips, live, measure, memory, world
from app.ui.gnss import FrameGnss
from app.ui.memory import MemoryPainter
from app.ui.navigation import Navigator
from app.world.build import WorldRequest, deferred_worlds

log = logging.getLogger("geofuse.viewer")
SOLVE_WAIT_S = 600.0  # `wait solved` gives up after this long (real seconds)


class OpenJob(OneShot):
    """Reading a session or clip and its scene (CityJSON, DEMs, meshes: seconds for a district)
    on a thread of its own, so that the frame loop keeps drawing; the viewer installs it (GL
    objects, players, solvers) on the frame loop's thread once `done`. on_fail runs there when
    it could not be read. A world it names is not built here: it opens on the flat ground and
    the world is built in the background once installed (app.ui.world)."""

    def __init__(
        self,
        path: Path,
        srt,
        lens,
        layers,
        on_fail: Callable[[], None] | None = None,
        start=None,
        accuracy_m: float | None = None,
    ):
        self.path, self.on_fail = path, on_fail
        self._args = (srt, lens, tuple(layers), start, accuracy_m)
        self.result: tuple[Session, MeshData] | None = None
        self.worlds: list[WorldRequest] = []  # to build in the background once installed
        super().__init__("geofuse-open")

    def _work(self) -> None:
        srt, lens, layers, start, accuracy_m = self._args
        with deferred_worlds() as worlds:
            session = open_any(
                self.path, srt, lens=lens, layers=layers, start=start, accuracy_m=accuracy_m
            )
        if worlds:  # not among its layers until drawn: nothing to register against meanwhile
            kept = tuple(layer for layer in session.layers if layer.kind != "world")
            session = replace(session, layers=kept)
        self.worlds = worlds
        self.result = (session, session.scene())

    def _failed(self) -> str:
        return str(self.path)


@dataclass
class Stats:
    frames: int = 0  # frames drawn since the session opened
    frame_times: list[float] = field(default_factory=list)  # the last FRAME_HISTORY, seconds
    depth_redraws: int = 0


@dataclass
class Loaded:
    """One open session and everything made for it."""

    session: Session
    renderer: FusionRenderer
    player: Player
    library: SolverLibrary
    source: str
    trajectory_version: tuple[int, str] | None = None  # (library version, source) drawn
    others: list = field(default_factory=list)  # further clips (app.ui.clips.OtherClip)
    timeline: Timeline | None = None  # this clip and the others on one clock
    extras_shown: tuple = ()  # what the further projectors were last given
    source_chosen: bool = False  # the user picked a source: never switched for them
    registered_said: bool = False  # the switch to `registered` (or why not) was said
    memory: MemoryPainter | None = None  # the scene memory being painted or painted
    gnss: FrameGnss | None = None  # the registered track's per-frame GNSS status (app.ui.gnss)
    world: world.ViewerWorld | None = None  # its world being built in the background

    @property
    def clock(self) -> PlaybackClock:
        return self.player.clock


def home_view(session: Session, mesh: MeshData) -> Navigator:
    """Where the window camera starts: for a model of a site, south of it looking across it; on an
    assumed ground, a tileset or terrain larger than a site, behind and above the camera's track
    so that its frustum and footprint show (without a fix, over the area a cold start searches)."""
    if (
        session.scene_path is None
        or mesh.tilesets
        or float(np.ptp(mesh.bounds()[:, :2], axis=0).max()) > 2000.0
    ):
        g = session.gnss
        if len(g.t):
            enu = session.frame.geodetic_to_enu(g.lat, g.lon, g.h)
        elif session.start is not None:  # no fix at all: the area searched, on the scene
            lat, lon = session.start.outline()
            enu = session.frame.geodetic_to_enu(lat, lon, np.full(len(lat), session.frame.h_m))
            ground = ground_heights(mesh, enu[:, :2])  # (NaN off the scene: its lowest point)
            enu[:, 2] = np.where(np.isfinite(ground), ground, mesh.bounds()[0, 2])
        else:
            enu = np.zeros((1, 3))
        centre = (enu.min(axis=0) + enu.max(axis=0)) / 2
        size = float(max(np.ptp(enu[:, 0]), np.ptp(enu[:, 1]), 10.0))
        eye = centre + np.array([-0.4 * size - 12.0, -0.8 * size - 25.0, 0.5 * size + 18.0])
        d = centre - eye
        return Navigator(
            position=eye,
            yaw=float(np.degrees(np.arctan2(d[0], d[1]))),
            pitch=float(np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1])))),
        )
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    return Navigator(
        position=np.array([centre[0] + 35.0, lo[1] - 20.0, 40.0]), yaw=-15.0, pitch=-15.0
    )


def _is_layer(path: Path) -> bool:
    """A tileset, a DEM, a city or a model: added to the open clip's scene rather than opened."""

    try:
        return layer_kind(path) in ("tileset", "dem", "city") or (
            layer_kind(path) == "mesh" and path.suffix.lower() != ".toml"
        )
    except GeofuseError:
        return False


class ViewerSessions:
    """Sessions for a Viewer."""

    def use_lens(self, profile: Path | None) -> None:
        """Reopen the clip through another lens profile (None: the one chosen from the file)."""
        s = self.loaded.session
        if s.path.suffix.lower() == ".toml":
            raise ValueError("a manifest names its lens as camera.lens; edit it and reopen")
        previous = self.options.lens
        self.options.lens = profile
        self.options.manifest = s.path
        self.open(s.path, on_fail=lambda: setattr(self.options, "lens", previous))

    def add_layer(self, location: str, background: bool = False) -> None:
        """Reopen the clip with one more scene layer (a tileset, a DEM, a city, a model in ECEF),
        as a dropped or opened tileset.json, .tif or .city.json does (background: read on a
        thread, see open)."""

        s = self.loaded.session if self.loaded is not None else None
        if s is None or s.path.suffix.lower() == ".toml":
            raise ValueError(
                f"{location}: a manifest names its scene ([scene], [[layers]], [dem]); edit it and reopen, or open a clip first"
            )
        previous = self.options.layers
        self.options.layers = (*previous, Layer.of(location))
        self.options.manifest = s.path
        self.open(s.path, background, lambda: setattr(self.options, "layers", previous))

    def wait_until_tiles_loaded(self) -> None:
        """Load the tiles the current view and the projector need (scripts, screenshots)."""
        L = self.loaded
        if L is None or not L.renderer.scene.tilesets or self.window_camera is None:
            return
        for layer in L.renderer.scene.tilesets:
            layer.max_sse_px = self.ui.max_sse_px
        if not L.renderer.settle(self.window_camera, self.ui.settings, SOLVE_WAIT_S):
            raise GeofuseError(f"the 3D Tiles did not load within {SOLVE_WAIT_S:g} s")

    def _tile_messages(self) -> None:
        """Tile load failures and skipped content, said once each as information."""
        errors = [e for layer in self.loaded.renderer.scene.tilesets for e in layer.stream.errors]
        for e in errors[self.ui.tile_errors_said :]:
            self.ui.info.append(f"3D Tiles: {e}")
        self.ui.tile_errors_said = len(errors)
        for layer in self.loaded.renderer.scene.tilesets:
            for kind in layer.stream.skipped.snapshot():
                note = f"3D Tiles: skipped {kind} (the Stats panel counts them)"
                if note not in self.ui.info:
                    self.ui.info.append(note)

    def wait_until_solved(self, registered: bool = False) -> None:
        """Hold everything until every source is solved: all but `registered` (a script's `wait
        solved`: registration takes about as long as the clip), or it too (`wait registered`)."""
        but = () if registered else (REGISTERED,)
        libraries = [] if self.loaded is None else [self.loaded.library]
        libraries += [c.library for c in self.loaded.others] if self.loaded is not None else []
        if not all(lib.wait(SOLVE_WAIT_S, but) for lib in libraries):
            raise GeofuseError(f"the pose sources were not solved within {SOLVE_WAIT_S:g} s")

    def open(
        self,
        manifest: Path | None,
        background: bool = False,
        on_fail: Callable[[], None] | None = None,
    ) -> bool:
        """Open a session or clip (the bundled sample when None); on failure keep the current one
        (and run on_fail). background: read it on a thread (OpenJob) and install it when read
        (poll_open); True then means only that reading began."""

        path = Path(manifest) if manifest is not None else SAMPLE_DIR / "session.toml"
        if path.suffix.lower() == ".parquet":  # an archive of clips (geofuse index)
            try:
                archive.load(self, path)
            except GeofuseError as exc:
                self.ui.error(str(exc))
                return False
            return True
        if manifest is not None and _is_layer(path):
            try:
                self.add_layer(str(path), background)
            except (ValueError, GeofuseError) as exc:
                self.ui.error(str(exc))
                return False
            return True
        if self.ui.opening is not None:
            self.ui.error(f"{path}: still opening {self.ui.opening.path}; open it after")
            return False
        own = path == self.options.manifest
        job = OpenJob(
            path,
            self.options.srt if own else None,
            self.options.lens if own else None,
            self.options.layers if own else (),
            on_fail,
            self.options.start if own else None,
            self.options.gnss_accuracy_m if own else None,
        )
        if background:
            self.ui.opening = job.start()
            return True
        job.run()
        return self._install(job)

    def poll_open(self) -> None:
        """Install a session read in the background, once read (each frame)."""
        job = self.ui.opening
        if job is not None and job.done:
            self.ui.opening = None
            self._install(job)

    def _install(self, job: OpenJob) -> bool:
        """What a read session needs to be shown: its renderer, player, solvers, clips."""
        if job.result is None:
            self.ui.error(job.error or f"{job.path}: could not be opened")
            if job.on_fail is not None:
                job.on_fail()
            return False
        path = job.path
        session, mesh = job.result
        live.close(self)
        self.close_session()
        cold = session.start is not None and REGISTERED in session.sources
        first = REGISTERED if cold else session.sources[0]  # no GNSS: only it has positions
        self.loaded = Loaded(
            session,
            FusionRenderer(self.window.ctx, mesh),
            Player(session.video),
            SolverLibrary(session, first=first),
            first,
        )
        self.ui.info, self.ui.warnings, self._messages_seen = [], [], 0
        self._show_messages()
        self.ui.time_offset_s = 0.0
        if session.course_pitch_deg is not None:
            self.ui.course_pitch_deg = session.course_pitch_deg
        self.stats = Stats()
        self.nav = home_view(session, mesh)
        world.start(self.loaded, job.worlds)
        clips.retime(self)
        for ref in session.further:  # [[clips]] of the manifest
            try:
                clips.add(self, ref.path, ref)
            except (GeofuseError, ValueError) as exc:
                self.ui.error(f"{ref.path}: {exc}")
        measure.load(self)
        if self.ui.archive is not None:  # the archive's footprints near this session
            try:
                archive.load(self, self.ui.archive.path)
            except GeofuseError as exc:
                self.ui.error(str(exc))
        log.info(
            "opened %s: %d frames, sources %s", path, len(session.video.pts_s), session.sources
        )
        return True

    def close_session(self) -> None:
        if self.loaded is not None:
            clips.close_all(self.loaded)
            memory.close(self.loaded)
            world.close(self.loaded)
            self.loaded.player.close()
            self.loaded.library.close()
            self.loaded.renderer.release()
            self.loaded = None

    def _prefer_registered(self) -> None:
        """Once `registered` is solved in the background, show it: it lines the video up with the
        model where the sensor filters leave it metres off. Said among the notes; a source the
        user chose (panel, key, script) is kept, and a registration that used no keyframe changes
        nothing worth switching to."""
        L = self.loaded
        if L.registered_said or L.source_chosen or L.source == REGISTERED:
            return
        if REGISTERED not in L.session.sources:
            return
        track = L.library.track(REGISTERED)
        if track is None or track.registration is None:
            return
        L.registered_said = True
        if not any(k.used for k in track.registration.keyframes):
            self.ui.info.append(
                f"registered used no keyframe: staying on {L.source} (the Attitude panel says why)"
            )
            return
        self.ui.info.append(
            f"registered is solved: showing it instead of {L.source} (the Attitude panel switches back)"
        )
        L.source = REGISTERED

    def _show_messages(self) -> None:
        """The session's messages not shown yet, by level: information among the notes,
        warnings apart (the Session panel shows them first), errors as errors. What the solver
        thread finds arrives here too."""
        self.show_messages(self.loaded.session.messages)

    def show_messages(self, messages) -> None:
        """Messages (app.core.messages) not shown yet, from what is open (a session, a stream),
        by level: information among the notes, warnings apart, errors as errors."""
        new = messages.since(self._messages_seen)
        self._messages_seen += len(new)
        for m in new:
            if m.level == ERROR:
                self.ui.error(m.text)
            elif m.level == WARNING:
                self.ui.warnings.append(m.text)
            else:
                self.ui.info.append(m.text)
