"""The bundled sample session: a person walks past the sample stadium's south front filming it
with a phone held in landscape, and everything a phone would record, plus the truth.

Motion (80 s): along the service path 62 m south of the hall's centre, eastward at 1.4 m/s with
handheld sway and step bounce; a 5 s stop (t = 30-35 s); the camera follows the hall with a slow
left-right pan, swings 70 deg right and back quickly (t = 40-46 s), points up at the roof edge
(t = 55-63 s). The phone is held in landscape with its top to the right, so the video is stored
turned (display rotation 180 deg), as phones do. The video is rendered from a world that differs
from the model the manifest names (app/simulate/world.py: textures retaken, trees, kiosks and
parked cars, another light, the camera's blur and noise), and shows moving cars, people and a
banner that the model lacks. Sensors: app/simulate/sensors.py (error model with sources). The manifest's
video start time is 80 ms late, as a start time taken from a file timestamp would be; the truth
says by how much (docs/ACCURACY.md measures what that costs).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from app.camera.intrinsics import Intrinsics
from app.camera.trajectory import device_to_camera
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.geodesy.geomag import field_enu
from app.scene import load_scene, shapes
from app.scene.mesh import MeshData
from app.simulate import flights, sensors
from app.simulate.city import site_buildings, write_cityjson
from app.simulate.flights import Flight
from app.simulate.phone import Motion, body_rates, specific_force
from app.simulate.stadium import HALL_MAX, HALL_MIN, SITE_ORIGIN
from app.simulate.video import render_video
from app.simulate.world import world_of

START_UNIX_S = 1_763_200_000.0  # 2025-11-15T09:46:40Z
DURATION_S = 80.0
SPEED = 1.4
PATH_Y = -62.0
STOP = (30.0, 35.0)
QUICK_PAN = (40.0, 46.0)
ROOF_LOOK = (55.0, 63.0)
ROTATION_CW = 180  # landscape, phone top to the right
VIDEO_SIZE = (640, 360)
HFOV_DEG = 66.0
FPS = 30.0
SYNC_ERROR_S = 0.08


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def _window(t: np.ndarray, a: float, c: float, ramp: float = 1.0) -> np.ndarray:
    """0 before a, rising to 1 over `ramp` s, 1 until c, falling to 0 over `ramp` s."""
    return _smoothstep((t - a) / ramp) * (1.0 - _smoothstep((t - c) / ramp))


def _window_integral(t: np.ndarray, a: float, c: float, ramp: float = 1.0) -> np.ndarray:
    """Integral of _window from -inf to t (closed form: the smoothstep integrates to u^3 - u^4/2)."""

    def ramp_int(u: np.ndarray) -> np.ndarray:
        u = np.clip(u, 0.0, 1.0)
        return ramp * (u**3 - u**4 / 2)

    rise = ramp_int((t - a) / ramp)
    hold = np.clip(t - (a + ramp), 0.0, c - (a + ramp))
    fall = np.where(t > c, np.clip(t - c, 0.0, ramp) - ramp_int((t - c) / ramp), 0.0)
    return rise + hold + fall


def _stop_window(t: np.ndarray) -> np.ndarray:
    return _window(t, STOP[0] - 1.0, STOP[1])


def walk_position(t: np.ndarray) -> np.ndarray:
    """ENU metres at t (seconds from the video start)."""
    t = np.asarray(t, np.float64)
    along = SPEED * (t - _window_integral(t, STOP[0] - 1.0, STOP[1]))
    walking = 1.0 - _stop_window(t)
    x = -45.0 + along
    y = PATH_Y + 0.4 * np.sin(2 * np.pi * 0.05 * t) + 0.015 * walking * np.sin(2 * np.pi * 0.9 * t)
    z = 1.45 + 0.03 * walking * np.sin(2 * np.pi * 1.8 * t)
    return np.column_stack([x, y, z])


def camera_hpr(t: np.ndarray) -> np.ndarray:
    """Heading, pitch, roll (deg) of the camera's optical axis at t."""
    t = np.asarray(t, np.float64)
    p = walk_position(t)
    target = np.array([0.0, 0.0, 8.0])
    d = target - p
    heading = np.degrees(np.arctan2(d[:, 0], d[:, 1]))
    heading = (
        heading
        + 12.0 * np.sin(2 * np.pi * t / 20.0)
        + 70.0 * _window(t, QUICK_PAN[0], QUICK_PAN[1] - 2.0, 2.0)
    )
    heading = heading + 1.0 * np.sin(2 * np.pi * 0.7 * t + 0.3) + 0.5 * np.sin(2 * np.pi * 1.3 * t)
    pitch = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))) + 2.0
    pitch = pitch + 22.0 * _window(t, ROOF_LOOK[0], ROOF_LOOK[1] - 2.0, 2.0)
    pitch = pitch + 0.8 * np.sin(2 * np.pi * 0.9 * t + 1.0) + 0.4 * np.sin(2 * np.pi * 1.8 * t)
    roll = -1.0 + 1.2 * np.sin(2 * np.pi * 0.6 * t + 2.0)
    return np.column_stack([heading, pitch, roll])


