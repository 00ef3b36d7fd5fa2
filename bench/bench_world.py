"""World sources benchmark (issue 48): `geofuse view CLIP --world local` on a DJI clip over the
tests' synthetic world, its imagery (XYZ) and terrain (Terrain-RGB) served over the loopback
with a delay added to every request (a network's round trip; 50 ms by default), in a real
window on the wall clock, the video playing. From the command's start: the window's first
frame (the flat ground), the first draped frame on the world (its coarse level), the full
level drawn; requests made and MB cached; the frame time while the tiles stream in against the
frame time after (same run; the registration against the world then runs beside it); and, as
a baseline, the frame time over as long a span from the first frame with `--world none` (the
flat ground, nothing fetched or registered). Each with a cold tile cache, then warm. Beside
it, the same clip opened with the world built synchronously, as `geofuse view` did before and
as the commands that write files still do (the time to the first frame it cost).

    python bench/bench_world.py [--delay-ms 50] [--seconds 20] [--size 1280x720] [--json F]

The window needs an X display: the current one, or a private Xvfb the benchmark starts.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bench_playback import Display  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402
from tests.test_world import TileServer, _settings, write_drone_clip  # noqa: E402

AFTER_S = 5.0  # seconds of frames drawn once the world is drawn in full


def folder_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 2**20


def view_run(
    display: str,
    clip: Path,
    tmp: Path,
    env: dict,
    size: tuple[int, int],
    world: str = "local",
    seconds: float = 0.0,
) -> dict:
    """The viewer on `clip` with the world `world`: plays on the wall clock until the world is
    drawn in full, AFTER_S s more (with `--world none`: `seconds` s), then writes its state and
    quits. The state, with `t0`: the monotonic time (s) the command was started at (the
    viewer's world times are monotonic)."""
    state, script = tmp / "state.json", tmp / "script.txt"
    state.unlink(missing_ok=True)
    wait, end = ("0 wait world\n", AFTER_S) if world != "none" else ("", seconds)
    script.write_text(f"0 play\n{wait}{end} state {state}\n{end} quit\n")
    cmd = [sys.executable, "-m", "app", "view", str(clip), "--world", world]
    cmd += ["--script", str(script), "--size", f"{size[0]}x{size[1]}"]
    t0 = time.monotonic()
    result = subprocess.run(
        cmd, cwd=ROOT, env=dict(env, DISPLAY=display), capture_output=True, text=True, timeout=900
    )
    if result.returncode != 0 or not state.is_file():
        raise SystemExit(f"the viewer failed:\n{result.stderr[-3000:]}")
    out = json.loads(state.read_text())
    out["t0"] = t0
    return out


def synchronous_open_s(clip: Path, cache: Path) -> float:
    """Seconds to open the clip with its world built before anything is shown (the commands
    that write files; `geofuse view` before), in this process, its tiles cached in `cache`."""
    from app.footage.clips import open_any
    from app.world.build import world_layer
    from app.world.settings import choose_world

    os.environ["GEOFUSE_TILE_CACHE"] = str(cache)
    t0 = time.monotonic()
    session = open_any(clip, layers=(world_layer(choose_world("local")),))
    session.scene()
    return time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--delay-ms", type=float, default=50.0, help="added to every request")
    parser.add_argument("--seconds", type=int, default=20, help="the clip's length")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    print(
        f"# world sources benchmark\n\n{machine()}; window {size[0]}x{size[1]}; a {args.seconds} s DJI clip "
        f"(640x360); tiles over the loopback with {args.delay_ms:g} ms added per request\n"
    )
    server = TileServer()
    server.delay_s = args.delay_ms / 1000.0
    figures: dict = {"delay_ms": args.delay_ms, "size": list(size), "runs": {}}
    try:
        with tempfile.TemporaryDirectory() as tmp, Display() as display:
            tmp = Path(tmp)
            _settings(tmp, server.base)  # tmp/config/geofuse/settings.toml: the world `local`
            os.environ["XDG_CONFIG_HOME"] = str(tmp / "config")
            os.environ.pop("GEOFUSE_WORLD", None)
            clip = write_drone_clip(tmp / "clip", args.seconds, (640, 360))
            env = dict(os.environ, GEOFUSE_TILE_CACHE=str(tmp / "cache"))
            rows = []
            for label in ("cold", "warm"):
                server.log.clear()
                s = view_run(display, clip, tmp, env, size)
                w, t0 = s["world"], s["t0"]
                run = {
                    "first_frame_s": w["started_at"] - t0,
                    "coarse_drawn_s": w["shown_at"].get("coarse", float("nan")) - t0,
                    "full_drawn_s": w["shown_at"]["full"] - t0,
                    "requests": len(server.log),
                    "cached_mb": folder_mb(tmp / "cache"),
                    "frame_ms": w["frame_ms"],
                }
                figures["runs"][label] = run
                fs, fa = w["frame_ms"]["streaming"], w["frame_ms"]["after"]
                rows.append([
                    label, f"{run['first_frame_s']:.2f}", f"{run['coarse_drawn_s']:.2f}",
                    f"{run['full_drawn_s']:.2f}", run["requests"], f"{run['cached_mb']:.1f}",
                    f"{fs['median']:.1f} / {fs['p95']:.1f} ({fs['frames']})",
                    f"{fa['median']:.1f} / {fa['p95']:.1f} ({fa['frames']})",
                    f"{fs['median'] / fa['median']:.2f}",
                ])  # fmt: skip
            span = (
                figures["runs"]["cold"]["full_drawn_s"] - figures["runs"]["cold"]["first_frame_s"]
            )
            flat = view_run(display, clip, tmp, env, size, "none", span)
            figures["flat_ground"] = {
                "seconds": span,
                "frame_ms": {"median": flat["frame_ms"], "p95": flat["frame_p95_ms"]},
            }
            rows.append([
                "--world none", "", "", "", 0, "", f"{flat['frame_ms']:.1f} / {flat['frame_p95_ms']:.1f} (first {span:.0f} s)",
                "", "",
            ])  # fmt: skip
            print(
                table(
                    [
                        "tile cache",
                        "first frame s",
                        "first draped frame (coarse) s",
                        "full level drawn s",
                        "requests",
                        "MB cached",
                        "frame ms streaming: median / p95 (frames)",
                        "frame ms after",
                        "ratio",
                    ],
                    rows,
                )  # fmt: skip
            )
            cold = synchronous_open_s(clip, tmp / "sync-cache")
            warm = synchronous_open_s(clip, tmp / "sync-cache")
            figures["synchronous_open_s"] = {"cold": cold, "warm": warm}
            print(
                f"\nthe clip opened with the world built first (in process, no window): "
                f"{cold:.2f} s cold, {warm:.2f} s warm"
            )
    finally:
        server.stop()
    write_json(args.json, figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
