"""GNSS that lies (issue 52): how fast the `registered` source catches a jump, a drag-off, a
frozen track, a replayed track and a height lie, what it names them, how much of the lie it
rejects, and what the lie costs the camera's position.

    python bench/bench_gnss_lies.py [--flights orbit survey] [--seeds 1 2] [--duration 40]
        [--from-s 15] [--lies jump drag1 drag drag5 frozen replay height] [--jobs 1]
        [--json out.json] [--cases cases.jsonl] [--from-cases cases.jsonl] [--fog FROM TO]

For each flight and seed a session is simulated (app.simulate.session: the video rendered from
a world that differs from the model), then copies of it with the GNSS falsified from --from-s
seconds (app.simulate.lies: a 200 m jump east, drag-offs east at 1, 2 and 5 m/s, the fix
frozen, the fixes of 10 s before replayed, every height 40 m up) are solved with the
`registered` source, and the clean session too, and a copy with multipath bursts
(app.simulate.lies' `multipath`: no lie, what a clean session in a city suffers), --jobs at a
time. Figures per run: the lies said and the kinds they were named (frozen, replayed, height,
disagrees), where the first was said to begin (clip s), the alarm's delay (s) from the moment
the lie exceeds the fixes' stated accuracy (the jump's, replay's and height lie's start; the
drag's start plus accuracy / speed; for a frozen fix the moment the true camera has left it by
that much), the share of frames after that moment marked `rejected`, the median camera
position error (m) and drape error (m on the model, every 15th frame) over the frames after
it, the clean run's over the same frames, and the share of those frames whose position error
lies within 1 and 2 of the frame's sigma (app.solve.uncertainty); for the clean and the
multipath runs, lies said and frames rejected (false alarms). --cases keeps each case's arrays as
it is solved (a run cut short keeps what it finished); --from-cases makes the figures from them.
--fog FROM TO greys every case's video over those media seconds (app.simulate.fog's
fogged_copy: a stretch the scene cannot register, as sky, fog or a featureless field are), the
clean run's too.

    python bench/bench_gnss_lies.py --live [--flights orbit survey] [--seeds 1 2]
        [--duration 40] [--from-s 15] [--live-lies drag1 drag drag5 jump frozen] [--accuracy 2.5]
        [--fog FROM TO] [--recorded]

Live (forward only, app.live.gnss_watch): for each flight and seed a drone downlink over the
sample site (app.simulate.downlink: 480x270 H.264 MPEG-TS, a KLV set per frame, the model itself
rendered, its positions with the simulator's GNSS error: 2.5 m per axis and 4 m in height,
correlated over 30 s) is sent over the loopback in real time to `geofuse live`'s pipeline
(drawing 320x180 off screen, live registration on, the fixes held to --accuracy, which KLV does
not state), clean and with each lie from --from-s (drag-offs east at 1, 2, 5 m/s, a 200 m jump
east; with `frozen`, the fix frozen). Figures per feed: the lies said, when the first was caught and said to begin (flight s),
the alarm's delay from the moment the lie exceeds the stated accuracy (as for files), how long
after the alarm's keyframe the first frame was drawn rejected (registration's lag), the share
of frames drawn rejected after the lie exceeds the accuracy, and the drawn camera's position
error against the truth over those frames (median, p95) with the clean feed's over the same
flight times; for the clean feed, lies said and frames rejected (false alarms). The keyframes'
spacing is what the machine gives: say its load. --fog FROM TO: every feed's video grey over
those seconds (app.simulate.downlink's fog_s), the clean one's too. --recorded: each feed is
also recorded as it arrives (`geofuse live --record`) and the recording, once the feed ends,
solved as a file (forward and backward: `geofuse solve REC.ts --scene ... --gnss-accuracy`),
with the same figures beside the live ones: what an operator reviewing the flight afterwards
gets.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.fixes import REJECTED  # noqa: E402
from app.footage.clips import open_any  # noqa: E402
from app.geodesy.enu import LocalFrame  # noqa: E402
from app.live.run import LiveOptions, run_sent  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate import drone, flights, sensors  # noqa: E402
from app.simulate import session as sample  # noqa: E402
from app.simulate.downlink import SITE, path_of, sample_layer, write_downlinks  # noqa: E402
from app.simulate.fog import fogged_copy  # noqa: E402
from app.simulate.lies import Lie, falsify  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.solve.accuracy import ProjectionProbe, true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from app.solve.uncertainty import frame_sigmas  # noqa: E402
from bench.common import table, write_json  # noqa: E402

LIES = {
    "jump": Lie("jump", size_m=200.0),
    "drag1": Lie("drag", speed_mps=1.0),
    "drag": Lie("drag", speed_mps=2.0),
    "drag5": Lie("drag", speed_mps=5.0),
    "frozen": Lie("frozen"),
    "replay": Lie("replay", back_s=10.0),
    "height": Lie("height", height_m=40.0),
}
FILE_LIES = ("jump", "drag1", "drag", "drag5", "frozen", "replay")  # issue 52's cases
DRAPE_EVERY = 15  # frames between those whose drape error is measured (0.5 s at 30 fps)
DRAPE_GRID = (32, 18)  # pixels probed per frame (app.solve.accuracy.ProjectionProbe)
LIVE_LIES = (
    "drag1",
    "drag",
    "drag5",
    "jump",
    "frozen",
)  # of LIES: live, drag-offs at 1, 2, 5 m/s, a jump, a frozen fix
LIVE_VIDEO, LIVE_DRAWING = (480, 270), (320, 180)


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


def said_near(got: dict, lie: Lie) -> int | None:
    """The index (into a run's `caught`) of the first lie said from 5 s before `lie` began on;
    None where none was."""
    return next((k for k, c in enumerate(got["caught"]) if c >= lie.from_s - 5.0), None)


def after_lie(got: dict, lie: Lie, start: float) -> tuple[int | None, float, np.ndarray]:
    """Of a run (live or a recording solved) against `lie`, whose fixes exceed their accuracy
    from `start` s: (the index of the lie said near it (said_near), the share of frames from
    `start` on marked rejected, their errors (m))."""
    after = got["t"] >= start
    return said_near(got, lie), float(np.mean(got["gnss"][after] == REJECTED)), got["error"][after]


def flight_enu(frame: LocalFrame, flight: flights.Flight, t: np.ndarray) -> np.ndarray:
    """Where the simulated downlink's camera was at flight times t (N,) s: (N, 3) ENU m of
    `frame` (a live run's or a recording's session frame)."""
    return frame.geodetic_to_enu(*SITE.enu_to_geodetic(path_of(flight, t)[0]).T)


def run(manifest: Path) -> dict:
    """The registered track of one session: per frame its clip time (s from the simulation's
    start), true position (ENU m), position error (m) against the truth, its sigma (m, each
    axis: app.solve.uncertainty.frame_sigmas) and gnss status; every DRAPE_EVERY-th frame's
    drape error (the median distance on the model between where the frame's pixels land from
    its camera and from the true one, app.solve.accuracy.ProjectionProbe); the lies said (when
    caught and began, clip s; their kinds); registration's searches (clip s, the disc's radius
    m, whether found)."""
    session = open_session(manifest)
    track = solve_track(session, "registered")
    truth = true_track(session)
    frames = np.arange(track.frame_count)
    ours = track.poses_at(track.clock.media_s[frames], frames)
    true = truth.poses_at(truth.clock.media_s[frames])
    check = track.registration.gnss
    sigma, _ = frame_sigmas(session, track, frames)
    probe = ProjectionProbe(session, DRAPE_GRID)
    sampled = frames[::DRAPE_EVERY]
    try:
        drape = [
            np.nanmedian(
                np.linalg.norm(
                    probe.points(ours.enu[k], ours.q[k]) - probe.points(true.enu[k], true.q[k]),
                    axis=2,
                )
            )  # fmt: skip
            for k in sampled
        ]
    finally:
        probe.release()
    return {
        "t": ours.time_s - sample.START_UNIX_S,
        "true": true.enu,
        "error": np.linalg.norm(ours.enu - true.enu, axis=1),
        "sigma": sigma,
        "drape": np.array(drape),
        "drape_frames": sampled,
        "gnss": ours.gnss,
        "caught": [lie.caught_s - sample.START_UNIX_S for lie in check.lies],
        "began": [lie.began_s - sample.START_UNIX_S for lie in check.lies],
        "kinds": [lie.kind for lie in check.lies],
        "accuracy": float(np.median(session.gnss.h_acc)) if len(session.gnss.t) else float("nan"),
        "searched": [(t - sample.START_UNIX_S, r, ok) for t, r, ok in track.registration.searched],
    }


def _session(job: tuple[str, int, float, str, tuple[float, float] | None]) -> tuple[str, int]:
    """Write one simulated session (flight, seed, duration s, folder, fog: its video grey over
    these media seconds, or None) and its multipath copy."""
    flight, seed, duration, folder, fog = job
    config = replace(sample.quick_config(duration), flight=flight, seed=seed)
    clean = Path(folder) / "clean"
    if fog is None:
        sample.write_sample_session(clean, SAMPLE_SCENE, config)
    else:  # every case, the clean one too, flies through the same fog
        sample.write_sample_session(Path(folder) / "clear", SAMPLE_SCENE, config)
        clean.mkdir(parents=True)
        fogged_copy(Path(folder) / "clear", clean, fog)
    falsify(Path(folder) / "clean", Path(folder) / "multipath", Lie("multipath", -1e6, seed=seed))
    return flight, seed


def _case(job: tuple[str, int, str, str, float]) -> tuple[str, int, str, dict]:
    """Solve one case (flight, seed, lie name or clean/multipath, folder, lie start s)."""
    flight, seed, name, folder, from_s = job
    base = Path(folder)
    if name in ("clean", "multipath"):
        return flight, seed, name, run(base / name / "session.toml")
    lie = replace(LIES[name], from_s=from_s)
    return flight, seed, name, run(falsify(base / "clean", base / name, lie))


def within(got: dict, mask: np.ndarray, k: float) -> float:
    """The share of frames in mask whose position error is within k sigma (each axis's, so
    k sqrt(3) sigma in 3D)."""
    return float(np.mean(got["error"][mask] <= k * np.sqrt(3.0) * got["sigma"][mask]))


def _drape(got: dict, mask: np.ndarray) -> float:
    """The median drape error (m) of the sampled frames inside mask (per frame)."""
    inside = mask[got["drape_frames"]]
    return float(np.nanmedian(got["drape"][inside])) if inside.any() else float("nan")


def _read_cases(path: Path) -> dict:
    """The cases an earlier run wrote with --cases (JSON lines), by (flight, seed, case)."""
    done = {}
    for line in path.read_text().splitlines():
        case = json.loads(line)
        lists = ("caught", "began", "kinds")
        done[(case["flight"], case["seed"], case["case"])] = {k: np.asarray(v) if isinstance(v, list) and k not in lists else v for k, v in case.items()}  # fmt: skip
    return done


def files_main(args: argparse.Namespace) -> int:
    """The measurements on files (module docstring), jobs sessions at a time; with
    --from-cases, the figures of an earlier run's cases (the flights and seeds it finished)."""
    if args.from_cases is not None:
        done = _read_cases(args.from_cases)
        names = ("clean", "multipath", *args.lies)
        units = {(f, s) for f, s, _ in done if all((f, s, n) in done for n in names)}
        return _figures(done, sorted(units), args)
    with tempfile.TemporaryDirectory(prefix="gnss-lies-") as tmp:
        fog = None if args.fog is None else tuple(args.fog)
        units = [(f, s, args.duration, str(Path(tmp) / f"{f}-{s}"), fog) for s in args.seeds for f in args.flights]  # fmt: skip
        cases = [(f, s, n, d, args.from_s) for f, s, _, d, _ in units for n in ("clean", "multipath", *args.lies)]  # fmt: skip
        with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
            list(pool.imap_unordered(_session, units))
            done = {}
            for f, s, n, got in pool.imap_unordered(_case, cases):
                done[(f, s, n)] = got  # each said as it comes: a run cut short keeps them
                print(f"{f} {s} {n}: caught {[round(c, 1) for c in got['caught']]} {got['kinds']}, rejected {np.mean(got['gnss'] == REJECTED):.2f}, median error {np.median(got['error']):.2f} m", file=sys.stderr, flush=True)  # fmt: skip
                if args.cases is not None:  # every figure of the case, one JSON line
                    with open(args.cases, "a") as out:
                        out.write(json.dumps({"flight": f, "seed": s, "case": n} | {k: np.asarray(v).tolist() if isinstance(v, np.ndarray) else v for k, v in got.items()}) + "\n")  # fmt: skip
    return _figures(done, sorted((f, s) for f, s, _, _, _ in units), args)


