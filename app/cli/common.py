"""What several commands share: the scene layers and projection settings their options name,
the session opened with its attitude source, solving it, and printing its messages."""

from __future__ import annotations

import argparse
import sys
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.camera.pinhole import Camera
from app.camera.profiles import still_camera
from app.core.constants import DEFAULT_START_RADIUS_M, DRONE_DEFAULT_PITCH_DEG
from app.core.errors import GeofuseError, ManifestError
from app.core.imageio import read_rgb
from app.core.outputs import check_output
from app.core.progress import ProgressBar
from app.core.settings import ProjectionSettings
from app.footage.clips import open_any
from app.geodesy.enu import LocalFrame
from app.io.area import read_area
from app.register.solve import RegistrationSettings
from app.scene import Placement
from app.scene.layers import Layer, LoadedLayers, load_layers, named_layers
from app.scene.mesh import MeshData
from app.session.camera_track import CameraTrack
from app.session.config import ClipRef
from app.session.model import REGISTERED, Session
from app.session.start import StartArea
from app.solve.track import solve_track
from app.world.build import world_layer
from app.world.overpass import is_overpass
from app.world.settings import NONE, choose_world


def layers(
    args: argparse.Namespace, placement: Placement | None = None, clip: bool = True
) -> tuple[Layer, ...]:
    """The layers --scene/--dem/--ortho/--buildings name, checked: files exist, kinds known;
    for a clip (clip: not a manifest, not a still), the world --world/--imagery/--terrain name, or with no
    scene the settings' default (app.world.settings.choose_world)."""
    names = list(getattr(args, "scene", None) or [])
    if getattr(args, "dem", None) is not None:
        names.append(str(args.dem))
    given = list(getattr(args, "buildings", None) or [])
    buildings = [b for b in given if not is_overpass(b)]  # files: drawn on the world, if any
    fetched = [b for b in given if is_overpass(b)]  # fetched over the clip's area by its world
    if len(fetched) > 1:
        raise GeofuseError("--buildings overpass: once (one query for the clip's area)")
    named = named_layers(
        names + buildings,
        args.ortho,
        args.dem_vertical,
        args.dem_error,
        placement,
        getattr(args, "city_theme", None),
    )
    return named + _world_layers(args, bool(names), clip, fetched[0] if fetched else None)


def _world_layers(
    args: argparse.Namespace, scene_named: bool, clip: bool, buildings: str | None = None
) -> tuple[Layer, ...]:
    """The world layer of --world/--imagery/--terrain/--buildings overpass: (or the settings'
    default), () for none; refused where there is no clip's track to build it around."""
    name, imagery, terrain = (getattr(args, k, None) for k in ("world", "imagery", "terrain"))
    if not clip:
        if imagery or terrain or buildings or (name is not None and name.lower() != NONE):
            raise GeofuseError(
                "--world/--imagery/--terrain/--buildings overpass: drape a clip's track: give a clip (a manifest names its scene; a still's scene is --scene/--dem)"
            )
        return ()
    world = choose_world(
        name, imagery, terrain, scene_named, getattr(args, "dem_vertical", None), buildings
    )
    return () if world is None else (world_layer(world),)


def projection_settings(args: argparse.Namespace) -> ProjectionSettings:
    """--alpha, --bias, --slope-bias, --no-neighbourhood, --depth-size (range-checked by
    ProjectionSettings)."""
    try:
        return ProjectionSettings(
            alpha=args.alpha,
            bias_constant_m=args.bias,
            bias_slope=args.slope_bias,
            neighbourhood=not args.no_neighbourhood,
            depth_long_side=args.depth_size,
        )
    except ValueError as exc:
        raise GeofuseError(f"projection settings: {exc}") from exc


def solved(session: Session, source: str, keyframes_s: float | None = None) -> CameraTrack:
    """The session's camera track under `source` (a progress bar on stderr while registering),
    printing the registration's summary line and the messages solving raised. keyframes_s: the
    `registered` source's seconds of video between keyframes (None: RegistrationSettings')."""
    options = {}
    if source == REGISTERED and keyframes_s is not None:
        options["settings"] = RegistrationSettings(every_s=keyframes_s)
    track = solve_track(
        session, source, progress=ProgressBar(f"registering ({source})", sys.stderr), **options
    )
    if track.registration is not None:
        print(track.registration.summary(), file=sys.stderr)
    print_messages(session)
    return track


