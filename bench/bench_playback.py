"""Playback benchmark: the viewer's own frame loop (`geofuse view` in a real window, the code path
a person runs), playing at 1x on the wall clock for `--seconds`: playback latency (a frame's due
time -> its first display, the paper's measure), frames shown and dropped, frame time; for the
bundled sample and for a 1080p30 clip on the same model and sensors. Then the decoder alone:
throughput against real time, and seek time to an exact frame.

    python bench/bench_playback.py [--seconds 60] [--size 1280x720]

The window needs an X display: the current one, or a private Xvfb that the benchmark starts.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.common import machine, table, write_json  # noqa: E402


def make_1080p_clip(path: Path, seconds: float) -> Path:
    from app.simulate.phone import write_video

    n = int(seconds * 30)
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (1080 // 8, 1920 // 8, 3), dtype=np.uint8).repeat(8, 0).repeat(8, 1)

    def frame(k: int) -> np.ndarray:
        return np.roll(base, 4 * k, axis=1)  # a moving texture: real work for the encoder/decoder

    return write_video(path, np.arange(n) / 30.0, (1920, 1080), 0, frame=frame, crf=23)


def make_drone_clip(folder: Path, seconds: float, size: tuple[int, int] = (640, 360)) -> Path:
    """A 30 fps clip of `size` (w, h) with the subtitle a DJI Air 2S writes, dated like the sample
    walk (app.simulate.drone), so that the two play together on one timeline."""
    from app.simulate import drone
    from app.simulate.phone import write_video

    folder.mkdir(parents=True, exist_ok=True)
    video = write_video(folder / "DJI_0001.MP4", np.arange(int(seconds * 30)) / 30.0, size, 0)
    (folder / "DJI_0001.SRT").write_text(drone.srt_text(seconds, 0.0), encoding="utf-8")
    return video


def sample_session_with(video: Path, out: Path) -> Path:
    """The sample session's manifest with another video (same start time, model and sensors)."""
    from app.simulate.sample import SAMPLE_DIR

    text = (SAMPLE_DIR / "session.toml").read_text()
    for name in (
        "scene.glb",
        "acc.csv",
        "gyr.csv",
        "mag.csv",
        "phone_orientation.csv",
        "gnss.csv",
        "truth_orientation.csv",
        "truth_position.csv",
    ):
        text = text.replace(f'"{name}"', f'"{SAMPLE_DIR / name}"')
    text = text.replace('path = "clip.mp4"', f'path = "{video}"').replace(
        'frame_times = "truth_frames.csv"\n', ""
    )
    out.write_text(text)
    return out


class Display:
    """The current X display, or a private Xvfb for the benchmark's lifetime."""

    def __enter__(self) -> str:
        self.proc = None
        if os.environ.get("DISPLAY"):
            return os.environ["DISPLAY"]
        if shutil.which("Xvfb") is None:
            raise SystemExit(
                "no DISPLAY and no Xvfb (apt-get install xvfb): the viewer needs a window"
            )
        number = 150 + os.getpid() % 100
        self.proc = subprocess.Popen(
            ["Xvfb", f":{number}", "-screen", "0", "1920x1080x24", "-nolisten", "tcp"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        socket = Path(f"/tmp/.X11-unix/X{number}")
        for _ in range(200):
            if socket.exists():
                break
            time.sleep(0.05)
        return f":{number}"

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=5)


def viewer_playback(
    display: str,
    manifest: Path,
    seconds: float,
    size: tuple[int, int],
    tmp: Path,
    while_registering: bool = False,
    more: tuple[Path, ...] = (),
    wait: bool = True,
) -> dict:
    """Run the viewer on `manifest`: wait for every source to be solved (with while_registering,
    every one but `registered`, which then registers in the background during the playback;
    wait=False: none, all are solved while it plays), play `seconds` of wall time at 1x, write
    its state (latency, frames shown and dropped, frame times) and quit."""
    state = tmp / f"{manifest.stem}.json"
    script = tmp / f"{manifest.stem}.txt"
    until = "solved" if while_registering else "registered"
    first = f"0 wait {until}\n" if wait else ""
    script.write_text(f"{first}0 play\n{seconds} state {state}\n{seconds} quit\n")
    env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(tmp / "config"))
    cmd = [
        sys.executable,
        "-m",
        "app",
        "view",
        str(manifest),
        *map(str, more),
        "--script",
        str(script),
        "--size",
        f"{size[0]}x{size[1]}",
    ]
    result = subprocess.run(
        cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=seconds + 600
    )
    if result.returncode != 0 or not state.is_file():
        raise SystemExit(f"the viewer failed on {manifest}:\n{result.stderr[-3000:]}")
    return json.loads(state.read_text())


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