def _figures(done: dict, units: list[tuple[str, int]], args: argparse.Namespace) -> int:
    """The table and the JSON of the solved cases (by (flight, seed, case)) of each unit."""
    rows, figures = [], []
    for flight, seed in units:
        clean = done[(flight, seed, "clean")]
        for name in ("clean", "multipath"):
            got = done[(flight, seed, name)]
            rejected = int(np.sum(got["gnss"] == REJECTED))
            every = np.ones(len(got["t"]), bool)
            rows.append([flight, seed, name, len(got["caught"]), " ".join(got["kinds"]), "", "", f"{rejected} frames", f"{np.median(got['error']):.2f}", "", f"{_drape(got, every):.2f}", "", f"{100 * within(got, every, 1):.0f} / {100 * within(got, every, 2):.0f} %"])  # fmt: skip
            figures.append({"flight": flight, "seed": seed, "lie": name, "alarms": len(got["caught"]), "kinds": got["kinds"], "rejected_frames": rejected, "median_error_m": float(np.median(got["error"])), "median_drape_m": _drape(got, every), "within_1_sigma": within(got, every, 1), "within_2_sigma": within(got, every, 2)})  # fmt: skip
        for name in args.lies:
            lie = replace(LIES[name], from_s=args.from_s)
            got = done[(flight, seed, name)]
            start = exceeds_s(lie, got["accuracy"], got["t"], got["true"])
            after = got["t"] >= start
            near, share, during = after_lie(got, lie, start)
            delay = None if near is None else got["caught"][near] - start
            began = None if near is None else got["began"][near]
            err, ref = float(np.median(during)), float(np.median(clean["error"][after]))
            drape, drape_ref = _drape(got, after), _drape(clean, after)
            cover = (within(got, after, 1), within(got, after, 2))
            rows.append([flight, seed, label(lie), len(got["caught"]), " ".join(got["kinds"]), "" if began is None else f"{began:.1f}", "none" if delay is None else f"{delay:.1f}", f"{100 * share:.0f} %", f"{err:.2f}", f"{ref:.2f}", f"{drape:.2f}", f"{drape_ref:.2f}", f"{100 * cover[0]:.0f} / {100 * cover[1]:.0f} %"])  # fmt: skip
            figures.append({"flight": flight, "seed": seed, "lie": label(lie), "alarms": len(got["caught"]), "kinds": got["kinds"], "began_s": began, "alarm_delay_s": delay, "rejected_share": share, "median_error_m": err, "clean_median_error_m": ref, "median_drape_m": drape, "clean_median_drape_m": drape_ref, "within_1_sigma": cover[0], "within_2_sigma": cover[1]})  # fmt: skip
    print(f"# GNSS lies: {args.duration:g} s sessions, lie from t = {args.from_s:g} s\n")
    print(table(["flight", "seed", "GNSS", "alarms", "named", "said from (s)", "alarm delay (s)", "rejected after", "median error during the lie (m)", "clean run's (m)", "median drape error during the lie (m)", "clean run's (m)", "error within 1 / 2 sigma"], rows))  # fmt: skip
    write_json(args.json, {"duration_s": args.duration, "from_s": args.from_s, "runs": figures})
    return 0