def camera_attitude(t: np.ndarray, flight: Flight | None = None) -> np.ndarray:
    """Camera -> ENU quaternions at t along a flight (the walk by default)."""
    return rotations.camera_quat_from_hpr(*(flight or WALK).hpr(t).T)


WALK = Flight("walk", walk_position, camera_hpr, False)
FLIGHT_OF = {"walk": WALK, "survey": flights.survey(), "orbit": flights.orbit()}


def rotation_cw(flight: Flight) -> int:
    """How the video is stored turned: a phone in landscape (the walk), a drone's camera not."""
    return 0 if flight.aircraft else ROTATION_CW


def device_motion(flight: Flight = WALK) -> Motion:
    """The device's motion: device -> ENU = camera -> ENU turned back by the camera's mounting."""
    q_dc_inv = rotations.conjugate(device_to_camera(rotation_cw(flight)))
    return Motion(
        flight.position,
        lambda t: rotations.canonical(rotations.multiply(camera_attitude(t, flight), q_dc_inv)),
    )


# --- content the model lacks ---------------------------------------------------------------------


@dataclass(frozen=True)
class Mover:
    size: tuple[float, float, float]
    colour: tuple[float, float, float]
    y: float
    x0: float
    speed: float  # m/s along x, wrapping in [-150, 150]


MOVERS = (
    Mover((4.4, 1.8, 1.5), (0.75, 0.1, 0.1), -55.5, -80.0, 6.0),
    Mover((4.6, 1.9, 1.6), (0.1, 0.25, 0.7), -57.5, 40.0, -7.5),
    Mover((4.2, 1.8, 1.45), (0.9, 0.9, 0.88), -55.5, 60.0, 5.0),
    Mover((0.5, 0.4, 1.75), (0.2, 0.5, 0.2), -47.0, -20.0, 1.2),
    Mover((0.5, 0.4, 1.65), (0.6, 0.3, 0.5), -45.5, 10.0, -1.0),
    Mover((0.5, 0.4, 1.80), (0.9, 0.6, 0.1), -46.2, 30.0, 1.3),
)


def _banner_texture() -> np.ndarray:
    img = Image.new("RGB", (512, 64), (190, 20, 30))
    d = ImageDraw.Draw(img)
    d.rectangle([2, 2, 509, 61], outline=(255, 255, 255), width=3)
    d.text(
        (256, 32),
        "OPEN DAY  15 NOV",
        fill=(255, 255, 255),
        font=ImageFont.load_default(size=40),
        anchor="mm",
    )
    return np.asarray(img)


def _mover_vertices(m: Mover, t: float) -> np.ndarray:
    x = (m.x0 + m.speed * t + 150.0) % 300.0 - 150.0
    sx, sy, sz = m.size
    return shapes.box([x - sx / 2, m.y - sy / 2, 0.0], [x + sx / 2, m.y + sy / 2, sz]).vertices


def extras() -> list:
    """Primitives of the banner (static) and the movers (their positions updated per frame)."""
    banner = shapes.quad([-10.0, HALL_MIN[1] - 0.15, 5.0], [20.0, 0, 0], [0, 0, 2.5]).primitive(
        (1, 1, 1, 1), _banner_texture(), "banner"
    )
    movers = [
        shapes.box(*np.split(np.zeros(6), 2)).primitive((*m.colour, 1.0), name=f"mover{i}")
        for i, m in enumerate(MOVERS)
    ]
    for m, prim in zip(MOVERS, movers, strict=True):
        prim.positions = _mover_vertices(m, 0.0).astype(np.float32)
    return [banner, *movers]


# --- writing the session -------------------------------------------------------------------------

TIME_FMT = "%.5f"  # Unix seconds to 10 us
VALUE_FMT = "%.7g"  # sensor values: 7 significant digits is below every noise level
DEGREE_FMT = "%.9f"  # latitude/longitude: 1e-9 deg is 0.1 mm


def _csv(
    path: Path, header: list[str], columns: list[np.ndarray], fmt: list[str] | None = None
) -> None:
    """Write columns under a header; the first column is a time unless `fmt` says otherwise."""
    data = np.column_stack(columns)
    fmt = fmt or [TIME_FMT] + [VALUE_FMT] * (data.shape[1] - 1)
    np.savetxt(path, data, delimiter=",", header=",".join(header), comments="", fmt=fmt)


