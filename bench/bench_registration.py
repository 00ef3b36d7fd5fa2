"""Registration against the scene: speed per stage and keyframes per second on the sample
session, and the fallback on a copy of it whose view is fogged over (featureless) for 15 s.

    python bench/bench_registration.py [--repeat 3] [--no-fog] [--no-matchers]

Speed: the whole `registered` source solved `repeat` times (median wall time against the clip's
length; time per stage: render, match (features, matching, pose), decode). Fallback: the sample's
video from 20 to 35 s replaced by grey fog (what a lens fogged up, a featureless wall or the sky
look like to a matcher); position error (m) of the registered and the prior track against the
truth, inside and outside the fog, at every 10th frame. Matchers: every 4th second's frame
registered from its true pose moved 3 m and turned 2 deg, by each detector (SIFT, ORB)
with and without the fine step (corners tracked by Lucas-Kanade): how many land within 0.3 m and
0.3 deg, the median errors, and the time per keyframe.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.camera.pinhole import Camera  # noqa: E402
from app.core.progress import ProgressBar  # noqa: E402
from app.geodesy import rotations  # noqa: E402
from app.io.video import frames_at  # noqa: E402
from app.register import MatchSettings, Registrar, RegistrationSettings  # noqa: E402
from app.register.solve import keyframe_indices  # noqa: E402
from app.render.context import create_offscreen_context, describe  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.camera_track import camera_track  # noqa: E402
from app.simulate.fog import fogged_copy  # noqa: E402
from app.solve.accuracy import true_track  # noqa: E402
from app.solve.track import solve_track  # noqa: E402
from bench.common import table, write_json  # noqa: E402

FOG_S = (20.0, 35.0)


def perturbed(cam: Camera, metres: float, degrees: float, seed: int) -> Camera:
    """The camera moved `metres` (mostly horizontally) and turned `degrees`, in a direction and
    about an axis drawn from the seed."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=3) * [1.0, 1.0, 0.3]
    axis = rng.normal(size=3)
    turn = rotations.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis))
    position = np.asarray(cam.position) + metres * d / np.linalg.norm(d)
    return Camera.create(
        cam.intrinsics,
        position,
        rotations.multiply(turn, np.asarray(cam.orientation)),
        cam.near,
        cam.far,
        cam.lens,
    )