def live_run(
    path: Path, accuracy_m: float, flight: flights.Flight, record: Path | None = None
) -> dict:
    """One downlink received live: per frame drawn its flight time (s), position error (m)
    against the truth and gnss status; the lies said (caught, began: flight s; kinds), the
    first frame drawn rejected (flight s), the keyframes tested (flight s). record: where the
    feed is recorded as it arrives."""
    drawn = []
    options = LiveOptions(
        silence_s=1.0,
        size=LIVE_DRAWING,
        layers=(sample_layer(),),
        gnss_accuracy_m=accuracy_m,
        record=record,
    )
    run = run_sent(
        path, options, lambda d, c: drawn.append((d.pts_s, np.asarray(c.position), d.gnss))
    )
    origin = run.origin_s or 0.0
    t = np.array([p for p, _, _ in drawn]) + origin
    want = flight_enu(run.frame, flight, t)
    gnss = np.array([g for _, _, g in drawn])
    rejected = t[gnss == REJECTED]
    watch = run.gnss
    return {
        "t": t,
        "true": want,
        "error": np.linalg.norm(np.array([p for _, p, _ in drawn]) - want, axis=1),
        "gnss": gnss,
        "caught": [lie.caught_s + origin for lie in watch.lies],
        "began": [lie.began_s + origin for lie in watch.lies],
        "unseen": [
            None if lie.unseen_from_s is None else lie.unseen_from_s + origin for lie in watch.lies
        ],
        "kinds": [lie.kind for lie in watch.lies],
        "first_rejected": float(rejected[0]) if len(rejected) else None,
        "keyframes": np.array(watch.keyframe_times) + origin,
        "summary": run.summary(),
    }