def open_with_source(
    path: Path, args: argparse.Namespace, suffixes: tuple[str, ...], any_source: bool = False
) -> tuple[Session, str]:
    """(session, source) for a command: the session or clip opened, --out (when the command
    writes one) checked against every file it reads, --source checked against what it offers
    (any_source: a further clip that does not offer it takes its own first)."""
    start = start_area(args)
    session = open_any(
        path,
        getattr(args, "srt", None),
        single(getattr(args, "fov", None)),
        getattr(args, "pitch", DRONE_DEFAULT_PITCH_DEG),
        single(args.lens),
        layers(args, clip=Path(path).suffix.lower() != ".toml"),
        start,
        getattr(args, "gnss_accuracy", None),
    )
    if getattr(args, "out", None) is not None:
        check_output(args.out, "--out", suffixes, list(session.inputs))
    first = REGISTERED if start is not None and REGISTERED in session.sources else None
    source = args.source or first or session.sources[0]
    if any_source and source not in session.sources:  # a further clip: its own first source
        source = session.sources[0]
    if source not in session.sources:
        raise GeofuseError(f"--source {source}: this session offers {', '.join(session.sources)}")
    return session, source


def start_area(args: argparse.Namespace) -> StartArea | None:
    """The area --near with --radius (default DEFAULT_START_RADIUS_M), or --start-area, names,
    with --height (app.session.start.StartArea); None where neither is given. GeofuseError for
    --radius or --height without one, --radius with --start-area."""
    near, polygon = getattr(args, "near", None), getattr(args, "start_area", None)
    radius, height = getattr(args, "radius", None), getattr(args, "height", None)
    if near is None and polygon is None:
        if radius is not None or height is not None:
            raise GeofuseError(
                f"{'--radius' if radius is not None else '--height'} goes with --near LAT,LON (or --start-area FILE)"
            )
        return None
    if polygon is not None:
        if radius is not None:
            raise GeofuseError("--radius goes with --near, not with --start-area")
        return StartArea.within(read_area(polygon, "--start-area"), height)
    return StartArea.near(*near, radius or DEFAULT_START_RADIUS_M, height)


def open_further(
    ref: ClipRef, args: argparse.Namespace, suffixes: tuple[str, ...], manifest: Path, key: str
) -> tuple[Session, str]:
    """(session, source) of a further clip: --source where it offers it, else its own first;
    the manifest's [[clips]] `source` where it names one (ManifestError naming `key` in
    `manifest` when the clip does not offer it)."""
    session, source = open_with_source(ref.path, args, suffixes, any_source=True)
    if ref.source is not None:
        try:
            session.check_source(ref.source)
        except ValueError as exc:
            raise ManifestError(manifest, f"{exc} ({ref.path})", field=key) from exc
        source = ref.source
    return session, source


# id of a session's messages -> (a weak reference to them, how many this command has printed);
# the reference tells a later object given the same id (the first one gone) from the first
_PRINTED: dict[int, tuple[weakref.ref, int]] = {}


def print_messages(session: Session) -> None:
    """The session's messages this command has not printed yet, each with its level ("note:" for
    information, "warning:", "error:"): called when a session opens and again after work that
    may add some (solving, registering, exporting)."""
    messages = session.messages
    ref, done = _PRINTED.get(id(messages), (None, 0))
    if ref is None or ref() is not messages:
        done = 0  # not printed by this command: a new object, perhaps at a freed one's address
    new = messages.since(done)
    for message in new:
        print(message, file=sys.stderr)
    _PRINTED[id(messages)] = (weakref.ref(messages), done + len(new))