def seek_times(video: Path, info, count: int = 15) -> list[float]:
    """Seconds from a seek request to the exact frame arriving from the decoder thread."""
    from app.playback.decoder import Decoder

    pts = info.pts_s
    rng = np.random.default_rng(1)
    dec = Decoder(str(video), info.origin_s)
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
    parser.add_argument(
        "--while-registering",
        action="store_true",
        help="play while the registered source is solved in the background (default: after it)",
    )
    parser.add_argument(
        "--two-clips-only", action="store_true", help="only the two-clips-at-once table"
    )
    parser.add_argument(
        "--drone-size", default="640x360", help="the further (drone) clip's frame size, WxH"
    )
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="play at once, the sources solved meanwhile (a check that it runs, not a measure)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))

    from app.io.video import probe
    from app.simulate.sample import SAMPLE_DIR

    print(
        f"# playback benchmark\n\n{machine()}; the viewer's window {size[0]}x{size[1]} (default panels and depth map); {args.seconds:g} s of 1x playback each{', while the registered source is solved in the background' if args.while_registering else ', every source solved first'}\n"
    )
    figures: dict = {"size": list(size), "seconds": args.seconds, "one_clip": {}}
    with tempfile.TemporaryDirectory() as tmp, Display() as display:
        tmp = Path(tmp)
        if not args.two_clips_only:
            clip = make_1080p_clip(tmp / "1080p30.mp4", min(args.seconds, 70.0) + 1.0)
            rows, decode_rows = [], []
            for label, manifest in (
                ("sample 640x360 (VFR ~30 fps)", SAMPLE_DIR / "session.toml"),
                ("1080p30", sample_session_with(clip, tmp / "hd.toml")),
            ):
                r = viewer_playback(
                    display,
                    manifest,
                    args.seconds,
                    size,
                    tmp,
                    args.while_registering,
                    wait=not args.no_wait,
                )
                _, mean, p95 = r["latency_ms"]
                due = r["frames_shown"] + r["dropped"]
                rows.append(
                    [
                        label,
                        r["frames_shown"],
                        r["dropped"],
                        f"{100 * r['dropped'] / max(due, 1):.1f} %",
                        r["skipped_by_decoder"],
                        f"{mean:.1f}",
                        f"{p95:.1f}",
                        f"{r['frame_ms']:.1f}",
                        f"{1000 / r['frame_ms']:.1f}",
                    ]
                )
                info = (
                    probe(manifest.parent / "clip.mp4")
                    if manifest.name == "session.toml"
                    else probe(clip)
                )
                seeks = np.asarray(seek_times(Path(info.path), info)) * 1000
                decoded = decode_throughput(Path(info.path), info.nominal_fps)
                decode_rows.append(
                    [
                        label,
                        f"{decoded:.1f}x",
                        f"{np.median(seeks):.0f} / {np.percentile(seeks, 95):.0f}",
                    ]
                )
                figures["one_clip"][label] = {
                    **_viewer_figures(r),
                    "decode_x_real_time": round(decoded, 2),
                    "seek_median_ms": round(float(np.median(seeks)), 1),
                }
                figures["gl"] = r.get("gl")
            print(
                table(
                    [
                        "clip",
                        "frames shown",
                        "dropped",
                        "dropped share",
                        "skipped by the decoder",
                        "latency mean ms",
                        "latency p95 ms",
                        "frame time median ms",
                        "loop fps",
                    ],
                    rows,
                )
            )
            print()
            print(table(["clip", "decode vs real time", "seek median / p95 ms"], decode_rows))
        drone_size = tuple(int(v) for v in args.drone_size.split("x"))
        print(
            "\n## Two clips at once: the sample walk and a drone clip filmed at the same time"
            f" ({drone_size[0]}x{drone_size[1]})\n"
        )
        drone_clip = make_drone_clip(tmp / "drone", min(args.seconds, 70.0) + 1.0, drone_size)
        r = viewer_playback(
            display,
            SAMPLE_DIR / "session.toml",
            args.seconds,
            size,
            tmp,
            args.while_registering,
            more=(drone_clip,),
            wait=not args.no_wait,
        )
        other = r["clips"][0]
        two = []
        for label, shown, dropped, latency in (
            ("sample (first)", r["frames_shown"], r["dropped"], r["latency_ms"]),
            ("drone (further)", other["frames_shown"], other["dropped"], other["latency_ms"]),
        ):
            two.append(
                [
                    label,
                    shown,
                    dropped,
                    f"{100 * dropped / max(shown + dropped, 1):.1f} %",
                    f"{latency[1]:.1f}",
                    f"{latency[2]:.1f}",
                ]
            )
        print(
            table(
                [
                    "clip",
                    "frames shown",
                    "dropped",
                    "dropped share",
                    "latency mean ms",
                    "latency p95 ms",
                ],
                two,
            )
        )
        print(f"\nframe time median {r['frame_ms']:.1f} ms ({1000 / r['frame_ms']:.1f} fps)")
        figures["two_clips"] = {
            **_viewer_figures(r),
            "further": {
                "frames_shown": other["frames_shown"],
                "dropped": other["dropped"],
                "latency_mean_ms": other["latency_ms"][1],
                "latency_p95_ms": other["latency_ms"][2],
            },
        }
        figures["gl"] = r.get("gl")
    figures["machine"] = machine()
    write_json(args.json, figures)
    return 0


def _viewer_figures(r: dict) -> dict:
    """The viewer state's playback figures (ms): frames shown and dropped, latency, frame time."""
    return {
        "frames_shown": r["frames_shown"],
        "dropped": r["dropped"],
        "latency_mean_ms": r["latency_ms"][1],
        "latency_p95_ms": r["latency_ms"][2],
        "frame_ms": r["frame_ms"],
        "frame_p95_ms": r.get("frame_p95_ms"),
    }


if __name__ == "__main__":
    raise SystemExit(main())
