"""GNSS that lies (issue 52): how fast the `registered` source catches a jump, a drag-off, a
frozen track, a replayed track and a height lie, what it names them, how much of the lie it
rejects, and what the lie costs the camera's position.

    python bench/bench_gnss_lies.py [--flights orbit survey] [--seeds 1 2] [--duration 40]
        [--from-s 15] [--lies jump drag frozen replay height] [--json out.json]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from the model), then copies of it with the GNSS falsified from --from-s
seconds (app.simulate.lies: a 200 m jump east, a 2 m/s drag-off east, the fix frozen, the fixes
of 10 s before replayed, every height 40 m up) are solved with the `registered` source, and the
clean session too. Figures per run: the lies said and the kinds they were named (frozen,
replayed, height, disagrees), where the first was said to begin (clip s), the alarm's delay (s)
from the moment the lie exceeds the fixes' stated accuracy (the jump's, replay's and height
lie's start; the drag's start plus accuracy / speed; for a frozen fix the moment the true camera
has left it by that much), the share of frames after that moment marked `rejected`, the median
camera position error (m) against the truth over the frames after it, and the clean run's over
the same frames; for the clean run, lies said and frames rejected (false alarms).
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

LIES = {
    "jump": Lie("jump", size_m=200.0),
    "drag": Lie("drag", speed_mps=2.0),
    "frozen": Lie("frozen"),
    "replay": Lie("replay", back_s=10.0),
    "height": Lie("height", height_m=40.0),
}


def exceeds_s(lie: Lie, accuracy_m: float, t: np.ndarray, true_enu: np.ndarray) -> float:
    """Clip seconds from which the lie is larger than the fixes' stated accuracy (m): for a
    frozen fix, the first frame (clip times t (F,) s, true positions true_enu (F, 3) ENU m)
    whose true position has left the true one at the lie's start by more than that."""
    if lie.kind == "drag":
        return lie.from_s + accuracy_m / lie.speed_mps
    if lie.kind == "frozen":
        k = int(np.searchsorted(t, lie.from_s))
        gone = np.linalg.norm(true_enu[k:, :2] - true_enu[k, :2], axis=1) > accuracy_m
        return float(t[k + int(np.argmax(gone))]) if gone.any() else float("inf")
    return lie.from_s


def label(lie: Lie) -> str:
    """The lie as the table names it."""
    return {
        "jump": f"jump {lie.size_m:g} m",
        "drag": f"drag {lie.speed_mps:g} m/s",
        "frozen": "frozen",
        "replay": f"replay of {lie.back_s:g} s before",
        "height": f"height {lie.height_m:+g} m",
    }[lie.kind]


def run(manifest: Path) -> dict:
    """The registered track of one session: per frame its clip time (s from the simulation's
    start), true position (ENU m), position error (m) against the truth and gnss status; the
    lies said (when caught and began, clip s; their kinds)."""
    session = open_session(manifest)
    track = solve_track(session, "registered")
    truth = true_track(session)
    frames = np.arange(track.frame_count)
    ours = track.poses_at(track.clock.media_s[frames], frames)
    true = truth.poses_at(truth.clock.media_s[frames])
    check = track.registration.gnss
    return {
        "t": ours.time_s - sample.START_UNIX_S,
        "true": true.enu,
        "error": np.linalg.norm(ours.enu - true.enu, axis=1),
        "gnss": ours.gnss,
        "caught": [lie.caught_s - sample.START_UNIX_S for lie in check.lies],
        "began": [lie.began_s - sample.START_UNIX_S for lie in check.lies],
        "kinds": [lie.kind for lie in check.lies],
        "accuracy": float(np.median(session.gnss.h_acc)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--duration", type=float, default=40.0, help="seconds of video")
    parser.add_argument("--from-s", type=float, default=15.0, help="the lie begins (clip s)")
    parser.add_argument("--lies", nargs="+", default=list(LIES), choices=list(LIES))
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
                rows.append([flight, seed, "clean", len(clean["caught"]), " ".join(clean["kinds"]), "", "", f"{rejected} frames", "", f"{np.median(clean['error']):.2f}"])  # fmt: skip
                figures.append({"flight": flight, "seed": seed, "lie": "clean", "alarms": len(clean["caught"]), "kinds": clean["kinds"], "rejected_frames": rejected, "median_error_m": float(np.median(clean["error"]))})  # fmt: skip
                for name in args.lies:
                    lie = replace(LIES[name], from_s=args.from_s)
                    got = run(falsify(base / "clean", base / lie.kind, lie))
                    start = exceeds_s(lie, got["accuracy"], got["t"], got["true"])
                    after = got["t"] >= start
                    near = [k for k, c in enumerate(got["caught"]) if c >= lie.from_s - 5.0]
                    delay = got["caught"][near[0]] - start if near else None
                    began = got["began"][near[0]] if near else None
                    share = float(np.mean(got["gnss"][after] == REJECTED))
                    err, ref = float(np.median(got["error"][after])), float(np.median(clean["error"][after]))  # fmt: skip
                    rows.append([flight, seed, label(lie), len(got["caught"]), " ".join(got["kinds"]), "" if began is None else f"{began:.1f}", "none" if delay is None else f"{delay:.1f}", f"{100 * share:.0f} %", f"{err:.2f}", f"{ref:.2f}"])  # fmt: skip
                    figures.append({"flight": flight, "seed": seed, "lie": label(lie), "alarms": len(got["caught"]), "kinds": got["kinds"], "began_s": began, "alarm_delay_s": delay, "rejected_share": share, "median_error_m": err, "clean_median_error_m": ref})  # fmt: skip
                    print(rows[-1], file=sys.stderr)
    print(f"# GNSS lies: {args.duration:g} s sessions, lie from t = {args.from_s:g} s\n")
    print(table(["flight", "seed", "GNSS", "alarms", "named", "said from (s)", "alarm delay (s)", "rejected after", "median error during the lie (m)", "clean run's (m)"], rows))  # fmt: skip
    write_json(args.json, {"duration_s": args.duration, "from_s": args.from_s, "runs": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
