"""Frames late in a long video: decoded from the keyframe before them (app.io.video.decoded_at
seeks) against decoded from the start, as every reader of frames did before (the video's own
motion over an outage at minute 25, a replay, a painting). A clip of bars written at 30 fps (an
MP4, and an MPEG-TS: no index, FFmpeg's search by timestamps), ten frames 0.1 s apart wanted at
each of a few times into it; medians over repeated runs, both ways alternated in one run.

    python bench/bench_frames_at.py [--seconds 120] [--size 1280x720] [--repeats 5]
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

from bench.common import machine, table  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    from app.io import video
    from app.simulate.phone import write_video

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    fps = 30
    seek_after = video.SEEK_AFTER_S
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for suffix in (".mp4", ".ts"):
            path = write_video(
                Path(folder) / f"bars{suffix}", np.arange(int(args.seconds * fps)) / fps, (w, h), 0
            )
            info = video.probe(path)
            for at_s in (0.25 * args.seconds, 0.5 * args.seconds, 0.9 * args.seconds):
                wanted = [int(at_s * fps) + 3 * k for k in range(10)]
                sought, whole = [], []
                for _ in range(args.repeats):
                    for after, bucket in ((seek_after, sought), (float("inf"), whole)):
                        video.SEEK_AFTER_S = after
                        t0 = time.perf_counter()
                        got = [i for i, _ in video.frames_at(info, wanted, 640)]
                        bucket.append(time.perf_counter() - t0)
                        assert got == wanted, (got, wanted)
                video.SEEK_AFTER_S = seek_after
                a, b = statistics.median(sought), statistics.median(whole)
                rows.append(
                    [
                        suffix[1:],
                        f"{at_s:.0f}",
                        f"{1000 * a:.0f}",
                        f"{1000 * b:.0f}",
                        f"{b / a:.1f}x",
                    ]
                )
                print(rows[-1], flush=True)
    print(f"\n{machine()}, {w}x{h}, {args.seconds:.0f} s at {fps} fps, median of {args.repeats}\n")
    print(
        table(
            ["container", "frames wanted at (s)", "sought (ms)", "from the start (ms)", "ratio"],
            rows,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
