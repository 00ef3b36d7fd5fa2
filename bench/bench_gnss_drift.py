"""GNSS drag-offs against synthetic keyframes (issue 52): how soon the test catches a drag-off at
1, 2 and 5 m/s, and how many clean tracks it accuses, with and without the drift test
(app.register.gnss.drifting), for files (check_fixes over the whole clip) and live
(app.live.gnss_watch.GnssWatch, a keyframe at a time).

    python bench/bench_gnss_drift.py [--tracks 400] [--drags 40]

Each track: 120 s along a 6 m/s circle, fixes at 1 Hz with the simulator's GNSS error (2.5 m per
axis, 4 m in height live, correlated over 30 s: app.simulate.sensors.gauss_markov), stated
2.5 m; files: keyframes every 0.5 s with 0.1 m of noise and one in 20 registered 6 m astray
(tests/test_gnss_lies.py's model); live: a keyframe a second with 0.3 m of noise and one in 20
astray by 3 m, each tested against the fix of its moment (linear between the 1 Hz fixes); "live,
sooner in doubt": the same keyframes, but every 0.5 s while the watch is in doubt
(GnssWatch.suspect: the newest fix 2.5 stated accuracies off the GNSS's own offset, or a lie
going on), as app.live.register offers them. Clean tracks as they are and with the simulator's multipath bursts (their stated
accuracy grown: app.simulate.sensors.multipath), --tracks of each; --drags tracks per drag
speed, the drag east from 30 s. Figures: tracks that raised an alarm; per speed the delay from
the drag exceeding the stated accuracy (its start + 2.5 m / speed) to the alarm, median and
p90, the share within 5 s (the issue's goal), and how far from the drag's start the lie was said
to begin (|error|: median and p90; and how many were said from more than 3 s before it began,
or after).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.core.messages import Messages  # noqa: E402
from app.live.gnss_watch import DRIFT_S, GnssWatch  # noqa: E402
from app.register.gnss import CheckSettings, GnssLie, check_fixes  # noqa: E402
from app.simulate import sensors  # noqa: E402
from app.simulate.lies import Lie  # noqa: E402
from bench.common import table, write_json  # noqa: E402

ACCURACY_M = 2.5
LIE_FROM_S = 30.0
SPEEDS = (1.0, 2.0, 5.0)


def _circle(t: np.ndarray) -> np.ndarray:
    """ENU m along a 110 m circle 60 m up, flown at about 6 m/s, at times t (s)."""
    return np.column_stack([110 * np.cos(t / 18), 110 * np.sin(t / 18), np.full(len(t), 60.0)])


def _track(seed: int, live: bool, multipath: bool, lie: Lie | None):
    """(fix times, fixes (N, 3), their stated accuracy, keyframe times, keyframe positions)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 120.0)
    err = np.column_stack(
        [sensors.gauss_markov(t, 2.5, 30.0, rng, 2), sensors.gauss_markov(t, 4.0, 30.0, rng)]
    )
    if not live:
        err[:, 2] = 0.0
    fixes, acc = _circle(t) + err, np.full(len(t), ACCURACY_M)
    if multipath:
        extra, acc = sensors.multipath(t, acc, np.random.default_rng(1000 + seed))
        fixes = fixes + extra * ([1.0, 1.0, 1.0] if live else [1.0, 1.0, 0.0])
    if lie is not None:
        fixes = lie.apply(t, fixes)
    kt = np.arange(0.0, 120.0, 0.5)  # live: those on whole seconds, others while in doubt
    kp = _circle(kt) + rng.normal(0.0, 0.3 if live else 0.1, (len(kt), 3))
    kp[rng.random(len(kt)) < 0.05] += [3.0 if live else 6.0, 0.0, 0.0]
    return t, fixes, acc, kt, kp


def _lies(live: bool, drift: bool, *track, sooner: bool = False) -> list[GnssLie]:
    t, fixes, acc, kt, kp = track
    if not live:
        settings = CheckSettings() if drift else replace(CheckSettings(), drift_s=0.0)
        return list(check_fixes(t, fixes, acc, kt, kp, settings).lies)
    watch = GnssWatch(Messages(), ACCURACY_M, drift_s=DRIFT_S if drift else 0.0)
    k = 0
    while k < len(kt):
        fix = [np.interp(kt[k], t, fixes[:, j]) for j in range(3)]
        watch.keyframe(kt[k], fix, kp[k], acc[min(int(kt[k]), len(acc) - 1)])
        k += 1 if sooner and watch.suspect else 2 - k % 2  # the next half or whole second
    return watch.lies


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tracks", type=int, default=400, help="clean tracks (and with multipath)")
    parser.add_argument("--drags", type=int, default=40, help="tracks per drag speed")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    rows, figures = [], []
    for live, sooner in ((False, False), (True, False), (True, True)):
        for drift in (False, True) if not sooner else (True,):
            test = "live, sooner in doubt" if sooner else "live" if live else "files"
            fig: dict = {"test": test, "drift": drift}
            for name, mp in (("clean", False), ("multipath", True)):
                fig[name] = sum(bool(_lies(live, drift, *_track(s, live, mp, None), sooner=sooner)) for s in range(args.tracks))  # fmt: skip
            cells = []
            for speed in SPEEDS:
                lie = Lie("drag", LIE_FROM_S, speed_mps=speed)
                delays, began = [], []
                for seed in range(args.drags):
                    found = [x for x in _lies(live, drift, *_track(seed, live, False, lie), sooner=sooner) if x.caught_s >= LIE_FROM_S - 5.0]  # fmt: skip
                    delays.append(found[0].caught_s - (LIE_FROM_S + ACCURACY_M / speed) if found else np.inf)  # fmt: skip
                    if found:
                        began.append(found[0].began_s - LIE_FROM_S)
                d, b = np.array(delays), np.array(began)
                off = np.abs(b) if len(b) else np.array([np.nan])
                fig[f"drag_{speed:g}"] = {"median_s": float(np.median(d)), "p90_s": float(np.percentile(d, 90)), "within_5_s": float(np.mean(d <= 5.0)), "began_error_s": float(np.median(off)), "began_error_p90_s": float(np.percentile(off, 90)), "began_early_3_s": int(np.sum(b < -3.0)), "began_late_3_s": int(np.sum(b > 3.0))}  # fmt: skip
                cells.append(f"{np.median(d):.1f} / {np.percentile(d, 90):.1f} s, {100 * np.mean(d <= 5.0):.0f} %, {np.median(off):.1f} / {np.percentile(off, 90):.1f} s ({np.sum(b < -3.0)} early, {np.sum(b > 3.0)} late by 3 s)")  # fmt: skip
            figures.append(fig)
            rows.append([fig["test"], "with" if drift else "without", f"{fig['clean']} of {args.tracks}", f"{fig['multipath']} of {args.tracks}", *cells])  # fmt: skip
            print(rows[-1], file=sys.stderr, flush=True)
    head = [
        f"{s:g} m/s: delay median / p90, within 5 s, said from: off by median / p90 (how many more than 3 s early, late)"
        for s in SPEEDS
    ]
    print(table(["test", "drift test", "clean: alarms", "multipath: alarms", *head], rows))
    write_json(args.json, {"tracks": args.tracks, "drags": args.drags, "figures": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
