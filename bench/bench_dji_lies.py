"""A DJI clip's GNSS lying, with no IMU to tell: only the scene can (issue 52, a drone clip).

The simulated DJI weave (app.simulate.drone: 35 m up, eastward at 9 m/s along the sample site's
south side, --duration s, 640x360) is rendered once; its subtitle (gimbal angles, a fix per frame
as DJI writes it) is written per seed with the GNSS's own error (Gauss-Markov, --noise m per
axis, 30 s) and per case with a lie from --from-s (app.simulate.lies: a 200 m jump east,
drag-offs east at 1, 2 and 5 m/s, a frozen fix, a replay of 10 s before, or of --from-s less
2 s where that is less; `outage`: no fix, DJI's 0, 0, for 8 s; `multipath`: no lie, bursts that
pull the fixes 3-8 m off, which a DJI subtitle cannot say it is less sure of). Each case is solved as `registered` against the site written as a tileset, from
the clip and its subtitle alone (app.footage.clips.open_clip), and compared frame by frame with
the flight. DJI states no accuracy, so the checks assume CheckSettings.accuracy_m (5 m), or
what --gnss-accuracy states (the user's `--gnss-accuracy`); a lie's alarm delay counts from the
moment it exceeds that (as bench_gnss_lies does).

    python bench/bench_dji_lies.py --seeds 1 2 3
    python bench/bench_dji_lies.py --seeds 1 2 3 --gnss-accuracy 1.5

Figures per case: the lies said, when the first was caught and said to begin (clip s), the
alarm's delay, the share of frames marked rejected after the lie exceeds the accuracy (missing,
for the outage), frames marked rejected before the lie began (honest fixes accused), the position
error during the lie (median, p95) and the clean run's over the same frames, and the share of
those frames (all, for the clean and multipath runs) whose error lies within 1 and 2 of the
frame's sigma (app.solve.uncertainty.frame_sigmas: each axis's, so k sqrt(3) sigma in 3D).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.fixes import MISSING, REJECTED  # noqa: E402
from app.footage.clips import open_clip  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.register.gnss import CheckSettings  # noqa: E402
from app.scene.layers import Layer  # noqa: E402
from app.simulate import drone, sensors  # noqa: E402
from app.simulate.lies import Lie  # noqa: E402
from app.simulate.stadium import SITE_ORIGIN  # noqa: E402
from app.simulate.tileset import write_site  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from app.solve.uncertainty import frame_sigmas  # noqa: E402
from bench.bench_gnss_lies import LIES, exceeds_s, label, within  # noqa: E402
from bench.common import table, write_json  # noqa: E402

CASES = ("clean", "multipath", "jump", "drag1", "drag", "drag5", "frozen", "replay", "outage")
OUTAGE_S = 8.0
SIZE = (640, 360)


def subtitle(path: Path, duration_s: float, noise: np.ndarray, lie: Lie | None) -> Path:
    """Write the weave's subtitle: the flight plus `noise` (F, 3) m per frame, lied about by
    `lie` (an outage: its entries without a fix)."""

    def lying(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos, heading = drone.flight(t)
        k = np.clip(np.round(t * drone.FPS).astype(int), 0, len(noise) - 1)
        pos = pos + noise[k]
        if lie is not None and lie.kind != "outage":
            pos = lie.apply(t, pos)
        return pos, heading

    outage = None if lie is None or lie.kind != "outage" else (lie.from_s, lie.until_s)
    text = drone.srt_text(duration_s, 0.0, path_of=lying, gimbal=True, outage=outage)
    path.write_text(text, encoding="utf-8")
    return path


def solved(video: Path, srt: Path, site: Path, accuracy_m: float | None) -> dict:
    """The registered track of the clip with this subtitle (its fixes' accuracy accuracy_m, m,
    as --gnss-accuracy states it; None: none): per frame its clip time (s), true position (ENU
    m about the site origin), error (m), its sigma (m, each axis: app.solve.uncertainty), gnss
    status; the lies said."""
    session = open_clip(video, srt, layers=(Layer.of(site),))
    session = session.stating_accuracy(accuracy_m, "--gnss-accuracy")
    track = solve_track(session, "registered")
    poses = track.frame_poses()
    t0 = float(session.frame_times[0])
    t = poses.time_s - t0
    true, _ = drone.flight(t)
    got = LocalFrame(*SITE_ORIGIN).geodetic_to_enu(*poses.geodetic.T)
    lies = track.registration.gnss.lies if track.registration.gnss is not None else ()
    return {
        "t": t,
        "true": true,
        "error": np.linalg.norm(got - true, axis=1),
        "sigma": frame_sigmas(session, track, np.arange(len(t)))[0],
        "gnss": poses.gnss,
        "caught": [lie.caught_s - t0 for lie in lies],
        "began": [lie.began_s - t0 for lie in lies],
        "kinds": [lie.kind for lie in lies],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=24.0, help="s (the site ends at 24 s)")
    ap.add_argument("--from-s", type=float, default=8.0, help="the lie's start, clip s")
    ap.add_argument("--noise", type=float, default=1.5, help="the GNSS's own error, m per axis")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--gnss-accuracy", type=float, help="m: the fixes' accuracy, as stated")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args(argv)
    accuracy = args.gnss_accuracy or CheckSettings().accuracy_m
    rows, figures = [], []
    with tempfile.TemporaryDirectory(prefix="dji-lies-") as tmp:
        folder = Path(tmp)
        video = drone.write_video(folder / "DJI_0001.MP4", args.duration, SIZE)
        site = write_site(folder / "site")
        t_frames = np.arange(0.0, args.duration, 1.0 / drone.FPS)
        for seed in args.seeds:
            rng = np.random.default_rng(seed)
            noise = np.column_stack(
                [sensors.gauss_markov(t_frames, args.noise, 30.0, rng, 2), np.zeros(len(t_frames))]
            )
            noise[:, 2] = sensors.gauss_markov(t_frames, 2 * args.noise, 30.0, rng)[:, 0]
            done = {}
            for case in ["clean", *(c for c in args.cases if c != "clean")]:
                if case == "clean":
                    lie = None
                elif case == "multipath":
                    lie = Lie("multipath", -1e6, seed=seed)
                elif case == "outage":
                    lie = Lie("outage", args.from_s, until_s=args.from_s + OUTAGE_S)
                else:  # a replay of what came before the clip would replay its first fix
                    lie = replace(LIES[case], from_s=args.from_s)
                    lie = replace(lie, back_s=min(lie.back_s, args.from_s - 2.0))
                srt = subtitle(folder / f"{seed}-{case}.SRT", args.duration, noise, lie)
                got = done[case] = solved(video, srt, site, args.gnss_accuracy)
                t, err = got["t"], got["error"]
                before = int(np.sum((got["gnss"] == REJECTED) & (t < args.from_s - 0.5)))
                if lie is None or lie.kind == "multipath":
                    sure = (
                        f"{100 * within(got, t >= 0, 1):.0f} / {100 * within(got, t >= 0, 2):.0f} %"
                    )
                    rows.append([seed, case, len(got["caught"]), "", "", "", "", before, f"{np.median(err):.2f} / {np.percentile(err, 95):.2f}", "", sure])  # fmt: skip
                    figures.append({"seed": seed, "case": case, "alarms": len(got["caught"]), "rejected_before": before, "median_error_m": float(np.median(err))})  # fmt: skip
                    continue
                clean = done["clean"]
                if lie.kind == "outage":
                    after, marked, name = (t >= lie.from_s) & (t < lie.until_s), MISSING, f"outage {OUTAGE_S:g} s"  # fmt: skip
                    start = lie.from_s
                else:
                    start = exceeds_s(lie, accuracy, t, got["true"])
                    after, marked, name = t >= start, REJECTED, label(lie)
                near = [k for k, c in enumerate(got["caught"]) if c >= lie.from_s - 5.0]
                delay = None if not near or lie.kind == "outage" else got["caught"][near[0]] - start
                began = got["began"][near[0]] if near else None
                share = float(np.mean(got["gnss"][after] == marked))
                e, ref = err[after], clean["error"][after]
                sure = f"{100 * within(got, after, 1):.0f} / {100 * within(got, after, 2):.0f} %"
                rows.append([seed, name, len(got["caught"]), " ".join(got["kinds"]), "" if began is None else f"{began:.1f}", "" if lie.kind == "outage" else ("none" if delay is None else f"{delay:.1f}"), f"{100 * share:.0f} %", before, f"{np.median(e):.2f} / {np.percentile(e, 95):.2f}", f"{np.median(ref):.2f} / {np.percentile(ref, 95):.2f}", sure])  # fmt: skip
                figures.append({"seed": seed, "case": case, "alarms": len(got["caught"]), "kinds": got["kinds"], "began_s": began, "alarm_delay_s": delay, "marked_share": share, "rejected_before": before, "median_error_m": float(np.median(e)), "p95_error_m": float(np.percentile(e, 95)), "clean_median_error_m": float(np.median(ref))})  # fmt: skip
                print(f"seed {seed} {name}: done", file=sys.stderr, flush=True)
    stated = (
        f"stated {args.gnss_accuracy:g} m" if args.gnss_accuracy else "none stated: 5 m assumed"
    )
    print(f"# A DJI clip's GNSS lying, no IMU: {args.duration:g} s weave, lie from t = {args.from_s:g} s, GNSS error {args.noise:g} m, accuracy {stated}\n")  # fmt: skip
    print(table(["seed", "GNSS", "alarms", "named", "said from (s)", "alarm delay (s)", "marked after (rejected; outage: missing)", "rejected before the lie (frames)", "error during the lie, median / p95 (m)", "clean run's (m)", "error within 1 / 2 sigma"], rows))  # fmt: skip
    write_json(args.json, {"duration_s": args.duration, "from_s": args.from_s, "noise_m": args.noise, "accuracy_m": args.gnss_accuracy, "runs": figures})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