def _disturbance(p: np.ndarray, e: sensors.SensorErrors) -> np.ndarray:
    """Extra field near the hall's steel and concrete: e.disturbance_ut at 1 m, falling as 1/d^3,
    pointing away from the nearest wall point (a crude dipole stand-in)."""
    lo, hi = np.array(HALL_MIN), np.array(HALL_MAX)
    nearest = np.clip(p, lo, hi)
    d = p - nearest
    dist = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1.0)
    return e.disturbance_ut * d / dist / dist**3


@dataclass(frozen=True)
class SampleConfig:
    seed: int = 2026
    duration_s: float = DURATION_S
    errors: sensors.SensorErrors = sensors.SensorErrors()
    render_video: bool = True
    crf: int = 30
    world: bool = True  # render from a world that differs from the model (False: the model itself)
    flight: str = "walk"  # app.simulate.flights.FLIGHTS
    # name the site as a city publishes it (an untextured LoD2 CityJSON in UTM + EGM2008 heights,
    # written beside the session as CITY_NAME) as the session's scene, not the GLB
    city: bool = False


CITY_NAME = "site.city.json"


def write_sample_session(
    out: str | Path, scene_path: str | Path, config: SampleConfig = SampleConfig()
) -> Path:
    """Write the sample session (manifest, video, logs, truth) into `out`; returns the manifest.
    The video is rendered from `scene_path` (or the world that differs from it); with
    `config.city` the manifest names the sample site's LoD2 city model instead (the stadium's
    layout: meant for the sample site)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(config.seed)
    e = config.errors
    if config.flight not in FLIGHT_OF:
        raise ValueError(f"flight {config.flight!r}: expected one of {', '.join(FLIGHT_OF)}")
    flight = FLIGHT_OF[config.flight]
    motion = device_motion(flight)
    frame = LocalFrame(*SITE_ORIGIN)
    t0 = START_UNIX_S
    span = (t0 - 2.0, t0 + config.duration_s + 2.0)

    def rel(t: np.ndarray) -> np.ndarray:
        return t - t0

    tg = sensors.callback_clock(*span, 100.0, e, rng)
    _csv(
        out / "gyr.csv",
        ["t", "x", "y", "z"],
        [tg, sensors.gyroscope(tg, body_rates(motion, rel(tg)), e, rng)],
    )
    ta = sensors.callback_clock(*span, 100.0, e, rng)
    _csv(
        out / "acc.csv",
        ["t", "x", "y", "z"],
        [ta, sensors.accelerometer(ta, specific_force(motion, rel(ta)), e, rng)],
    )
    tm = sensors.callback_clock(*span, 50.0, e, rng)
    qm = motion.attitude(rel(tm))
    field = field_enu(*SITE_ORIGIN, t0)
    _csv(
        out / "mag.csv",
        ["t", "x", "y", "z"],
        [tm, sensors.magnetometer(qm, field, _disturbance(motion.position(rel(tm)), e), e, rng)],
    )
    to = sensors.callback_clock(*span, 50.0, e, rng)
    q_phone = sensors.phone_orientation(to, motion.attitude(rel(to)), e, rng)
    _csv(out / "phone_orientation.csv", ["t", "qw", "qx", "qy", "qz"], [to, q_phone])

    tf = np.arange(np.ceil(span[0]), span[1], 1.0)
    p_true = motion.position(rel(tf))
    err = np.column_stack(
        [
            sensors.gauss_markov(tf, e.gnss_sigma_h_m, e.gnss_tau_s, rng, 2),
            sensors.gauss_markov(tf, e.gnss_sigma_v_m, e.gnss_tau_s, rng),
        ]
    )
    llh = frame.enu_to_geodetic(p_true + err)
    v = (motion.position(rel(tf) + 0.05) - motion.position(rel(tf) - 0.05)) / 0.1 + rng.normal(
        0, e.gnss_speed_sigma, (len(tf), 3)
    )
    speed = np.hypot(v[:, 0], v[:, 1])
    bearing = np.degrees(np.arctan2(v[:, 0], v[:, 1])) % 360.0
    _csv(
        out / "gnss.csv",
        ["t", "lat", "lon", "h", "speed", "bearing", "h_acc"],
        [tf, llh[:, 0], llh[:, 1], llh[:, 2], speed, bearing, np.full(len(tf), e.gnss_sigma_h_m)],
        [TIME_FMT, DEGREE_FMT, DEGREE_FMT, "%.3f", "%.3f", "%.2f", "%.1f"],
    )

    tt = np.arange(span[0], span[1], 0.01)
    _csv(
        out / "truth_orientation.csv", ["t", "qw", "qx", "qy", "qz"], [tt, motion.attitude(rel(tt))]
    )
    llh_true = frame.enu_to_geodetic(motion.position(rel(tt)))
    _csv(
        out / "truth_position.csv",
        ["t", "lat", "lon", "h"],
        [tt, llh_true[:, 0], llh_true[:, 1], llh_true[:, 2]],
        [TIME_FMT, DEGREE_FMT, DEGREE_FMT, "%.4f"],
    )

    n = int(config.duration_s * FPS)
    pts = np.arange(n) / FPS + np.concatenate([[0.0], rng.uniform(-0.003, 0.003, n - 1)])
    _csv(out / "truth_frames.csv", ["frame", "t"], [np.arange(n), t0 + pts], ["%d", TIME_FMT])
    if config.render_video:
        render_frames(out / "clip.mp4", scene_path, pts, config.crf, config.world, flight)
    if config.city:
        buildings, relief, crs = site_buildings(frame)
        write_cityjson(out / CITY_NAME, buildings, crs, relief=relief)
        scene_rel, up_axis = Path(CITY_NAME), ""
    else:
        scene_rel, up_axis = Path(scene_path).resolve(), '\nup_axis = "Y"'
        try:
            scene_rel = scene_rel.relative_to(out.resolve())
        except ValueError:
            pass
    manifest = out / "session.toml"
    manifest.write_text(
        MANIFEST.format(
            scene=scene_rel.as_posix(),
            up_axis=up_axis,
            origin=SITE_ORIGIN,
            start=t0 + SYNC_ERROR_S,
            hfov=HFOV_DEG,
            sync=SYNC_ERROR_S * 1000,
            what=WHAT[flight.name],
            height=AIRCRAFT_HEIGHT if flight.aircraft else PHONE_HEIGHT,
        )
    )
    return manifest


WHAT = {
    "walk": "a phone filming the sample stadium while its owner walks past it",
    "survey": "a drone surveying the sample site at 70 m, its camera looking down",
    "orbit": "a drone circling the sample stadium at 60 m, its camera on the hall",
}
PHONE_HEIGHT = """height = "ground"             # phone GNSS heights are metres off; the model's ground is not
mount_height_m = 1.45"""
AIRCRAFT_HEIGHT = (
    """height = "gnss"               # the aircraft's own height (not the ground's plus a mount)"""
)