def matchers(session) -> list[list[str]]:
    """Rows of the matcher comparison (see the module docstring)."""
    truth = true_track(session)
    idx = keyframe_indices(np.asarray(session.video.pts_s), 4.0)
    frames = dict(frames_at(session.video, idx, RegistrationSettings().long_side))
    rows = []
    for detector in ("sift", "orb"):
        for fine in (True, False):
            settings = RegistrationSettings(match=MatchSettings(detector=detector), fine=fine)
            registrar = Registrar(session, settings)
            errs, t0 = [], time.perf_counter()
            for k in idx:
                true = truth.frame_camera(int(k))
                _, solved, _ = registrar.keyframe(frames[int(k)], perturbed(true, 3.0, 2.0, int(k)))
                if solved is None:
                    errs.append((np.inf, np.inf))
                else:
                    errs.append(
                        (
                            float(np.linalg.norm(np.subtract(solved.position, true.position))),
                            float(
                                np.degrees(
                                    rotations.angle_between(solved.orientation, true.orientation)
                                )
                            ),
                        )
                    )
            per = (time.perf_counter() - t0) / len(idx)
            registrar.release()
            e = np.array(errs)
            ok = (e[:, 0] < 0.3) & (e[:, 1] < 0.3)
            got = np.isfinite(e[:, 0])
            rows.append([detector + (" + fine" if fine else ""), f"{got.sum()} / {len(idx)}", f"{ok.sum()} / {len(idx)}",
                         f"{np.median(e[got, 0]):.2f}" if got.any() else "-", f"{np.median(e[got, 1]):.2f}" if got.any() else "-", f"{per:.2f}"])  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--repeat", type=int, default=3, help="solves of the sample for the speed figures (median)"
    )
    parser.add_argument(
        "--every-s", type=float, default=0.5, help="seconds of video between keyframes"
    )
    parser.add_argument("--no-fog", action="store_true", help="skip the fogged clip")
    parser.add_argument("--no-matchers", action="store_true", help="skip the matcher comparison")
    parser.add_argument(
        "--json", type=Path, default=None, help="also write the speed figures to this file"
    )
    args = parser.parse_args(argv)
    settings = RegistrationSettings(every_s=args.every_s)

    sample = ROOT / "assets" / "sample"
    session = open_session(sample / "session.toml")
    clip_s = float(session.video.pts_s[-1] - session.video.pts_s[0])
    ctx = create_offscreen_context()
    gl = describe(ctx)
    print(
        f"# registration: {sample / 'session.toml'} ({clip_s:.1f} s of video, {session.video.width}x{session.video.height}); {gl}\n"
    )
    ctx.release()
    walls, stages, reg = [], [], None
    for i in range(args.repeat):
        t0 = time.perf_counter()
        track = solve_track(
            session,
            "registered",
            progress=ProgressBar(f"registering {i + 1}/{args.repeat}", sys.stderr),
            settings=settings,
        )
        walls.append(time.perf_counter() - t0)
        reg = track.registration
        stages.append(reg.stage_s)
    n = len(reg.keyframes)
    wall = statistics.median(walls)
    print(f"{reg.summary()}\n")
    print(table(["what", "median of " + str(args.repeat)], [
        ["wall time (s)", f"{wall:.1f}"],
        ["wall time / clip length", f"{wall / clip_s:.2f}"],
        ["keyframes per second", f"{n / wall:.2f}"],
        *[[f"{k} (s, all keyframes)", f"{statistics.median(s[k] for s in stages):.1f}"] for k in ("render", "match", "decode")],
        ["renderings per keyframe (mean)", f"{np.mean([k.iterations for k in reg.keyframes]):.2f}"],
    ]))  # fmt: skip
    write_json(args.json, {
        "clip_s": round(clip_s, 2), "every_s": args.every_s, "repeats": args.repeat,
        "keyframes": n, "registered": sum(k.registered for k in reg.keyframes),
        "used": sum(k.used for k in reg.keyframes),
        "wall_s": round(wall, 2), "wall_per_clip": round(wall / clip_s, 3),
        "keyframes_per_s": round(n / wall, 3),
        "stage_s": {k: round(statistics.median(s[k] for s in stages), 2) for k in ("render", "match", "decode")},
        "renderings_per_keyframe": round(float(np.mean([k.iterations for k in reg.keyframes])), 2),
        "gl": gl,
    })  # fmt: skip
    if not args.no_matchers:
        print("\n## Matchers: from the true pose moved 3 m and turned 2 deg, every 4th second\n")
        print(
            table(
                [
                    "matcher",
                    "registered",
                    "within 0.3 m and 0.3 deg",
                    "median m",
                    "median deg",
                    "s per keyframe",
                ],
                matchers(session),
            )
        )
    if args.no_fog:
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        fog = open_session(fogged_copy(sample, Path(tmp), FOG_S))
        track = solve_track(fog, "registered")
        prior = camera_track(fog, track.registration.prior)
        truth = true_track(fog)
        frames = np.arange(0, truth.frame_count, 10)
        media = fog.video.pts_s[frames]
        err = {
            name: np.linalg.norm(
                t.poses_at(media, frames).enu - truth.poses_at(media, frames).enu, axis=1
            )
            for name, t in (("registered", track), ("prior", prior))
        }
        inside = (media >= FOG_S[0]) & (media < FOG_S[1])
        print(
            f"\n## Fogged over {FOG_S[0]:.0f}-{FOG_S[1]:.0f} s\n\n{track.registration.summary()}\n"
        )
        worse = float(np.mean(err["registered"][inside] > err["prior"][inside] + 0.05))
        rows = [
            [
                name,
                f"{np.median(e[~inside]):.2f}",
                f"{np.median(e[inside]):.2f}",
                f"{e[inside].max():.2f}",
            ]
            for name, e in err.items()
        ]
        print(
            table(
                [
                    "track",
                    "position error outside the fog, median m",
                    "inside, median m",
                    "inside, max m",
                ],
                rows,
            )
        )
        print(
            f"\nframes inside the fog where the registered track is more than 5 cm worse than its prior: {100 * worse:.0f} %"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
