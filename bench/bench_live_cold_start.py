"""Live cold start from a MAVLink home point (issue 52): a drone whose GNSS is jammed from the
start, its video (no KLV) and its autopilot's MAVLink (GLOBAL_POSITION_INT at 0, 0 with the
barometer's height above home, HOME_POSITION, ATTITUDE, the gimbal's) sent over the loopback in
real time (not lockstep: the search's time is what is measured) to `geofuse live`'s pipeline,
registered against the textured sample model.

    python bench/bench_live_cold_start.py [--homes 5] [--radius 250] [--seconds 20]
        [--size 640x360] [--seed 1] [--lost-at S] [--json out.json]

--lost-at S: the fixes are sent until flight time S and lost then (jammed in flight) instead:
each run's figures are the drawn error from a second after S on, the largest in the second
after S, the frames marked `missing` after S, and whether any lie was said.

Each run: the home point drawn uniformly over a disc of --radius metres around where the
video's flight begins (app.simulate.drone's weave; the search covers 300 m around the home).
Figures per run: the home's distance from the flight's start; whether the camera was found and
when (media s of the first frame drawn, and the wall time from the stream's first frame to it);
frames received without a pose (before it); keyframes registered of those tried; the drawn
position's error against the flight (median, p95, max, m) from the first frame drawn and from a
second after it, and the attitude's (median, deg). Say the machine's load.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.geodesy import rotations  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.live.run import LiveOptions, run_flown  # noqa: E402
from app.simulate import drone  # noqa: E402
from app.simulate.downlink import sample_layer  # noqa: E402
from app.simulate.stadium import SITE_ORIGIN  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402

SITE = LocalFrame(*SITE_ORIGIN)


def one_run(
    video: Path, home_enu: tuple[float, float], seconds: float, lost_at: float | None = None
) -> dict:
    """One jammed flight (from the start, or from lost_at s) sent and received in real time; its
    figures."""
    drawn = []
    options = LiveOptions(
        silence_s=2.0, size=(640, 360), layers=(sample_layer(),), hfov_deg=drone.HFOV_DEG
    )
    run = run_flown(
        video, options, seconds, lambda d, c: drawn.append((d, c)), fixed=lost_at is not None,
        home=lost_at is None, home_enu=home_enu, lost_at_s=lost_at,
    )  # fmt: skip
    start, _ = drone.flight(np.array([0.0]))
    out = {
        "home_m": float(np.hypot(*(np.asarray(home_enu) - start[0, :2]))),
        "found": bool(drawn),
        "without_pose": run.without_pose,
        "registered": run.registration.registered if run.registration else 0,
        "tried": run.registration.tried if run.registration else 0,
    }
    if not drawn:
        return out
    first = drawn[0][0]
    errors, statuses = [], []
    for d, cam in drawn:
        t = d.pts_s + run.origin_s  # the stream starts at flight time 0
        pos, heading = drone.flight(np.array([t]))
        want = run.frame.geodetic_to_enu(*SITE.enu_to_geodetic(pos).T)[0]
        q = rotations.camera_quat_from_hpr(heading[0], drone.PITCH_DEG, 0.0)
        statuses.append(d.gnss)
        errors.append(
            (
                t,
                float(np.linalg.norm(np.asarray(cam.position) - want)),
                float(np.degrees(rotations.angle_between(np.asarray(cam.orientation), q))),
            )
        )
    e = np.array(errors)
    if lost_at is not None:
        after = e[:, 0] >= lost_at
        out.update(
            lies=len(run.gnss.lies) if run.gnss is not None else 0,
            missing=f"{sum(s == 'missing' for s, a in zip(statuses, after, strict=True) if a)} of {int(after.sum())}",
            onset_max_m=float(e[after & (e[:, 0] < lost_at + 1.0), 1].max()),
            median_m=float(np.median(e[e[:, 0] >= lost_at + 1.0, 1])),
            p95_m=float(np.percentile(e[e[:, 0] >= lost_at + 1.0, 1], 95)),
            max_m=float(e[e[:, 0] >= lost_at + 1.0, 1].max()),
            before_m=float(np.median(e[~after, 1])),
        )
        return out
    later = e[e[:, 0] >= e[0, 0] + 1.0, 1]
    out.update(
        first_s=first.pts_s,
        wait_s=first.drawn_s - (first.arrival_s - first.pts_s),
        drawn=len(drawn),
        median_m=float(np.median(e[:, 1])),
        p95_m=float(np.percentile(e[:, 1], 95)),
        max_m=float(e[:, 1].max()),
        later_max_m=float(later.max()) if len(later) else float("nan"),
        attitude_deg=float(np.median(e[:, 2])),
    )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--homes", type=int, default=5)
    parser.add_argument("--radius", type=float, default=250.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--lost-at", type=float, default=None, help="flight s: fixes lost then")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    rng = np.random.default_rng(args.seed)
    start, _ = drone.flight(np.array([0.0]))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        video = drone.write_video(Path(tmp) / "downlink.ts", args.seconds, size)
        for k in range(args.homes):
            r, a = args.radius * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
            home = (float(start[0, 0] + r * np.cos(a)), float(start[0, 1] + r * np.sin(a)))
            row = one_run(video, home, args.seconds, args.lost_at)
            rows.append(row)
            print(k, row, flush=True)
            if args.lost_at is not None and k + 1 >= args.homes:
                break

    def f(row: dict, key: str, spec: str) -> str:
        return format(row[key], spec) if key in row else "-"

    print(machine())
    if args.lost_at is not None:
        print(
            table(
                ["run", "drawn error before (m, median)", "largest in the second after", "error from 1 s after: median / p95 / max (m)",
                 "frames missing after", "lies said", "keyframes"],
                [[k + 1, f"{r['before_m']:.2f}", f"{r['onset_max_m']:.2f}",
                  f"{r['median_m']:.2f} / {r['p95_m']:.2f} / {r['max_m']:.2f}", r["missing"], r["lies"],
                  f"{r['registered']} of {r['tried']}"] for k, r in enumerate(rows)],
            )
        )  # fmt: skip
        return 0
    print(
        table(
            ["home from start (m)", "found", "first drawn (media s)", "wait (wall s)",
             "frames without pose", "keyframes", "error m: median / p95 / max",
             "max from 1 s after", "attitude (deg, median)"],
            [
                [f"{r['home_m']:.0f}", "yes" if r["found"] else "no", f(r, "first_s", ".2f"),
                 f(r, "wait_s", ".2f"), r["without_pose"], f"{r['registered']} of {r['tried']}",
                 f"{f(r, 'median_m', '.2f')} / {f(r, 'p95_m', '.2f')} / {f(r, 'max_m', '.2f')}",
                 f(r, "later_max_m", ".2f"), f(r, "attitude_deg", ".2f")]
                for r in rows
            ],
        )
    )  # fmt: skip
    if args.json is not None:
        write_json(args.json, {"runs": rows, "args": vars(args) | {"json": str(args.json)}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