MANIFEST = """# geofuse sample session: {what}.
# Generated by `geofuse simulate session` (app/simulate/session.py); the [truth] files are what a
# real session would not have.

[scene]
path = "{scene}"
origin = [{origin[0]}, {origin[1]}, {origin[2]}]{up_axis}

[video]
path = "clip.mp4"
start_time = {start:.3f}    # from the file's timestamp: {sync:.0f} ms late (see truth_frames.csv)
time_offset_s = 0.0

[camera]
hfov_deg = {hfov}

[sensors]
format = "csv"
acc = "acc.csv"
gyr = "gyr.csv"
mag = "mag.csv"
orientation = "phone_orientation.csv"

[gnss]
path = "gnss.csv"
{height}

[truth]
orientation = "truth_orientation.csv"
position = "truth_position.csv"
frame_times = "truth_frames.csv"
"""


def render_frames(
    path: Path,
    scene_path: str | Path,
    pts: np.ndarray,
    crf: int,
    world: bool = True,
    flight: Flight = WALK,
) -> Path:
    """Render the video from the true camera poses with the project's renderer, extras included;
    with `world`, from the world that differs from the model (app.simulate.world)."""
    base = load_scene(scene_path, LocalFrame(*SITE_ORIGIN))
    seen = world_of(base) if world else None
    mesh = MeshData((seen.mesh if seen else base).primitives + extras())
    first_mover = len(mesh.primitives) - len(MOVERS)

    def move(renderer, k: int) -> None:
        for i, m in enumerate(MOVERS):
            renderer.scene.update_positions(
                first_mover + i, _mover_vertices(m, float(pts[k])).astype(np.float32)
            )

    w, h = VIDEO_SIZE
    intr = Intrinsics.from_fov(w, h, HFOV_DEG)
    light, effects = (seen.light_dir, seen.camera) if seen else (None, None)
    return render_video(
        path,
        mesh,
        intr,
        flight.position(pts),
        camera_attitude(pts, flight),
        pts,
        rotation_cw(flight),
        crf,
        "2025-11-15T09:46:40Z",
        move,
        light,
        effects,
    )


def quick_config(duration_s: float = 8.0) -> SampleConfig:
    """A short session for tests (same generator, fewer seconds)."""
    return replace(SampleConfig(), duration_s=duration_s)
