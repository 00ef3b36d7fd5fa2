"""The session manifest: its schema, read and validated once into a frozen `SessionConfig` (the
TOML reader that types and checks each key is app.session.reader).

    [origin]                      # optional: the session's ENU origin (default: the scene's, else
                                  # the first GNSS fix)
    lat = 34.80                   # degrees
    lon = 113.53                  # degrees
    h = 110.0                     # ellipsoidal metres

    [scene]                       # optional: without it (and without layers or a DEM), an
                                  # assumed flat ground under the track
    path = "scene.glb"            # glTF/GLB, OBJ, PLY; or a 3D Tiles tileset.json (folder or
                                  # http(s) URL), a DEM .tif or a city model (CityJSON
                                  # .city.json/.city.jsonl, CityGML .gml/.xml/.zip; building
                                  # footprints .osm/.osm.pbf/.parquet, extruded on the other
                                  # layers' ground), which place themselves
    origin = [34.80, 113.53, 110.0]  # a model's origin (tilesets and DEMs need none)
    up_axis = "Y"                 # optional: Y for glTF, Z otherwise
    heading_deg = 0.0             # optional
    scale = 1.0                   # optional
    vertical = "egm2008"          # a city model's heights, optional: "ellipsoid", "egm2008" or
                                  # "egm96" (default: its CRS's vertical datum, else EGM2008)
    lod = 1.2                     # a city model's highest level of detail read, optional
                                  # (default: each object's highest)
    theme = "rgbTexture"          # a city model's appearance theme drawn, optional (default:
                                  # the first the file names)

    [[layers]]                    # optional, repeated: more layers drawn together with [scene]
    path = "city/tileset.json"    # same kinds as scene.path; a model here takes the same keys
                                  # (origin, up_axis, heading_deg, scale)

    [world]                       # optional: terrain and imagery from tile services around the
                                  # track, drawn with the layers above (app.world): a [[world]]
    name = "maptiler"             # of the settings file by its name alone, or sources of its
    imagery = "ortho.mbtiles"     # own as a [[world]] table gives them (files relative to the
    terrain = "terrain-rgb:https://host/{z}/{x}/{y}.png"  # manifest; a key by key_env only)

    [[clips]]                     # optional, repeated: further clips played with this one
    path = "other/session.toml"   # a manifest or a camera file (its own settings live there)
    offset_s = 0.0                # optional: its shift on the timeline (s)
    priority = 0.0                # optional: where clips see one surface, the higher wins
    alpha = 0.8                   # optional: its opacity 0..1 (default: the viewer's)
    source = "gd-ahrs"            # optional: its pose source, one of ATTITUDE_SOURCES that the
                                  # clip offers (default: its first)

    [dem]                         # optional: terrain from a GeoTIFF DEM in any CRS
    path = "dem.tif"
    ortho = "ortho.tif"           # optional: an orthophoto GeoTIFF draped on it
    vertical = "egm2008"          # optional: "ellipsoid", "egm2008" or "egm96" (default: the
                                  # file's vertical CRS, else EGM2008)
    max_error_m = 0.5             # optional: the terrain mesh's largest vertical error

    [video]
    path = "clip.mp4"
    start_time = 1700000000.0     # optional: session-clock seconds of the first frame (default:
                                  # the video's creation time)
    time_offset_s = 0.0           # optional: added to every frame time (sync correction), or
                                  # "auto": found from the video against the gyroscope (geofuse
                                  # sync; NAME.geofuse.toml beside the manifest keeps it)
    timing = "pts"                # or "eq5": frame i at i / nominal fps (paper Eq. 5)

    [camera]
    hfov_deg = 66.0               # or focal_mm + sensor_width_mm, or a lens profile:
    lens = "profile.json"         # optional: a gyroflow lens profile (fisheye or Brown-Conrady)
    readout_ms = 30.0             # optional: rolling-shutter readout, first row to last (default:
                                  # the lens profile's; unknown: not corrected)
    rotation_cw = 90              # optional: override the video's display rotation

    [sensors]
    mag_calibration = "clip"      # or "none": fit hard-iron offset and scale on the clip
    format = "csv"                # "csv": acc, gyr, mag, orientation files below;
                                  # "gopro": the GPMF telemetry inside [video]'s MP4;
                                  # "none": no IMU (a drone clip with its .SRT as [gnss]);
    acc = "acc.csv"               # "sensorlogger": path = folder or zip
    gyr = "gyr.csv"
    mag = "mag.csv"               # optional: without it only IMU filters are offered
    orientation = "phone.csv"     # optional: the phone's own attitude (a recorded source)

    [gnss]
    path = "gnss.csv"             # CSV (csvlog.py), GPX, or a DJI .SRT (times from the clip start)
    takeoff_height_m = 110.0      # optional, for heights above take-off: the take-off point's
                                  # ellipsoidal height (default: the scene's ground under the
                                  # first position)
    height_offset_m = 0.0         # optional: added to heights (e.g. geoid separation for GPX)
    height = "gnss"               # or "ground": the model's ground under each fix + mount height
    mount_height_m = 1.5          # with height = "ground": camera above the ground (hand-held 1.5)
    pitch_deg = -30.0             # a DJI subtitle without gimbal attitude: the camera's pitch
    accuracy_m = 2.0              # optional: the fixes' horizontal accuracy (m, 1 sigma per
                                  # axis) where they state none (DJI, GPX); default: 5 assumed

    [truth]                       # optional, for simulated sessions
    orientation = "truth.csv"     # device -> ENU quaternions (t, qw, qx, qy, qz)
    position = "truth_pos.csv"    # optional: t, lat, lon, h
    frame_times = "frames.csv"    # optional: frame, t (each frame's true session time)

Relative paths resolve against the manifest's folder. Times of every log and of the video must be
on one clock (Unix seconds for phone apps). Every error names the manifest key; every number is
checked for finiteness and range here, where it enters.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from app.core.constants import COURSE, DRONE_DEFAULT_PITCH_DEG, FOV_RANGE_DEG, REGISTERED, TRUTH
from app.core.errors import GeofuseError, ManifestError, SceneError
from app.geodesy.geoid import VERTICAL_DATUMS
from app.scene import Placement
from app.scene.layers import Layer, layer_kind
from app.scene.tiles import fetch
from app.session.model import FILTERS
from app.session.reader import Manifest, array_tables, check_keys, checked_geodetic, load_manifest
from app.world.build import world_layer
from app.world.settings import MANIFEST_KEYS, manifest_world

HANDHELD_MOUNT_M = 1.5  # a hand-held or body camera's height above the ground, metres
_PLACED = {"path", "origin", "up_axis", "heading_deg", "scale"}
KNOWN_KEYS: dict[str, set[str]] = {  # every table and key of the schema above
    "origin": {"lat", "lon", "h"},
    "scene": _PLACED | {"vertical", "lod", "theme"},
    "layers": _PLACED | {"vertical", "lod", "theme"},
    "dem": {"path", "ortho", "vertical", "max_error_m"},
    "clips": {"path", "offset_s", "priority", "alpha", "source"},
    "video": {"path", "start_time", "time_offset_s", "timing"},
    "camera": {"hfov_deg", "focal_mm", "sensor_width_mm", "lens", "readout_ms", "rotation_cw"},
    "sensors": {
        "format",
        "mag_calibration",
        "acc",
        "gyr",
        "mag",
        "orientation",
        "path",
        "standardised",
    },
    "gnss": {
        "path",
        "takeoff_height_m",
        "height_offset_m",
        "height",
        "mount_height_m",
        "pitch_deg",
        "accuracy_m",
    },
    "truth": {"orientation", "position", "frame_times"},
    "world": MANIFEST_KEYS,
}


SENSOR_FORMATS = ("csv", "sensorlogger", "gopro", "none")
RECORDED_SOURCES = ("camera", "phone", "telemetry")  # app.session.assemble, app.footage.clips
ATTITUDE_SOURCES = (*FILTERS, COURSE, *RECORDED_SOURCES, REGISTERED, TRUTH)  # any clip's, named


@dataclass(frozen=True)
class ClipRef:
    """A further clip a manifest names ([[clips]]): its manifest or camera file (its own settings
    live there), its offset on the timeline (s), priority, opacity (None: the viewer's) and pose
    source (None: the first it offers)."""

    path: Path
    offset_s: float = 0.0
    priority: float = 0.0
    alpha: float | None = None
    source: str | None = None


@dataclass(frozen=True)
class SceneConfig:
    """The [scene] table: its layer and, for a model, the geographic origin it gives."""

    layer: Layer
    origin: tuple[float, float, float] | None  # the scene's origin: deg, deg, ellipsoidal m

    @property
    def path(self) -> str:
        return self.layer.location

    @property
    def placement(self) -> Placement:
        return self.layer.placement


@dataclass(frozen=True)
class VideoConfig:
    path: Path
    start_time: (
        float | None
    )  # session-clock seconds of the first frame; None: the video's creation time
    time_offset_s: float
    timing: str  # "pts" or "eq5"
    auto_offset: bool = False  # time_offset_s = "auto"


@dataclass(frozen=True)
class CameraConfig:
    hfov_deg: float | None
    focal_mm: float | None
    sensor_width_mm: float | None
    rotation_cw: int | None  # None: the video's display rotation
    lens: Path | None = None  # a gyroflow lens profile
    readout_ms: float | None = None  # rolling shutter


@dataclass(frozen=True)
class SensorsConfig:
    format: str  # one of SENSOR_FORMATS
    acc: Path | None = None
    gyr: Path | None = None
    mag: Path | None = None
    orientation: Path | None = None
    path: Path | None = None  # a Sensor Logger folder or zip
    standardised: bool = False
    mag_calibration: str = "clip"


@dataclass(frozen=True)
class GnssConfig:
    path: Path | None  # None: the positions come from the sensors (GoPro, Sensor Logger)
    takeoff_height_m: float | None
    height_offset_m: float
    height: str  # "gnss" or "ground"
    mount_height_m: float
    pitch_deg: float  # a subtitle without gimbal attitude: the camera's assumed pitch
    accuracy_m: float | None = None  # the fixes' accuracy (m) where they state none


@dataclass(frozen=True)
class TruthConfig:
    orientation: Path | None = None
    position: Path | None = None
    frame_times: Path | None = None


@dataclass(frozen=True)
class SessionConfig:
    """A validated manifest. `origin`: the session's ENU origin (deg, deg, ellipsoidal m)."""

    path: Path
    origin: tuple[float, float, float] | None  # None: the first GNSS fix (sessions without a scene)
    scene: SceneConfig | None  # the [scene] table, if any
    video: VideoConfig
    camera: CameraConfig
    sensors: SensorsConfig
    gnss: GnssConfig
    truth: TruthConfig
    layers: tuple[
        Layer, ...
    ] = ()  # [scene], [[layers]] and [dem], in that order; () : an assumed ground
    clips: tuple[ClipRef, ...] = ()  # [[clips]]: further clips played with this one

    def inputs(self) -> list[Path]:
        """Every file the session reads (never to be written)."""
        s, g, t = self.sensors, self.gnss, self.truth
        files = [
            self.path,
            *(f for layer in self.layers for f in layer.files()),
            *(c.path for c in self.clips),
            self.video.path,
            self.camera.lens,
            s.acc,
            s.gyr,
            s.mag,
            s.orientation,
            s.path,
            g.path,
            t.orientation,
            t.position,
            t.frame_times,
        ]
        return [p for p in files if p is not None]


def _location(m: Manifest, section: str, key: str) -> str:
    """A layer's location: an http(s) URL as written, or an existing file's resolved path."""
    value = m.get(section, key, str)
    return value if fetch.is_url(value) else str(m.file(section, key))


def _layer(m: Manifest, section: str) -> tuple[Layer, tuple[float, float, float] | None]:
    """(layer, model origin) of a [scene] or [[layers]] table."""
    location = _location(m, section, "path")
    try:
        kind = layer_kind(location)
    except SceneError as exc:
        raise ManifestError(m.path, exc.detail, field=f"{section}.path") from exc
    origin = m.geodetic(section, "origin")
    up = m.get(section, "up_axis", str, None)
    if up is not None and up not in ("Y", "Z"):
        raise ManifestError(m.path, f"got {up!r}, expected 'Y' or 'Z'", field=f"{section}.up_axis")
    placement = Placement(
        origin,
        up,
        m.number(section, "heading_deg", 0.0, low=-360.0, high=360.0),
        m.number(section, "scale", 1.0, low=0.0, high=1e6, open_low=True),
    )
    vertical = m.get(section, "vertical", str, None)
    if vertical is not None and (kind != "city" or vertical not in VERTICAL_DATUMS):
        raise ManifestError(
            m.path,
            f"got {vertical!r}, expected {' or '.join(repr(v) for v in VERTICAL_DATUMS)} for a city model"
            if kind == "city"
            else "a vertical datum is a city model's key (a DEM's is dem.vertical)",
            field=f"{section}.vertical",
        )
    lod = m.number(section, "lod", None, low=0.0, high=4.0)
    if lod is not None and kind != "city":
        raise ManifestError(
            m.path, "a level of detail is a city model's key", field=f"{section}.lod"
        )
    theme = m.get(section, "theme", str, None)
    if theme is not None and kind != "city":
        raise ManifestError(
            m.path, "an appearance theme is a city model's key", field=f"{section}.theme"
        )
    return Layer(location, kind, placement, vertical=vertical, lod=lod, theme=theme), origin


def _layers(m: Manifest) -> list[Layer]:
    """[[layers]] tables, then [dem]."""
    out = [_layer(one, name)[0] for name, one in array_tables(m, "layers")]
    if m.section("dem", required=False):
        path = m.file("dem", "path")
        if layer_kind(path) != "dem":
            raise ManifestError(
                m.path, f"got {path.name!r}, expected a GeoTIFF (.tif)", field="dem.path"
            )
        vertical = m.get("dem", "vertical", str, None)
        if vertical is not None and vertical not in VERTICAL_DATUMS:
            raise ManifestError(
                m.path,
                f"got {vertical!r}, expected {' or '.join(repr(v) for v in VERTICAL_DATUMS)}",
                field="dem.vertical",
            )
        out.append(
            Layer(
                str(path),
                "dem",
                ortho=m.file("dem", "ortho", required=False),
                vertical=vertical,
                max_error_m=m.number("dem", "max_error_m", 0.5, low=0.01, high=100.0),
            )
        )
    return out


def _clips(m: Manifest) -> tuple[ClipRef, ...]:
    """[[clips]] tables: a further clip each (a manifest or a camera file that exists)."""
    out = []
    for name, one in array_tables(m, "clips"):
        alpha = one.get(name, "alpha", float, None)
        if alpha is not None and not 0.0 <= alpha <= 1.0:
            raise ManifestError(m.path, f"got {alpha}, expected 0 to 1", field=f"{name}.alpha")
        named = one.get(name, "source", str, None)  # which of them the clip offers: when opened
        source = None if named is None else one.choice(name, "source", ATTITUDE_SOURCES, named)
        out.append(
            ClipRef(
                one.file(name, "path"),
                one.number(name, "offset_s", 0.0, low=-1e6, high=1e6),
                one.number(name, "priority", 0.0, low=-10.0, high=10.0),
                alpha,
                source,
            )
        )
    return tuple(out)


def read_config(path: str | Path) -> SessionConfig:
    """Read and validate a manifest (files named must exist; values typed and in range)."""
    m = load_manifest(path)
    check_keys(m.path, m.data, KNOWN_KEYS)
    scene = SceneConfig(*_layer(m, "scene")) if m.section("scene", required=False) else None
    layers = ([scene.layer] if scene else []) + _layers(m)
    if m.section("world", required=False):
        try:
            world = manifest_world(m.section("world"), m.path.parent)
        except GeofuseError as exc:
            raise ManifestError(m.path, str(exc), field="world") from exc
        layers.append(world_layer(world))
    if m.section("origin", required=False):
        origin = checked_geodetic(
            m.path, "origin", *(m.get("origin", k, float) for k in ("lat", "lon", "h"))
        )
    elif scene is not None and scene.origin is not None:
        origin = scene.origin
    elif all(layer.georeferenced for layer in layers):
        origin = None  # the first GNSS fix
    else:
        raise ManifestError(
            m.path,
            "give [origin] or scene.origin: the session needs a geographic origin",
            field="origin",
        )

    auto = m.get("video", "time_offset_s", (float, str), 0.0) == "auto"
    offset = 0.0 if auto else m.number("video", "time_offset_s", 0.0, low=-86400.0, high=86400.0)
    video = VideoConfig(
        m.file("video", "path"),
        m.number("video", "start_time", None),
        offset,
        m.choice("video", "timing", ("pts", "eq5"), "pts"),
        auto,
    )
    m.section("camera")
    rotation = m.get("camera", "rotation_cw", int, None)
    if rotation is not None and rotation % 90:
        raise ManifestError(
            m.path, f"got {rotation}, expected 0, 90, 180 or 270", field="camera.rotation_cw"
        )
    camera = CameraConfig(
        m.number("camera", "hfov_deg", None, low=FOV_RANGE_DEG[0], high=FOV_RANGE_DEG[1]),
        m.number("camera", "focal_mm", None, low=0.0, high=10_000.0, open_low=True),
        m.number("camera", "sensor_width_mm", None, low=0.0, high=1_000.0, open_low=True),
        None if rotation is None else rotation % 360,
        m.file("camera", "lens", required=False),
        m.number("camera", "readout_ms", None, low=0.0, high=200.0),
    )
    if (
        camera.hfov_deg is None
        and camera.lens is None
        and (camera.focal_mm is None or camera.sensor_width_mm is None)
    ):
        raise ManifestError(
            m.path, "expected hfov_deg, focal_mm and sensor_width_mm, or lens", field="camera"
        )

    fmt = m.choice("sensors", "format", SENSOR_FORMATS, "csv")
    calibration = m.choice("sensors", "mag_calibration", ("clip", "none"), "clip")
    if fmt == "csv":
        sensors = SensorsConfig(
            fmt,
            m.file("sensors", "acc"),
            m.file("sensors", "gyr"),
            m.file("sensors", "mag", required=False),
            m.file("sensors", "orientation", required=False),
            mag_calibration=calibration,
        )
    elif fmt == "sensorlogger":
        sensors = SensorsConfig(
            fmt,
            path=m.file("sensors", "path"),
            standardised=bool(m.get("sensors", "standardised", bool, False)),
            mag_calibration=calibration,
        )
    else:
        sensors = SensorsConfig(fmt, mag_calibration=calibration)
    own_positions = fmt in ("gopro", "sensorlogger")
    gnss = GnssConfig(
        m.file("gnss", "path", required=not own_positions, required_section=not own_positions),
        m.number(
            "gnss", "takeoff_height_m", None, low=-12_000.0, high=100_000.0, required_section=False
        ),
        m.number(
            "gnss", "height_offset_m", 0.0, low=-1_000.0, high=1_000.0, required_section=False
        ),
        m.choice("gnss", "height", ("gnss", "ground"), "gnss", required_section=False),
        m.number(
            "gnss",
            "mount_height_m",
            HANDHELD_MOUNT_M,
            low=0.0,
            high=10_000.0,
            required_section=False,
        ),
        m.number(
            "gnss",
            "pitch_deg",
            DRONE_DEFAULT_PITCH_DEG,
            low=-90.0,
            high=90.0,
            required_section=False,
        ),
        m.number("gnss", "accuracy_m", None, low=0.1, high=1000.0, required_section=False),
    )
    truth = TruthConfig(
        *(
            m.file("truth", k, required=False, required_section=False)
            for k in ("orientation", "position", "frame_times")
        )
    )
    return SessionConfig(
        m.path, origin, scene, video, camera, sensors, gnss, truth, tuple(layers), _clips(m)
    )
