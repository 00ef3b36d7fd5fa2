"""Drone downlinks whose GNSS lies (issue 52, live): the sample site seen from a flight, as an
H.264 MPEG-TS with a MISB ST 0601 set per frame whose position is the camera's own, plus GNSS
noise if given, falsified by a lie (app.simulate.lies.Lie: a jump, a drag-off, a frozen fix,
...). Several lies of one flight share its frames: the scene is rendered once (for the first),
the others encoded again from those frames with their own KLV. For tests/test_live_gnss.py and
`bench/bench_gnss_lies.py --live`.

The flight is app.simulate.drone's weave (its camera pitched drone.PITCH_DEG) or any
app.simulate.flights.Flight; times are seconds from the flight's start (the stream's first
frame), positions ENU metres of the site (app.simulate.stadium.SITE_ORIGIN). The sets carry
UTC from app.simulate.drone.START and the site's ground height as their frame centre's.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from app.camera.intrinsics import Intrinsics
from app.geodesy import rotations
from app.geodesy.enu import LocalFrame
from app.io.misb import camera_set
from app.scene import load_scene
from app.scene.layers import Layer
from app.scene.loader import Placement
from app.simulate import drone
from app.simulate.flights import Flight
from app.simulate.lies import Lie
from app.simulate.phone import write_video
from app.simulate.sample import SAMPLE_DIR
from app.simulate.stadium import SITE_ORIGIN
from app.simulate.video import render_video

SITE = LocalFrame(*SITE_ORIGIN)
FOG_GREY = 170  # a fogged frame's every pixel (no texture to match)


def sample_layer() -> Layer:
    """The textured sample model placed at the site: the scene a downlink is registered on."""
    return Layer.of(SAMPLE_DIR / "scene.glb", placement=Placement(origin=SITE_ORIGIN))


def path_of(flight: Flight | None, t: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3) ENU m of the site, heading/pitch/roll (N, 3) deg of the optical axis)
    at times t (N,) s of `flight` (None: app.simulate.drone's weave)."""
    t = np.asarray(t, np.float64)
    if flight is None:
        pos, heading = drone.flight(t)
        return pos, np.column_stack([heading, np.full(len(t), drone.PITCH_DEG), np.zeros(len(t))])
    return flight.position(t), flight.hpr(t)


def lying_sets(
    lie: Lie, t: np.ndarray, pos: np.ndarray, hpr: np.ndarray, hfov_deg: float
) -> list[tuple[float, bytes]]:
    """A Local Set per time t (N,) s: the camera's angles hpr (N, 3) deg and field of view, its
    position pos (N, 3) ENU m as the lie says it (none inside an outage)."""
    geo = SITE.enu_to_geodetic(lie.apply(t, pos))
    start = drone.START.timestamp()
    sent = ~lie.inside(t) if lie.kind == "outage" else np.ones(len(t), bool)
    return [
        (float(t[k]), camera_set(start + t[k], tuple(geo[k]), tuple(hpr[k]), hfov_deg, SITE_ORIGIN[2]))
        for k in np.flatnonzero(sent)
    ]  # fmt: skip


def write_downlinks(
    folder: Path,
    lies: Sequence[tuple[Lie, float]],
    size: tuple[int, int] = (480, 270),
    flight: Flight | None = None,
    noise_enu: npt.ArrayLike | None = None,
    hfov_deg: float = drone.HFOV_DEG,
    crf: int = 20,
    fog_s: tuple[float, float] | None = None,
) -> list[Path]:
    """One .ts per (lie, seconds) in `folder` (named by position and kind), each the flight's
    first `seconds` at drone.FPS, `size` (w, h) pixels; noise_enu (N, 3) m: GNSS error added to
    every frame's position before the lie (N: the longest feed's frames; None: none); fog_s:
    (from, to) s of video drawn grey (what sky, fog or a featureless field give a matcher)."""
    longest = max(seconds for _, seconds in lies)
    t = np.arange(0.0, longest, 1.0 / drone.FPS)
    pos, hpr = path_of(flight, t)
    noisy = pos if noise_enu is None else pos + np.asarray(noise_enu, np.float64)[: len(t)]
    q = rotations.camera_quat_from_hpr(hpr[:, 0], hpr[:, 1], hpr[:, 2])
    frames = np.lib.format.open_memmap(
        folder / "frames.npy", "w+", np.uint8, (len(t), size[1], size[0], 3)
    )

    def keep(rgb: np.ndarray, k: int) -> np.ndarray:
        if fog_s is not None and fog_s[0] <= t[k] < fog_s[1]:
            rgb = np.full_like(rgb, FOG_GREY)
        frames[k] = rgb
        return rgb

    mesh = load_scene(SAMPLE_DIR / "scene.glb", SITE)
    intr = Intrinsics.from_fov(*size, hfov_deg)
    order = sorted(range(len(lies)), key=lambda i: -lies[i][1])  # the longest rendered first
    paths: list[Path] = [Path()] * len(lies)
    for n, i in enumerate(order):
        lie, seconds = lies[i]
        k = int(np.searchsorted(t, seconds - 1e-9))
        path = folder / f"{i}-{lie.kind}.ts"
        klv = lying_sets(lie, t[:k], noisy[:k], hpr[:k], hfov_deg)
        if n == 0:
            render_video(path, mesh, intr, pos[:k], q[:k], t[:k], crf=crf, after_frame=keep, klv=klv)  # fmt: skip
        else:
            write_video(path, t[:k], size, 0, frame=lambda j: frames[j], crf=crf, klv=klv)
        paths[i] = path
    (folder / "frames.npy").unlink()
    return paths