def recorded_run(path: Path, accuracy_m: float, flight: flights.Flight) -> dict:
    """A live feed's recording solved as a file (the `registered` source, its fixes held to
    accuracy_m, the sample model as its scene): per frame its flight time (s), position error
    (m) against the truth and gnss status; the lies said (caught, began: flight s)."""
    session = open_any(path, hfov_deg=sample.HFOV_DEG, layers=(sample_layer(),), accuracy_m=accuracy_m)  # fmt: skip
    track = solve_track(session, "registered")
    frames = np.arange(track.frame_count)
    ours = track.poses_at(track.clock.media_s[frames], frames)
    utc = session.utc_of(0.0)  # the KLV's own clock: session time 0 in Unix seconds
    if utc is None:
        raise ValueError(f"{path}: its KLV carries no time, so its frames cannot be put on the flight")  # fmt: skip
    t0 = drone.START.timestamp() - utc  # the flight's start, session s
    t = ours.time_s - t0
    want = flight_enu(session.frame, flight, t)
    lies = track.registration.gnss.lies
    return {
        "t": t,
        "true": want,
        "error": np.linalg.norm(ours.enu - want, axis=1),
        "gnss": ours.gnss,
        "caught": [lie.caught_s - t0 for lie in lies],
        "began": [lie.began_s - t0 for lie in lies],
        "kinds": [lie.kind for lie in lies],
    }


