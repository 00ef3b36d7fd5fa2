"""Playback benchmark, off-screen on the machine's OpenGL (Mesa llvmpipe without a GPU): playback
latency (a frame's due time -> its first display, the paper's measure) and dropped frames over
`--seconds` of 1x playback, for the bundled sample and for a 1080p30 clip; decode throughput
against real time; seek time to an exact frame.

    python bench/bench_playback.py [--seconds 60] [--size 1280x720] [--depth 2048]

The loop is the viewer's (app/playback/player.py): tick, upload the frame's Y/U/V planes, update
the projector from the pose track, draw (depth map redrawn when the pose changed), glFinish with
the GIL released; the view is still, so the loop draws only when a frame is due and sleeps
otherwise. "loop fps" is the draws per second.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import machine, table  # noqa: E402


def make_1080p_clip(path: Path, seconds: float) -> Path:
    from app.simulate.phone import write_video

    n = int(seconds * 30)
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (1080 // 8, 1920 // 8, 3), dtype=np.uint8).repeat(8, 0).repeat(8, 1)

    def frame(k: int) -> np.ndarray:
        return np.roll(base, 4 * k, axis=1)  # a moving texture: real work for the encoder/decoder

    return write_video(path, np.arange(n) / 30.0, (1920, 1080), 0, frame=frame, crf=23)


def playback(video: Path, pts: np.ndarray, seconds: float, size: tuple[int, int], depth: int) -> dict[str, float]:
    """Play `video` at 1x for `seconds`, drawing the sample scene with the sample's GD-AHRS track."""
    from app.camera import Camera, Intrinsics, look_at_quat
    from app.config import ProjectionSettings
    from app.demo import SAMPLE_DIR
    from app.playback.player import Player
    from app.render.context import create_offscreen_context, wait_for_gpu
    from app.render.offscreen import OffscreenTarget
    from app.render.renderer import FusionRenderer
    from app.session import open_session, pose_track

    session = open_session(SAMPLE_DIR / "session.toml")
    track = pose_track(session, "gd-ahrs")
    ctx = create_offscreen_context()
    renderer = FusionRenderer(ctx, session.scene())
    target = OffscreenTarget(ctx, *size)
    view = Camera.create(Intrinsics.from_fov(*size, 60.0), [35.0, -160.0, 40.0], look_at_quat([35.0, -160.0, 40.0], [0.0, -20.0, 8.0]), 0.5, 3000.0)
    player = Player(str(video), pts, loop=True)
    settings = ProjectionSettings(alpha=0.85, depth_long_side=depth)
    frames = 0
    renders = []
    try:
        time.sleep(0.5)  # let the decoder fill its queue, as the viewer's start-up does
        start = time.perf_counter()
        player.clock.set_paused(False, start)
        while True:
            now = time.perf_counter()
            if now - start >= seconds:
                break
            if not player.tick(now):
                # The view is still: nothing to draw until the next frame is due (less the
                # look-ahead); sleeping leaves the cores to the decoder.
                due = player.next_due_wall(now)
                wake = now + 0.002 if due is None else due - player.lookahead_s
                time.sleep(min(0.005, max(0.0, wake - now)))
                continue
            f = player.current
            renderer.set_video_yuv(f.y, f.u, f.v, 0 if video != session.video.path else session.rotation_cw, f.bt709, f.full_range)
            k = min(player.index, len(session.frame_times) - 1)
            enu, _, q = track.at(session.frame_times[k : k + 1])
            renderer.set_projector(Camera.create(Intrinsics.from_fov(*renderer.video.size, 66.0), enu[0], q[0], 0.5, 2000.0))
            renderer.draw(view, target.fbo, settings)
            wait_for_gpu(ctx)
            shown = time.perf_counter()
            renders.append(shown - now)
            player.shown(shown, shown - now)
            frames += 1
        _, mean, p95 = player.stats.summary()
        return {
            "frames shown": len(player.stats.latencies),
            "dropped": player.stats.dropped,
            "latency mean ms": mean,
            "latency p95 ms": p95,
            "render median ms": 1000 * float(np.median(renders)),
            "loop fps": frames / seconds,
        }
    finally:
        player.close()
        target.release()
        renderer.release()
        ctx.release()


def decode_throughput(video: Path, fps: float) -> float:
    """Frames decoded per second (FFmpeg threading on, planes extracted as the viewer does),
    as a multiple of real time."""
    import av

    from app.playback.decoder import yuv_planes

    with av.open(str(video)) as c:
        s = c.streams.video[0]
        s.thread_type = "AUTO"
        t0 = time.perf_counter()
        n = 0
        for frame in c.decode(s):
            yuv_planes(frame)
            n += 1
        dt = time.perf_counter() - t0
    return n / dt / fps


def seek_times(video: Path, pts: np.ndarray, count: int = 15) -> list[float]:
    """Seconds from a seek request to the exact frame arriving from the decoder thread."""
    from app.playback.decoder import Decoder

    rng = np.random.default_rng(1)
    dec = Decoder(str(video))
    out = []
    try:
        for i, target in enumerate(rng.uniform(0, pts[-1], count)):
            k = int(np.searchsorted(pts, target))
            k = min(k, len(pts) - 1)
            t0 = time.perf_counter()
            dec.seek(float(pts[k]), i + 1)
            while True:
                f = dec.frames.get(timeout=10)
                if f.serial == i + 1:
                    assert abs(f.pts_s - pts[k]) < 1e-3, (f.pts_s, pts[k])
                    out.append(time.perf_counter() - t0)
                    break
    finally:
        dec.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--depth", type=int, default=2048, help="depth-map texels on the video's long side")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))

    from app.demo import SAMPLE_DIR
    from app.io.video import probe
    from app.render.context import create_offscreen_context, describe

    ctx = create_offscreen_context()
    gl = describe(ctx)
    ctx.release()
    print(f"# playback benchmark\n\n{machine()}; GL: {gl}; view {size[0]}x{size[1]}, depth map {args.depth}; {args.seconds:g} s of 1x playback each\n")
    with tempfile.TemporaryDirectory() as tmp:
        sample = probe(SAMPLE_DIR / "clip.mp4")
        clip = make_1080p_clip(Path(tmp) / "1080p30.mp4", min(args.seconds, 60.0) + 1.0)
        hd = probe(clip)
        rows = []
        for label, info in (("sample 640x360 (VFR ~30 fps)", sample), ("1080p30", hd)):
            r = playback(Path(info.path), info.pts_s, args.seconds, size, args.depth)
            seeks = np.asarray(seek_times(Path(info.path), info.pts_s)) * 1000
            rows.append([label, r["frames shown"], r["dropped"], f"{r['latency mean ms']:.1f}", f"{r['latency p95 ms']:.1f}", f"{r['render median ms']:.1f}", f"{r['loop fps']:.1f}",
                         f"{decode_throughput(Path(info.path), info.nominal_fps):.1f}x", f"{np.median(seeks):.0f} / {np.percentile(seeks, 95):.0f}"])
        print(table(["clip", "frames shown", "dropped", "latency mean ms", "latency p95 ms", "render median ms", "loop fps", "decode vs real time", "seek median / p95 ms"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
