"""Registration by geometry (app/register/edges.py) against texture matching, keyframe by
keyframe: every 4th second of the sample, from the true pose moved 3 m and turned 2 deg, by SIFT
against the sample model and by the model's lines against the same model with its textures
removed (its lines matched point by point, and as segments). The video is the world that differs from the model (trees, kiosks, cars, other
textures), so its edges hold far more than the model's lines.

    python bench/bench_geometry.py [--every-s 4] [--session S] [--clip [--from-truth]]

--session: another session (e.g. `geofuse simulate session --flight orbit`); --clip: also the
whole `registered` source against the model without texture, beside the offline prior and the
textured registration: projection error on the model at the centre line and the edges
(app.solve.accuracy, every 10th frame), keyframes used, and the time taken; and the model
without texture's centre-line error by the pixels' range under the true pose; --from-truth:
also a row for the model without texture whose every keyframe's search begins at the true pose
(each fit still held to its usual start as the prior): what the lines' objective gives a
perfect search.

Prints per method: keyframes registered, within 0.5 m and 0.5 deg, median position and turn
errors of the registered ones, how many ended nearer the truth than they started, s a keyframe.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.geodesy import rotations  # noqa: E402
from app.io.video import frames_at  # noqa: E402
from app.register.edges import EdgeSettings  # noqa: E402
from app.register.solve import Registrar, RegistrationSettings  # noqa: E402
from app.scene.mesh import MeshData  # noqa: E402
from app.session import open_session  # noqa: E402
from app.simulate.sample import SAMPLE_DIR  # noqa: E402
from app.solve.accuracy import (  # noqa: E402
    Poses,
    ProjectionProbe,
    evaluate,
    poses_at,
    split_stats,
    true_track,
)
from app.solve.track import solve_track  # noqa: E402
from bench.common import table  # noqa: E402
from tests.test_register import _perturbed  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every-s", type=float, default=4.0)
    parser.add_argument(
        "--session", type=Path, default=SAMPLE_DIR / "session.toml", help="default: the sample"
    )
    parser.add_argument("--clip", action="store_true", help="the whole registered source too")
    parser.add_argument(
        "--from-truth", action="store_true", help="with --clip: a row begun at the true poses"
    )
    args = parser.parse_args(argv)
    session = open_session(args.session)
    truth_track = true_track(session)
    pts = np.asarray(session.video.pts_s)
    frames = sorted(
        {int(np.searchsorted(pts, t)) for t in np.arange(pts[0] + 2.0, pts[-1], args.every_s)}
    )
    grey = MeshData([replace(p, texture=None, uvs=None) for p in session.scene().primitives])
    probe = ProjectionProbe(session, (64, 36))

    def on_model(cams: list, truths: list) -> str:
        """median m at the centre line and at the edges, the cameras' pixels against the
        truth's (app.solve.accuracy)"""
        if not cams:
            return "-"
        est, tru = (
            Poses(np.array([c.position for c in cs]), np.array([c.orientation for c in cs]))
            for cs in (cams, truths)
        )
        s = split_stats(*probe.errors(est, tru), 64)
        return f"{s.centre_median:.2f} / {s.edge_median:.2f}"

    rows = []
    for name, mesh, settings in [
        ("texture (SIFT + fine), textured model", session.scene(), RegistrationSettings()),
        ("geometry (edges), model without texture", grey, RegistrationSettings(by_geometry=True)),
        (
            "geometry (line segments), model without texture",
            grey,
            # LSD leaves short lines unfound: 60 % of the model's segment points must find one
            RegistrationSettings(
                by_geometry=True, edges=EdgeSettings(lines_by="segments", min_found=0.6)
            ),
        ),
    ]:
        registrar = Registrar.of_scene(mesh, settings)
        errors, nearer, t0 = [], 0, time.perf_counter()
        solved_cams, true_cams, start_cams = [], [], []
        try:
            for k, rgb in frames_at(session.video, frames, settings.long_side):
                truth = truth_track.frame_camera(k)
                start = _perturbed(truth, 3.0, 2.0, seed=k)
                _, solved, _ = registrar.keyframe(rgb, start)
                if solved is None:
                    continue
                m = float(np.linalg.norm(np.subtract(solved.position, truth.position)))
                d = float(
                    np.degrees(rotations.angle_between(solved.orientation, truth.orientation))
                )
                errors.append((m, d))
                solved_cams.append(solved)
                true_cams.append(truth)
                start_cams.append(start)
                nearer += m < float(np.linalg.norm(np.subtract(start.position, truth.position)))
        finally:
            registrar.release()
        seconds = (time.perf_counter() - t0) / len(frames)
        e = np.array(errors).reshape(-1, 2)
        within = int(np.sum((e[:, 0] < 0.5) & (e[:, 1] < 0.5)))
        rows.append([
            name, f"{len(e)} / {len(frames)}", f"{within} / {len(frames)}",
            f"{np.median(e[:, 0]):.2f}" if len(e) else "-", f"{np.median(e[:, 1]):.2f}" if len(e) else "-",
            f"{nearer} / {len(e)}", on_model(start_cams, true_cams),
            on_model(solved_cams, true_cams), f"{seconds:.2f}",
        ])  # fmt: skip
    probe.release()
    if args.clip:
        clip_rows(session, grey, args.from_truth)
    print(table(
        ["method", "registered", "within 0.5 m and 0.5 deg", "median m", "median deg", "nearer than the start",
         "start on the model: centre / edges m", "registered on the model", "s a keyframe"],
        rows,
    ))  # fmt: skip
    return 0


