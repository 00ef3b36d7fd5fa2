"""A phone filming while it moves, simulated from a known trajectory: sensor logs as a phone
delivers them (each stream on its own jittered clock), GNSS fixes, the truth, a small video with
real presentation timestamps and a display rotation, and the session manifest.

This is the core the sample-session generator builds on; noise is off unless asked for.
"""

from __future__ import annotations

import fractions
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np

from app.geodesy import rotations
from app.geodesy.enu import LocalFrame

G = 9.80665
# A plausible field near 34.8 N 113.5 E (uT, ENU): north 33, east -3 (declination ~ -5 deg), down 42.
DEFAULT_FIELD_ENU = np.array([-3.1, 33.0, -42.0])


@dataclass(frozen=True)
class Motion:
    """position(t) -> (N, 3) ENU m and attitude(t) -> (N, 4) device -> ENU, for t (N,) seconds."""

    position: Callable[[np.ndarray], np.ndarray]
    attitude: Callable[[np.ndarray], np.ndarray]


def walking_pan(speed: float = 1.4, heading_amp: float = 25.0, pitch_amp: float = 6.0) -> Motion:
    """Walk east at `speed` m/s, phone upright in portrait facing north, panning left-right and
    nodding; camera heading 0 +- heading_amp, pitch +- pitch_amp (deg)."""

    def position(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            [speed * t, 2.0 * np.sin(0.2 * t), 1.5 + 0.03 * np.sin(2 * np.pi * 1.8 * t)]
        )

    def attitude(t: np.ndarray) -> np.ndarray:
        return rotations.camera_quat_from_hpr(
            heading_amp * np.sin(0.35 * t), pitch_amp * np.sin(0.6 * t), 3.0 * np.sin(0.9 * t)
        )

    return Motion(position, attitude)


def jittered_clock(
    t0: float, t1: float, rate: float, jitter: float, rng: np.random.Generator
) -> np.ndarray:
    """Sample times from t0 to t1 at `rate` Hz with uniform jitter of +-jitter/rate, increasing."""
    n = int((t1 - t0) * rate)
    t = t0 + np.arange(n) / rate + rng.uniform(-jitter, jitter, n) / rate
    return np.maximum.accumulate(t + np.arange(n) * 1e-9)


