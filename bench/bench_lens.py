"""What a wide lens and a rolling shutter cost when ignored, in metres on the model.

    python bench/bench_lens.py [--every 40] [--readout-ms 30]

The sample walk's true track (poses at the true frame times), with its camera given a GoPro
HERO8 Black wide lens (a bundled gyroflow profile, scaled to the 640x360 video) and a sensor
readout of `--readout-ms`. For each frame: where the image's centre, edge midpoints and corners
land on the model through the exact lens (the position pass and the lens's inverse, as the
footprints use), against where they land when the lens is ignored (a pinhole of the profile's
own focal length and centre: what a tool without a lens model assumes). The rolling shutter's
cost is the angle the camera turns in half a readout (true track) times the slant range of the
top and bottom rows: where those rows' pixels land when every row is taken at the frame's time.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import table  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=int, default=40)
    parser.add_argument("--readout-ms", type=float, default=30.0)
    args = parser.parse_args(argv)

    from app.camera.intrinsics import Intrinsics
    from app.camera.pinhole import Camera
    from app.camera.profiles import choose_profile, video_camera
    from app.export.records import FootprintCaster
    from app.geodesy import rotations
    from app.session import open_session
    from app.session.camera_track import camera_track
    from app.simulate.sample import SAMPLE_DIR

    session = open_session(SAMPLE_DIR / "session.toml")
    track = camera_track(session, "truth", true_timing=True)
    w, h = session.video.display_size
    choice = choose_profile("GoPro", "HERO8 Black", 1920, 1080, "wide")
    if choice is None:
        raise SystemExit("no bundled HERO8 Black wide profile")
    intr, lens = video_camera(choice[0], w, h, 0)
    pinhole = Intrinsics(w, h, lens.fx, lens.fy, lens.cx, lens.cy)
    exact = FootprintCaster(session.scene(), session.frame, intr, lens=lens)
    naive = FootprintCaster(session.scene(), session.frame, pinhole)
    g = exact.grid
    spots = {
        "centre": [exact.centre],
        "edge midpoints": [
            (0, (g.width - 1) // 2),
            ((g.height - 1) // 2, g.width - 1),
            (g.height - 1, (g.width - 1) // 2),
            ((g.height - 1) // 2, 0),
        ],
        "corners": exact.corners,
    }
    lens_err: dict[str, list[float]] = {k: [] for k in spots}
    shutter: list[float] = []
    half = args.readout_ms / 2000.0
    try:
        for k in range(0, track.frame_count, args.every):
            cam = track.frame_camera(k)
            real = Camera.create(intr, cam.position, cam.orientation, 0.5, 2000.0, lens)
            flat = Camera.create(pinhole, cam.position, cam.orientation, 0.5, 2000.0)
            p_exact, hit = exact.grid_points(real)
            p_naive, hit_n = naive.grid_points(flat)
            for name, cells in spots.items():
                for r, c in cells:
                    if hit[r, c] and hit_n[r, c]:
                        lens_err[name].append(
                            float(np.linalg.norm(p_exact[r, c, :2] - p_naive[r, c, :2]))
                        )
            t = float(track.clock.session_time([track.clock.media_s[k]])[0])
            _, _, q = track.poses.at([t - half, t + half])
            angle = (
                float(
                    np.linalg.norm(
                        rotations.to_scipy(
                            rotations.multiply(rotations.conjugate(q[0]), q[1])
                        ).as_rotvec()
                    )
                )
                / 2.0
            )
            for r, c in (spots["edge midpoints"][0], spots["edge midpoints"][2]):
                if hit[r, c]:
                    shutter.append(
                        angle * float(np.linalg.norm(p_exact[r, c] - np.asarray(cam.position)))
                    )
    finally:
        exact.release()
        naive.release()

    def row(name: str, values: list[float]) -> list[str]:
        v = np.asarray(values)
        return [
            name,
            str(len(v)),
            f"{np.median(v):.2f}",
            f"{np.percentile(v, 95):.2f}",
            f"{v.max():.2f}",
        ]

    print(f"# lens and rolling shutter, ignored\n\nsample walk, true track, every {args.every}th frame; lens: {choice[1]} ({lens.kind}, "
          f"{lens.hfov_deg:.0f} x {lens.vfov_deg:.0f} deg); readout {args.readout_ms:g} ms\n")  # fmt: skip
    print(
        table(
            ["where in the image", "samples", "median m", "p95 m", "max m"],
            [row(f"lens ignored: {name}", v) for name, v in lens_err.items()]
            + [row("readout ignored: top and bottom rows", shutter)],
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