def clip_rows(session, grey: MeshData, from_truth: bool = False) -> None:
    """The whole registered source on the model without texture and on the textured one, beside
    the offline prior: projection error on the model (m, median / p95); from_truth: also the
    model without texture with every keyframe's search begun at its true pose."""
    rows, tracks = [], {}
    clip_s = float(session.video.pts_s[-1] - session.video.pts_s[0])
    grey_session = replace(session, mesh=grey)
    runs = [("textured model", session, {}), ("model without texture", grey_session, {})]
    if from_truth:
        begun = {"begin": true_track(session).frame_camera}
        runs.append(("model without texture, begun at the truth", grey_session, begun))
    for name, sess, options in runs:
        t0 = time.perf_counter()
        track = solve_track(sess, "registered", **options)
        wall, reg = time.perf_counter() - t0, track.registration
        tracks[name] = track
        registered = sum(k.registered for k in reg.keyframes)
        used = f"{reg.used} / {len(reg.keyframes)} ({registered} registered)"
        took = f"{wall:.0f} s ({wall / clip_s:.2f}x the clip)"
        sources = ["offline", "registered"] if not options else ["registered"]
        for r in evaluate(sess, sources, paper=False, solved={"registered": track}):
            t, own = r.total, r.name == "registered"
            rows.append([
                name, r.name, f"{t.centre_median:.2f} / {t.centre_p95:.2f}",
                f"{t.edge_median:.2f} / {t.edge_p95:.2f}", f"{r.attitude[0]:.2f}",
                used if own else "-", took if own else "-",
            ])  # fmt: skip
    print(table(
        ["scene", "source", "centre m (median / p95)", "edges m (median / p95)", "attitude RMS deg", "keyframes used", "registered in"],
        rows,
    ))  # fmt: skip
    print()
    print(range_table(grey_session, tracks["model without texture"]))
    print()


RANGES_M = ((0.0, 100.0), (100.0, 200.0), (200.0, 400.0), (400.0, np.inf))


def range_table(session, track, every: int = 10, grid: tuple[int, int] = (64, 36)) -> str:
    """The centre column's projection error (m, median / p95) by the pixels' range (m) under the
    true pose, every `every`th frame: where a p95 comes from."""
    truth = true_track(session)
    frames = np.arange(0, len(session.video.pts_s), every)
    tru, est = poses_at(truth, frames), poses_at(track, frames)
    probe = ProjectionProbe(session, grid)
    centre = slice(grid[0] // 2 - 1, grid[0] // 2 + 1)
    errors, ranges = [], []
    try:
        for k in range(len(frames)):
            a, b = probe.points(est.enu[k], est.q[k]), probe.points(tru.enu[k], tru.q[k])
            errors.append(np.linalg.norm(a - b, axis=2)[:, centre].ravel())
            ranges.append(np.linalg.norm(b - tru.enu[k], axis=2)[:, centre].ravel())
    finally:
        probe.release()
    e, r = np.concatenate(errors), np.concatenate(ranges)
    ok = np.isfinite(e)
    rows = []
    for lo, hi in RANGES_M:
        m = ok & (r >= lo) & (r < hi)
        if m.any():
            rows.append([
                f"{lo:.0f}-{hi:.0f} m" if np.isfinite(hi) else f"over {lo:.0f} m",
                f"{100 * m.sum() / ok.sum():.0f} %",
                f"{np.median(e[m]):.2f} / {np.percentile(e[m], 95):.2f}",
            ])  # fmt: skip
    return table(["range under the true pose", "centre pixels", "model without texture, registered: m (median / p95)"], rows)  # fmt: skip


if __name__ == "__main__":
    raise SystemExit(main())
