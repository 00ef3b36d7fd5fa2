"""Cold start without GNSS (issue 52): from an area alone, how often the first pose is found
and in what time.

    python bench/bench_cold_start.py [--flights orbit survey] [--seeds 1 2] [--starts 5]
        [--radii 300 1000] [--height-error 5] [--duration 20] [--perspective] [--json out.json]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from its model) and every GNSS fix removed (app.simulate.lies `outage`).
Each start: a clip time (`--starts` of them spread over the clip), an area of each radius whose
centre lies off the true position by a distance drawn uniformly over the disc (a direction and
r = radius sqrt(u)), and the platform's height given with an error drawn uniformly within
+-height_error metres; the search (app.register.coldstart.search_start, the attitude from the
`offline` filter, the frames from that clip time on) runs on one registrar per session, as
`geofuse solve --near` runs it. Figures per start: found or why not, the method, the frame's
clip time, the found pose against the truth at that frame: the drape's error (the median
distance between where the two put the same pixels on the site's ground plane, a 9 x 9 grid
over the image, within 300 m), the camera's position error (m) and its attitude's (deg); the
search's time (s: from the start of the search to the first registered pose, the session
already open and the attitude filter compiled; say the machine's load), views rendered. Per
flight and radius: found with the drape within --tolerance (default 0.75 m: registration's
p95 at the image's centre on the sample, docs/ACCURACY.md "Registration"), found beyond it,
and the time's median and worst. --perspective: nadir views searched on the perspective grid
too (the top-down correlation's alternative, for the comparison in docs/ACCURACY.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.pinhole import Camera  # noqa: E402
from app.geodesy import rotations  # noqa: E402
from app.io.video import frames_at  # noqa: E402
from app.register.coldstart import SearchSettings, attitude_track, search_start  # noqa: E402
from app.register.keyframe import posed  # noqa: E402
from app.register.solve import Registrar, RegistrationSettings  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.start import StartArea  # noqa: E402
from app.simulate import session as sample  # noqa: E402
from app.simulate.flights import ORBIT_HEIGHT_M, SURVEY_HEIGHT_M  # noqa: E402
from app.simulate.lies import Lie, falsify  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.solve.accuracy import true_track  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402

HEIGHT = {"orbit": ORBIT_HEIGHT_M, "survey": SURVEY_HEIGHT_M}  # above the site's ground (z = 0)


def simulate(out: Path, flight: str, seed: int, duration_s: float) -> Path:
    """A simulated session with every fix removed; its manifest."""
    config = replace(sample.quick_config(duration_s), flight=flight, seed=seed)
    sample.write_sample_session(out / "clean", SAMPLE_SCENE, config)
    return falsify(out / "clean", out / "no-gnss", Lie("outage", -1e6))


def starts(seed: int, count: int, duration_s: float, radius: float, height_error: float):
    """(clip time s, offset east, north m, height error m) of each start."""
    rng = np.random.default_rng(1000 * seed + int(radius))
    last = max(0.0, duration_s - 4.0)
    for t in np.linspace(0.0, last, count):
        a, r = rng.uniform(0, 2 * np.pi), radius * np.sqrt(rng.uniform())
        yield float(t), r * np.cos(a), r * np.sin(a), rng.uniform(-height_error, height_error)


def run_start(session, registrar, truth, flight, t_s, de, dn, dh, radius, settings):
    """One start's figures (a dict)."""
    p0 = truth.camera_at(t_s).position
    lat, lon, _ = session.frame.enu_to_geodetic(np.array([p0[0] + de, p0[1] + dn, 0.0]))
    area = StartArea.near(lat, lon, radius, HEIGHT[flight] + dh)
    s = replace(session, start=area)
    tries = tuple(t_s + d for d in settings.tries)
    found = search_start(
        s,
        "offline",
        registrar.views,
        lambda rgb, start: registrar.keyframe(rgb, start)[:2],
        lambda wanted: frames_at(s.video, wanted, registrar.settings.long_side),
        replace(settings, tries=tries),
    )
    row = {
        "flight": flight, "radius_m": radius, "t_s": t_s, "off_m": float(np.hypot(de, dn)),
        "height_error_m": dh, "found": found.ok, "why": found.reason, "method": found.method,
        "seconds": found.seconds, "views": found.views, "searched_km2": found.searched_m2 / 1e6,
    }  # fmt: skip
    if found.ok:
        media = float(session.video.pts_s[found.index])
        true = truth.camera_at(media)
        d = np.asarray(found.position) - np.asarray(true.position)
        row |= {
            "frame_s": media, "error_h_m": float(np.hypot(d[0], d[1])), "error_m": float(np.linalg.norm(d)),
            "error_deg": float(np.degrees(rotations.angle_between(found.q, true.orientation))),
            "drape_m": drape_m(true, posed(true, found.position, found.q)),
            "position": [float(v) for v in found.position], "q": [float(v) for v in found.q],
        }  # fmt: skip
    return row