def print_scene_report(mesh: MeshData) -> None:
    """What of the scene's 3D Tiles could not be drawn, a line per tileset (the kinds skipped
    with their counts, the tiles missing or damaged with the first named), as warnings."""
    for tileset in mesh.tilesets:
        line = tileset.report()
        if line:
            print(f"warning: 3D Tiles {line}", file=sys.stderr)


def nothing_drawn(samples: int, mesh: MeshData) -> bool:
    """Say so when a still shows none of the scene (all of it out of view, or no tile loaded):
    samples, the scene's fragments drawn; True then."""
    if samples > 0:
        return False
    what = "no tile could be drawn" if mesh.tilesets else "the scene is out of view"
    print(
        f"warning: nothing of the scene was drawn ({what}): check the camera's pose and the scene's placement",
        file=sys.stderr,
    )
    return True


@dataclass(frozen=True)
class StillScene:
    """A still's scene and cameras as --scene/--dem, --origin, --image, --pose and --fov/--lens
    name them: the layers loaded in `frame` (the origin's, else the first camera's), the first
    image and its camera, further (image, camera) pairs projected with it (repeated --image and
    --pose, paired by order); inputs: every file read (never to be written)."""

    loaded: LoadedLayers
    frame: LocalFrame
    image: np.ndarray
    camera: Camera
    inputs: list[Path]
    extras: tuple[tuple[np.ndarray, Camera], ...] = ()


def single(value: object) -> object:
    """An option given once where the still options allow it repeated (--lens with a clip)."""
    return value[-1] if isinstance(value, list) else value


def _per_image(values: list | None, n: int, option: str) -> list:
    """One value per image: given once (for all) or once each."""
    if not values:
        return [None] * n
    if len(values) == 1:
        return values * n
    if len(values) != n:
        raise GeofuseError(
            f"{option}: give it once (for every image) or {n} times, got {len(values)}"
        )
    return values


def still_scene(args: argparse.Namespace, what: str, far: float) -> StillScene:
    """Load a still's scene and build its cameras (far: their far plane, m), after checking that
    every option they need is given (`what` begins the error that lists those missing)."""
    named = layers(
        args,
        Placement(
            origin=args.origin,
            up_axis=args.up,
            heading_deg=args.scene_heading,
            scale=args.scene_scale,
        ),
        clip=False,
    )
    missing = [f"--{k.replace('_', '-')}" for k in ("image", "pose") if not getattr(args, k)]
    if not named:
        missing.insert(0, "--scene (or --dem)")
    if args.origin is None and any(not layer.georeferenced for layer in named):
        missing.append("--origin (a model's origin)")
    if not args.fov and not args.lens:
        missing.append("--fov (or --lens)")
    if missing:
        raise GeofuseError(f"{what} {', '.join(missing)}")
    n = len(args.image)
    if len(args.pose) != n:
        raise GeofuseError(f"--pose: give one for each --image ({n}), got {len(args.pose)}")
    fovs, lenses = _per_image(args.fov, n, "--fov"), _per_image(args.lens, n, "--lens")
    lat, lon, h = args.pose[0][:3]
    frame = LocalFrame(*(args.origin or (lat, lon, h)))
    loaded = load_layers(named, frame, [[p[0], p[1]] for p in args.pose])
    loaded.warn_far([frame.geodetic_to_enu(*p[:3]) for p in args.pose], "the camera")
    for message in loaded.notes.since(0):
        print(message, file=sys.stderr)
    stills = []
    for path, pose, fov, lens in zip(args.image, args.pose, fovs, lenses, strict=True):
        image = read_rgb(path)
        try:
            camera = still_camera(
                (image.shape[1], image.shape[0]),
                frame.geodetic_to_enu(*pose[:3]),
                tuple(pose[3:]),
                fov,
                lens,
                far=far,
            )
        except ValueError as exc:
            raise GeofuseError(f"--fov: {exc}") from exc
        stills.append((image, camera))
    inputs = [*(f for layer in named for f in layer.files()), *args.image, *(args.lens or [])]
    (image, camera), *extras = stills
    return StillScene(
        loaded, frame, image, camera, [Path(p) for p in inputs if p is not None], tuple(extras)
    )
