"""GNSS that lies (issue 52): how fast the `registered` source catches a jump and a drag-off,
how much of the lie it rejects, and what the lie costs the camera's position.

    python bench/bench_gnss_lies.py [--flights orbit survey] [--seeds 1 2] [--duration 40]
        [--from-s 15] [--json out.json]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from the model), then copies of it with the GNSS falsified from --from-s
seconds (app.simulate.lies: a 200 m jump east, a 2 m/s drag-off east) are solved with the
`registered` source, and the clean session too. Figures per run: the alarm's delay (s) from the
moment the lie exceeds the fixes' stated accuracy (the jump's start; the drag's start plus
accuracy / speed), the share of frames after that moment marked `rejected`, the median camera
position error (m) against the truth over the frames after it, and the clean run's over the
same frames; for the clean run, lies said and frames rejected (false alarms).
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

from app.camera.fixes import REJECTED  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate import session as sample  # noqa: E402
from app.simulate.lies import Lie, falsify  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.solve.accuracy import true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from bench.common import table, write_json  # noqa: E402

LIES = (Lie("jump", size_m=200.0), Lie("drag", speed_mps=2.0))


def exceeds_s(lie: Lie, accuracy_m: float) -> float:
    """Clip seconds from which the lie is larger than the fixes' stated accuracy (m)."""
    return lie.from_s + (accuracy_m / lie.speed_mps if lie.kind == "drag" else 0.0)


def run(manifest: Path) -> dict:
    """The registered track of one session: per frame its clip time (s from the simulation's
    start), position error (m) against the truth and gnss status; the lies said."""
    session = open_session(manifest)
    track = solve_track(session, "registered")
    truth = true_track(session)
    frames = np.arange(track.frame_count)
    ours = track.poses_at(track.clock.media_s[frames], frames)
    true = truth.poses_at(truth.clock.media_s[frames])
    check = track.registration.gnss
    return {
        "t": ours.time_s - sample.START_UNIX_S,
        "error": np.linalg.norm(ours.enu - true.enu, axis=1),
        "gnss": ours.gnss,
        "caught": [lie.caught_s - sample.START_UNIX_S for lie in check.lies],
        "accuracy": float(np.median(session.gnss.h_acc)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--duration", type=float, default=40.0, help="seconds of video")
    parser.add_argument("--from-s", type=float, default=15.0, help="the lie begins (clip s)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    rows, figures = [], []
    with tempfile.TemporaryDirectory(prefix="gnss-lies-") as tmp:
        for flight in args.flights:
            for seed in args.seeds:
                base = Path(tmp) / f"{flight}-{seed}"
                config = replace(sample.quick_config(args.duration), flight=flight, seed=seed)
                sample.write_sample_session(base / "clean", SAMPLE_SCENE, config)
                clean = run(base / "clean" / "session.toml")
                rejected = int(np.sum(clean["gnss"] == REJECTED))
                rows.append([flight, seed, "clean", len(clean["caught"]), "", f"{rejected} frames", "", f"{np.median(clean['error']):.2f}"])  # fmt: skip
                figures.append({"flight": flight, "seed": seed, "lie": "clean", "alarms": len(clean["caught"]), "rejected_frames": rejected, "median_error_m": float(np.median(clean["error"]))})  # fmt: skip
                for lie in LIES:
                    lie = replace(lie, from_s=args.from_s)
                    got = run(falsify(base / "clean", base / lie.kind, lie))
                    start = exceeds_s(lie, got["accuracy"])
                    after = got["t"] >= start
                    delay = min((c - start for c in got["caught"] if c >= lie.from_s - 5.0), default=None)  # fmt: skip
                    share = float(np.mean(got["gnss"][after] == REJECTED))
                    err, ref = float(np.median(got["error"][after])), float(np.median(clean["error"][after]))  # fmt: skip
                    label = f"{lie.kind} {lie.size_m:g} m" if lie.kind == "jump" else f"drag {lie.speed_mps:g} m/s"  # fmt: skip
                    rows.append([flight, seed, label, len(got["caught"]), "none" if delay is None else f"{delay:.1f}", f"{100 * share:.0f} %", f"{err:.2f}", f"{ref:.2f}"])  # fmt: skip
                    figures.append({"flight": flight, "seed": seed, "lie": label, "alarms": len(got["caught"]), "alarm_delay_s": delay, "rejected_share": share, "median_error_m": err, "clean_median_error_m": ref})  # fmt: skip
                print(rows[-1], file=sys.stderr)
    print(f"# GNSS lies: {args.duration:g} s sessions, lie from t = {args.from_s:g} s\n")
    print(table(["flight", "seed", "GNSS", "alarms", "alarm delay (s)", "rejected after", "median error during the lie (m)", "clean run's (m)"], rows))  # fmt: skip
    write_json(args.json, {"duration_s": args.duration, "from_s": args.from_s, "runs": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