def drape_m(true: Camera, found: Camera, ground_z: float = 0.0, reach_m: float = 300.0) -> float:
    """The median distance (m) between where the true and the found camera put the same pixels
    on the site's ground plane (z = ground_z): a 9 x 9 grid over the image, the pixels whose
    rays meet it within reach_m under both."""
    i = true.intrinsics
    u, v = np.meshgrid(np.linspace(0.5, i.width - 0.5, 9), np.linspace(0.5, i.height - 0.5, 9))
    uv = np.column_stack([u.ravel(), v.ravel()])
    hits = []
    for cam in (true, found):
        rays = cam.pixel_rays(uv)
        eye = np.asarray(cam.position)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(rays[:, 2] < 0, (ground_z - eye[2]) / rays[:, 2], np.inf)
        hits.append(eye + rays * t[:, None])
    ok = np.all(np.isfinite(hits[0]), axis=1) & np.all(np.isfinite(hits[1]), axis=1)
    ok &= np.linalg.norm(hits[0][:, :2] - np.asarray(true.position)[:2], axis=1) <= reach_m
    return float(np.median(np.linalg.norm(hits[0][ok] - hits[1][ok], axis=1)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--starts", type=int, default=5, help="starts per session and radius")
    parser.add_argument("--radii", nargs="+", type=float, default=[300.0, 1000.0])
    parser.add_argument("--height-error", type=float, default=5.0, help="metres, +- uniform")
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument(
        "--tolerance",
        type=float,
        default=0.75,
        help="metres: found where the drape is within this (registration's p95 on the sample)",
    )
    parser.add_argument("--perspective", action="store_true")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    print(f"# {machine()}, load {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    rows: list[dict] = []
    variants = [("", SearchSettings())]
    if args.perspective:
        variants.append((" (perspective)", SearchSettings(nadir_within_deg=-1.0)))
    with tempfile.TemporaryDirectory(prefix="bench-cold-start-") as tmp:
        for flight in args.flights:
            for seed in args.seeds:
                manifest = simulate(Path(tmp) / f"{flight}-{seed}", flight, seed, args.duration)
                session = open_session(manifest)
                truth = true_track(session)
                attitude_track(session, "offline", np.zeros(2), 1.0)  # the filter compiled first
                registrar = Registrar(session, RegistrationSettings())
                try:
                    for radius in args.radii:
                        for t_s, de, dn, dh in starts(
                            seed, args.starts, args.duration, radius, args.height_error
                        ):
                            for name, settings in variants:
                                if name and flight != "survey":
                                    continue
                                row = run_start(
                                    session, registrar, truth, flight, t_s, de, dn, dh, radius, settings
                                )  # fmt: skip
                                row |= {"seed": seed, "variant": name}
                                rows.append(row)
                                print(_line(row), flush=True)
                finally:
                    registrar.release()
    print(f"# load after {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print(_summary(rows, args.tolerance))
    if args.json is not None:
        write_json(args.json, {"machine": machine(), "rows": rows})
    return 0


def _line(r: dict) -> str:
    what = (
        f"found at t = {r['frame_s']:.1f} s, drape {r['drape_m']:.2f} m, camera {r['error_m']:.2f} m, {r['error_deg']:.2f} deg"
        if r["found"]
        else f"not found: {r['why']}"
    )
    return (
        f"{r['flight']}{r['variant']} seed {r['seed']} radius {r['radius_m']:g} m, t = {r['t_s']:.1f} s, "
        f"{r['off_m']:.0f} m off, height {r['height_error_m']:+.1f} m: {what}; {r['method']}, "
        f"{r['views']} views, {r['seconds']:.1f} s"
    )


def _summary(rows: list[dict], tolerance: float) -> str:
    out = []
    keys = sorted({(r["flight"] + r["variant"], r["radius_m"]) for r in rows})
    for name, radius in keys:
        rs = [r for r in rows if r["flight"] + r["variant"] == name and r["radius_m"] == radius]
        ok = [r for r in rs if r["found"] and r["drape_m"] <= tolerance]
        wrong = [r for r in rs if r["found"] and r["drape_m"] > tolerance]
        secs = np.array([r["seconds"] for r in rs])
        found_secs = np.array([r["seconds"] for r in ok]) if ok else np.array([np.nan])
        errs = np.array([r["error_m"] for r in ok]) if ok else np.array([np.nan])
        drapes = np.array([r["drape_m"] for r in ok]) if ok else np.array([np.nan])
        out.append([
            name, f"{radius:g}", f"{len(ok)} of {len(rs)}", len(wrong),
            f"{np.median(drapes):.2f} / {np.max(drapes):.2f}",
            f"{np.median(errs):.2f} / {np.max(errs):.2f}",
            f"{np.median(found_secs):.1f} / {np.max(found_secs):.1f}", f"{np.max(secs):.1f}",
            f"{np.median([r['views'] for r in rs]):.0f}",
        ])  # fmt: skip
    return table(
        ["flight", "radius (m)", f"found within {tolerance:g} m", "found wrong", "drape error (m), median / max", "camera position error (m), median / max", "time to the first pose (s), median / max", "longest search (s)", "views (median)"],
        out,
    )  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
