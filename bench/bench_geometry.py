"""Registration by geometry (app/register/edges.py) against texture matching, keyframe by
keyframe: every 4th second of the sample, from the true pose moved 3 m and turned 2 deg, by SIFT
against the sample model and by the model's lines against the same model with its textures
removed. The video is the world that differs from the model (trees, kiosks, cars, other
textures), so its edges hold far more than the model's lines.

    python bench/bench_geometry.py [--every-s 4]

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
from app.register.solve import Registrar, RegistrationSettings  # noqa: E402
from app.scene.mesh import MeshData  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session.camera_track import camera_track, frame_clock  # noqa: E402
from app.simulate.sample import SAMPLE_DIR  # noqa: E402
from bench.common import table  # noqa: E402
from tests.test_register import _perturbed  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every-s", type=float, default=4.0)
    args = parser.parse_args(argv)
    session = open_session(SAMPLE_DIR / "session.toml")
    truth_track = replace(
        camera_track(session, "truth"), clock=frame_clock(session, true_timing=True)
    )
    pts = np.asarray(session.video.pts_s)
    frames = sorted(
        {int(np.searchsorted(pts, t)) for t in np.arange(pts[0] + 2.0, pts[-1], args.every_s)}
    )
    grey = MeshData([replace(p, texture=None, uvs=None) for p in session.scene().primitives])
    rows = []
    for name, mesh, settings in [
        ("texture (SIFT + fine), textured model", session.scene(), RegistrationSettings()),
        ("geometry (edges), model without texture", grey, RegistrationSettings(by_geometry=True)),
    ]:
        registrar = Registrar.of_scene(mesh, settings)
        errors, nearer, t0 = [], 0, time.perf_counter()
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
                nearer += m < float(np.linalg.norm(np.subtract(start.position, truth.position)))
        finally:
            registrar.release()
        seconds = (time.perf_counter() - t0) / len(frames)
        e = np.array(errors).reshape(-1, 2)
        within = int(np.sum((e[:, 0] < 0.5) & (e[:, 1] < 0.5)))
        rows.append([
            name, f"{len(e)} / {len(frames)}", f"{within} / {len(frames)}",
            f"{np.median(e[:, 0]):.2f}" if len(e) else "-", f"{np.median(e[:, 1]):.2f}" if len(e) else "-",
            f"{nearer} / {len(e)}", f"{seconds:.2f}",
        ])  # fmt: skip
    print(table(
        ["method", "registered", "within 0.5 m and 0.5 deg", "median m", "median deg", "nearer than the start", "s a keyframe"],
        rows,
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