def body_rates(motion: Motion, t: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Device-frame angular rate (rad/s) at t from the attitude by central differences."""
    qa, qb = motion.attitude(t - h), motion.attitude(t + h)
    d = rotations.multiply(rotations.conjugate(qa), qb)
    return rotations.to_scipy(d).as_rotvec() / (2 * h)


def specific_force(motion: Motion, t: np.ndarray, h: float = 1e-3) -> np.ndarray:
    """Accelerometer (m/s^2, device frame): the world acceleration plus g up, seen by the device."""
    acc = (motion.position(t + h) - 2 * motion.position(t) + motion.position(t - h)) / (h * h)
    return rotations.rotate(rotations.conjugate(motion.attitude(t)), acc + [0.0, 0.0, G])


def write_csv(path: Path, header: list[str], columns: list[np.ndarray]) -> Path:
    data = np.column_stack(columns)
    np.savetxt(path, data, delimiter=",", header=",".join(header), comments="", fmt="%.9f")
    return path


def bar_frame(k: int, size: tuple[int, int]) -> np.ndarray:
    """A test frame (H, W, 3) whose yellow bar's position encodes k (mod 8)."""
    w, h = size
    img = np.full((h, w, 3), 40, np.uint8)
    x = int((k % 8) * w / 8)
    img[:, x : x + max(1, w // 8)] = (230, 200, 40)
    return img


def write_video(
    path: Path,
    times: np.ndarray,
    size: tuple[int, int],
    rotation_cw: int,
    creation_time: str | None = None,
    frame: Callable[[int], np.ndarray] | None = None,
    crf: int = 18,
    klv: Sequence[tuple[float, bytes]] = (),
    more_klv: Sequence[Sequence[tuple[float, bytes]]] = (),
) -> Path:
    """An H.264 video (MP4, or MPEG-TS for a .ts path) whose frames carry the given presentation
    times (s) and display rotation.

    size: the stored (coded) width and height; frame(k) returns frame k as a player displays it
    (turned by rotation_cw); by default `bar_frame`. Frames are stored turned back by rotation_cw.
    klv: (time s, payload) packets of a KLV data stream muxed beside the video at their own
    presentation times (a set per frame, or their own rate); more_klv: further KLV streams'
    packets, each its own data stream after the first.
    """

    w, h = size
    display = (h, w) if rotation_cw % 180 else (w, h)
    frame = frame or (lambda k: bar_frame(k, display))
    each = [list(klv), *map(list, more_klv)] if klv else [list(p) for p in more_klv]
    pending = sorted(
        ((t, k, payload) for k, packets in enumerate(each) for t, payload in packets),
        key=lambda p: (p[0], p[1]),
    )
    tb = fractions.Fraction(1, 90000)
    with av.open(str(path), "w") as c:
        if creation_time:
            c.metadata["creation_time"] = creation_time
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.time_base = tb
        s.codec_context.time_base = s.time_base  # keep real presentation times (variable rate)
        s.codec_context.options = {"preset": "veryfast", "crf": str(crf), "bf": "0"}
        if Path(path).suffix.lower() == ".ts":  # a broadcast stream: a keyframe every second
            s.codec_context.options = {**s.codec_context.options, "g": "30"}
        if rotation_cw:
            s.set_display_rotation(-rotation_cw)  # FFmpeg's display matrix turns counter-clockwise
        data = [c.add_data_stream("klv") for _ in each]

        def mux_klv(until_s: float) -> None:
            while pending and pending[0][0] <= until_s:
                t, which, payload = pending.pop(0)
                k = av.Packet(payload)
                k.stream, k.time_base = data[which], tb
                k.pts = k.dts = int(round(t * 90000))
                c.mux(k)

        for k, ts in enumerate(times):
            mux_klv(ts)
            stored = np.ascontiguousarray(np.rot90(frame(k), k=(rotation_cw // 90) % 4))
            f = av.VideoFrame.from_ndarray(stored, format="rgb24")
            f.pts = int(round(ts * 90000))
            f.time_base = s.time_base
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
        mux_klv(math.inf)
    return path


def write_session(
    out: str | Path,
    motion: Motion,
    duration_s: float = 20.0,
    origin: tuple[float, float, float] = (34.80, 113.53, 110.0),
    start_unix_s: float = 1_700_000_000.0,
    scene: str | Path | None = None,
    video_size: tuple[int, int] = (64, 36),
    rotation_cw: int = 90,
    with_mag: bool = True,
    field_enu: np.ndarray = DEFAULT_FIELD_ENU,
    seed: int = 1,
) -> Path:
    """Write a noise-free phone session into folder `out`; returns the manifest's path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    frame = LocalFrame(*origin)
    t0 = start_unix_s
    # The sensors start a little before the video and stop after it, like a logging app.
    span = (t0 - 1.0, t0 + duration_s + 1.0)

    def rel(t: np.ndarray) -> np.ndarray:
        return t - t0

    tg = jittered_clock(*span, 100.0, 0.2, rng)
    write_csv(out / "gyr.csv", ["t", "x", "y", "z"], [tg, body_rates(motion, rel(tg))])
    ta = jittered_clock(*span, 100.0, 0.2, rng)
    write_csv(out / "acc.csv", ["t", "x", "y", "z"], [ta, specific_force(motion, rel(ta))])
    if with_mag:
        tm = jittered_clock(*span, 50.0, 0.2, rng)
        write_csv(
            out / "mag.csv",
            ["t", "x", "y", "z"],
            [
                tm,
                rotations.rotate(
                    rotations.conjugate(motion.attitude(rel(tm))), np.tile(field_enu, (len(tm), 1))
                ),
            ],
        )
    tq = np.arange(span[0], span[1], 0.01)
    write_csv(out / "truth.csv", ["t", "qw", "qx", "qy", "qz"], [tq, motion.attitude(rel(tq))])
    tf = np.arange(np.ceil(span[0]), span[1], 1.0)
    p = motion.position(rel(tf))
    v = (motion.position(rel(tf) + 1e-3) - motion.position(rel(tf) - 1e-3)) / 2e-3
    llh = frame.enu_to_geodetic(p)
    write_csv(
        out / "gnss.csv",
        ["t", "lat", "lon", "h", "vel_e", "vel_n", "vel_u"],
        [tf, llh[:, 0], llh[:, 1], llh[:, 2], v[:, 0], v[:, 1], v[:, 2]],
    )
    n_frames = int(duration_s * 30)
    pts = np.arange(n_frames) / 30.0 + np.concatenate(
        [[0.0], rng.uniform(-0.002, 0.002, n_frames - 1)]
    )
    write_video(out / "clip.mp4", pts, video_size, rotation_cw)
    scene_line = f'path = "{Path(scene).resolve()}"' if scene else 'path = "scene.obj"'
    if not scene:
        (out / "scene.obj").write_text(
            "v -100 -100 0\nv 100 -100 0\nv 100 100 0\nv -100 100 0\nf 1 2 3\nf 1 3 4\n"
        )
    mag_line = 'mag = "mag.csv"\n' if with_mag else ""
    manifest = out / "session.toml"
    manifest.write_text(
        f"""# simulated phone session (geofuse.simulate.phone)
[origin]
lat = {origin[0]}
lon = {origin[1]}
h = {origin[2]}

[scene]
{scene_line}
origin = [{origin[0]}, {origin[1]}, {origin[2]}]

[video]
path = "clip.mp4"
start_time = {t0}

[camera]
hfov_deg = 60.0

[sensors]
format = "csv"
acc = "acc.csv"
gyr = "gyr.csv"
{mag_line}
[gnss]
path = "gnss.csv"

[truth]
orientation = "truth.csv"
"""
    )
    return manifest