def live_main(args: argparse.Namespace) -> int:
    """The live measurements (module docstring)."""
    rows, figures = [], []

    def recording(path: Path) -> Path | None:
        """Where --recorded records the feed sent from `path` (None: not recorded)."""
        return path.with_name(f"{path.stem}-recorded.ts") if args.recorded else None

    with tempfile.TemporaryDirectory(prefix="gnss-lies-live-") as tmp:
        for name in args.flights:
            flight = {"orbit": flights.orbit, "survey": flights.survey}[name]()
            for seed in args.seeds:
                folder = Path(tmp) / f"{name}-{seed}"
                folder.mkdir()
                rng = np.random.default_rng(seed)
                t = np.arange(0.0, args.duration, 1.0 / 30.0)
                noise = np.column_stack([sensors.gauss_markov(t, 2.5, 30.0, rng, 2), sensors.gauss_markov(t, 4.0, 30.0, rng)])  # fmt: skip
                lies = [Lie("clean")] + [replace(LIES[k], from_s=args.from_s) for k in args.live_lies]  # fmt: skip
                fog = None if args.fog is None else tuple(args.fog)
                paths = write_downlinks(folder, [(lie, args.duration) for lie in lies], LIVE_VIDEO, flight, noise, sample.HFOV_DEG, fog_s=fog)  # fmt: skip
                clean = live_run(paths[0], args.accuracy, flight, recording(paths[0]))
                spacing = float(np.median(np.diff(clean["keyframes"]))) if len(clean["keyframes"]) > 1 else float("nan")  # fmt: skip
                n_rej = int(np.sum(clean["gnss"] == REJECTED))
                rows.append([name, seed, "clean", len(clean["caught"]), " ".join(clean["kinds"]), "", "", "", f"{n_rej} frames", "", "", f"{np.median(clean['error']):.2f}", f"{spacing:.2f}"])  # fmt: skip
                figures.append({"flight": name, "seed": seed, "lie": "clean", "alarms": len(clean["caught"]), "kinds": clean["kinds"], "rejected_frames": n_rej, "median_error_m": float(np.median(clean["error"])), "keyframe_spacing_s": spacing})  # fmt: skip
                if args.recorded:
                    solved = recorded_run(recording(paths[0]), args.accuracy, flight)
                    n_rej = int(np.sum(solved["gnss"] == REJECTED))
                    rows[-1] += [f"{len(solved['caught'])} alarms, {n_rej} frames", "", ""]
                    figures[-1]["recorded"] = {"alarms": len(solved["caught"]), "rejected_frames": n_rej, "median_error_m": float(np.median(solved["error"]))}  # fmt: skip
                print(rows[-1], clean["summary"], file=sys.stderr)
                for lie, path in zip(lies[1:], paths[1:], strict=True):
                    got = live_run(path, args.accuracy, flight, recording(path))
                    start = exceeds_s(lie, args.accuracy, got["t"], got["true"])
                    after = got["t"] >= start
                    near, share, err = after_lie(got, lie, start)
                    caught = None if near is None else got["caught"][near]
                    delay = None if caught is None else caught - start
                    lag = None if caught is None or got["first_rejected"] is None else got["first_rejected"] - caught  # fmt: skip
                    began = None if near is None else got["began"][near]
                    unseen = None if near is None else got["unseen"][near]
                    ref = np.interp(got["t"][after], clean["t"], clean["error"])
                    spacing = float(np.median(np.diff(got["keyframes"]))) if len(got["keyframes"]) > 1 else float("nan")  # fmt: skip
                    rows.append([name, seed, label(lie), len(got["caught"]), " ".join(got["kinds"]), "" if began is None else (f"{began:.1f}" if unseen is None else f"{unseen:.1f} to {began:.1f}"), "none" if delay is None else f"{delay:.1f}", "" if lag is None else f"{lag:.1f}", f"{100 * share:.0f} %", f"{np.median(err):.2f} / {np.percentile(err, 95):.2f}", f"{np.median(ref):.2f}", "", f"{spacing:.2f}"])  # fmt: skip
                    figures.append({"flight": name, "seed": seed, "lie": label(lie), "alarms": len(got["caught"]), "kinds": got["kinds"], "began_s": began, "unseen_from_s": unseen, "alarm_delay_s": delay, "frames_after_alarm_s": lag, "rejected_share": share, "median_error_m": float(np.median(err)), "p95_error_m": float(np.percentile(err, 95)), "clean_median_error_m": float(np.median(ref)), "keyframe_spacing_s": spacing})  # fmt: skip
                    if args.recorded:  # the same feed's recording, solved afterwards
                        solved = recorded_run(recording(path), args.accuracy, flight)
                        near, share, err = after_lie(solved, lie, start)
                        began = None if near is None else solved["began"][near]
                        rows[-1] += ["none" if began is None else f"{began:.1f}", f"{100 * share:.0f} %", f"{np.median(err):.2f} / {np.percentile(err, 95):.2f}"]  # fmt: skip
                        figures[-1]["recorded"] = {"alarms": len(solved["caught"]), "began_s": began, "rejected_share": share, "median_error_m": float(np.median(err)), "p95_error_m": float(np.percentile(err, 95))}  # fmt: skip
                    print(rows[-1], got["summary"], file=sys.stderr)
    fogged = "" if args.fog is None else f", video grey from {args.fog[0]:g} to {args.fog[1]:g} s"
    print(
        f"# GNSS lies, live: {args.duration:g} s downlinks, lie from t = {args.from_s:g} s, fixes held to {args.accuracy:g} m{fogged}\n"
    )
    head = ["flight", "seed", "GNSS", "alarms", "named", "said from (s)", "alarm delay (s)", "drawn rejected after (s)", "rejected after", "error during the lie, median / p95 (m)", "clean run's (m)", "clean: median error (m)", "keyframe spacing (s)"]  # fmt: skip
    if args.recorded:
        head += ["recorded, solved after: said from (s)", "rejected after", "error during the lie, median / p95 (m)"]  # fmt: skip
    print(table(head, rows))
    write_json(args.json, {"live": True, "duration_s": args.duration, "from_s": args.from_s, "accuracy_m": args.accuracy, "runs": figures})  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flights", nargs="+", default=["orbit", "survey"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--duration", type=float, default=40.0, help="seconds of video")
    parser.add_argument("--from-s", type=float, default=15.0, help="the lie begins (clip s)")
    parser.add_argument("--lies", nargs="+", default=list(FILE_LIES), choices=list(LIES))
    parser.add_argument("--jobs", type=int, default=1, help="files: sessions solved at a time")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    parser.add_argument(
        "--cases", type=Path, default=None, help="files: each case's arrays (JSON lines)"
    )
    parser.add_argument(
        "--from-cases", type=Path, default=None, help="files: the figures of --cases', solving none"
    )
    parser.add_argument(
        "--fog",
        nargs=2,
        type=float,
        default=None,
        metavar=("FROM", "TO"),
        help="every case's video grey from FROM to TO s (a stretch that cannot register)",
    )
    parser.add_argument("--live", action="store_true", help="live downlinks, forward only")
    parser.add_argument("--live-lies", nargs="+", default=list(LIVE_LIES[:4]), choices=LIVE_LIES)
    parser.add_argument("--accuracy", type=float, default=2.5, help="live: the fixes' accuracy (m)")
    parser.add_argument(
        "--recorded",
        action="store_true",
        help="live: also record each feed and solve its recording as a file afterwards",
    )
    args = parser.parse_args(argv)
    if args.live:
        return live_main(args)
    return files_main(args)


if __name__ == "__main__":
    raise SystemExit(main())
