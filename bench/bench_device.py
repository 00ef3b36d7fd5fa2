"""Every frame-time benchmark a lent GPU should answer, in one go, into one JSON (issue 49).

    python bench/bench_device.py --out OUT.json [--dry-run] [--require-gpu] [--only a,b]
        [--budget-s 480]

Run by bench/device.sh, which prepares the machine (EGL on NVIDIA, the Python packages) first.
Each step is a benchmark script run in its own process with its own time limit, in order of
what matters most (the render-cost goals first); the JSON is written again after every step,
so that a run cut short still returns what it measured. It holds the GPU, driver and GL strings,
and per step: whether it ran, its wall time, its figures (the script's own --json), and the end
of its output where it failed. --dry-run runs every step at tiny sizes (on llvmpipe, to know
the script works) and checks the JSON's shape; --check FILE checks a JSON already written.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.render.context import software_rasteriser  # noqa: E402


@dataclass(frozen=True)
class Step:
    """One benchmark run: its script (in bench/), arguments for the full and the dry run, the
    keys its figures must hold, its time limit (s), and whether it needs an X display."""

    name: str
    script: str
    full: tuple[str, ...]
    dry: tuple[str, ...]
    keys: tuple[str, ...]
    limit_s: float
    display: bool = False


_RENDER_KEYS = (
    "projector_ratios",
    "gpu_ratios",
    "frame_median_ms",
    "sample_on_off_ratio",
    "city_on_off",
    "gl",
)


def _render(size: str, dry_size: str) -> Step:
    """The projectors' tables (1, 2, 4 and 8 at once, both paths, the sample and the city on and
    off) at one view size."""
    full = ("--projectors-only", "--frames", "60", "--size", size)
    dry = ("--projectors-only", "--frames", "2", "--size", dry_size, "--city-detail", "1")
    return Step(f"render_{size}", "bench_render.py", full, dry, _RENDER_KEYS, 150)


def _playback(size: str, dry_one_clip: bool) -> Step:
    """The viewer's own loop in a window at one size: the sample and a 1080p30 clip alone, and
    two clips at once. The dry run plays at once, its sources solved meanwhile, and leaves the
    clips alone out where dry_one_clip is False (the run's two minutes)."""
    full = ("--seconds", "20", "--size", size)
    dry = ("--seconds", "1", "--size", "640x360", "--no-wait")
    dry += () if dry_one_clip else ("--two-clips-only",)
    keys = ("one_clip", "two_clips", "gl")
    return Step(f"playback_{size}", "bench_playback.py", full, dry, keys, 360, display=True)


STEPS: tuple[Step, ...] = (
    _render("1280x720", "320x180"),
    _render("1920x1080", "480x270"),
    Step(
        "terrain",
        "bench_render.py",
        ("--terrain-only", "--frames", "40", "--size", "1280x720"),
        ("--terrain-only", "--frames", "2", "--size", "320x180", "--dem-samples", "257"),
        ("dem", "sample_on_off", "gl"),
        120,
    ),
    Step(
        "live",
        "bench_live.py",
        ("--seconds", "10", "--repeats", "1"),
        ("--seconds", "1.5", "--repeats", "1"),
        ("720p30 loss 0%", "1080p30 loss 0%"),
        150,
    ),
    Step(
        "registration",
        "bench_registration.py",
        ("--repeat", "1", "--no-fog", "--no-matchers"),
        ("--repeat", "1", "--no-fog", "--no-matchers", "--every-s", "20"),
        ("keyframes_per_s", "wall_s", "stage_s", "gl"),
        150,
    ),
    Step(
        "paged",
        "bench_paged.py",
        ("--every-s", "1", "--memory-mb", "64"),
        ("--every-s", "20", "--memory-mb", "64"),
        ("runs", "same"),
        100,
    ),
    _playback("1280x720", dry_one_clip=True),
    _playback("1920x1080", dry_one_clip=False),
)


def environment() -> dict:
    """The machine, the GPU and driver (nvidia-smi, where there is one) and the EGL context's
    GL strings, as the benchmarks will see them."""
    from app.render.context import create_offscreen_context
    from bench.common import machine

    ctx = create_offscreen_context()
    info = ctx.info
    gl = {k: info[f"GL_{k.upper()}"] for k in ("vendor", "renderer", "version")}
    ctx.release()
    out: dict = {"machine": machine(), "platform": platform.platform(), "gl": gl, "gpu": None}
    if shutil.which("nvidia-smi"):
        got = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        if got.returncode == 0 and got.stdout.strip():
            name, driver, memory = (v.strip() for v in got.stdout.splitlines()[0].split(","))
            out["gpu"] = {"name": name, "driver": driver, "memory": memory}
    return out


def is_software(gl: dict) -> bool:
    """Whether the GL strings name a software rasteriser (Mesa's llvmpipe, softpipe, swrast)."""
    return software_rasteriser(f"{gl.get('vendor', '')} {gl.get('renderer', '')}")


def has_display() -> bool:
    """An X display for the viewer's window: the current one, or Xvfb to start."""
    return bool(os.environ.get("DISPLAY")) or shutil.which("Xvfb") is not None


def run_step(step: Step, dry: bool, limit_s: float, log) -> dict:
    """Run one step in its own process; its result (see the module docstring)."""
    with tempfile.TemporaryDirectory(prefix=f"geofuse-{step.name}-") as tmp:
        out = Path(tmp) / "figures.json"
        args = step.dry if dry else step.full
        cmd = [sys.executable, str(ROOT / "bench" / step.script), *args, "--json", str(out)]
        log.write(f"\n===== {step.name}: {' '.join(cmd[1:])}\n")
        log.flush()
        env = dict(os.environ, PYTHONUNBUFFERED="1", XDG_CONFIG_HOME=str(Path(tmp) / "config"))
        t0 = time.perf_counter()
        try:
            done = subprocess.run(
                cmd,
                cwd=ROOT,
                env=env,
                stdout=log,
                stderr=subprocess.PIPE,
                text=True,
                timeout=limit_s,
            )
            code, err = done.returncode, done.stderr
        except subprocess.TimeoutExpired as exc:
            code = None
            err = (
                (exc.stderr or b"").decode(errors="replace")
                if isinstance(exc.stderr, bytes)
                else (exc.stderr or "")
            )
            err += f"\nstopped after its limit of {limit_s:.0f} s"
        seconds = time.perf_counter() - t0
        log.write(err[-4000:])
        log.flush()
        figures = json.loads(out.read_text()) if out.is_file() else None
    ok = code == 0 and figures is not None
    return {
        "ok": ok,
        "seconds": round(seconds, 1),
        "returncode": code,
        "args": list(args),
        "figures": figures,
        "error": None if ok else err.strip()[-1500:],
    }


def check(result: dict, dry: bool) -> list[str]:
    """What is wrong with a result's shape: environment strings, every step present, and each
    step that ran holding its figures' keys (empty where all is well). A full run may skip the
    window's steps where there is no display; a dry run may not."""
    problems = []
    env = result.get("environment") or {}
    for key in ("vendor", "renderer", "version"):
        if not (env.get("gl") or {}).get(key):
            problems.append(f"environment.gl.{key} missing")
    steps = result.get("steps") or {}
    for step in STEPS:
        got = steps.get(step.name)
        if got is None:
            problems.append(f"{step.name}: not run")
            continue
        if got.get("skipped"):
            if dry or not step.display:
                problems.append(f"{step.name}: skipped ({got['skipped']})")
            continue
        if not got.get("ok"):
            problems.append(f"{step.name}: failed ({(got.get('error') or '')[-300:]})")
            continue
        missing = [k for k in step.keys if k not in (got.get("figures") or {})]
        if missing:
            problems.append(f"{step.name}: figures lack {missing}")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="the JSON to write")
    parser.add_argument(
        "--log", type=Path, default=None, help="every step's output (default: stdout)"
    )
    parser.add_argument("--dry-run", action="store_true", help="tiny sizes; check the JSON's shape")
    parser.add_argument("--require-gpu", action="store_true", help="fail at once on a software GL")
    parser.add_argument("--only", default="", help="comma-separated step names (default: all)")
    parser.add_argument("--budget-s", type=float, default=480.0, help="stop starting steps after")
    parser.add_argument(
        "--limit-scale",
        type=float,
        default=1.0,
        help="multiply every step's time limit (the full sizes on llvmpipe, for the comparison)",
    )
    parser.add_argument("--check", type=Path, default=None, help="only check this JSON's shape")
    args = parser.parse_args(argv)
    if args.check is not None:
        problems = check(json.loads(args.check.read_text()), dry=False)
        print("\n".join(problems) or f"{args.check}: shape as expected")
        return 1 if problems else 0
    if args.out is None:
        parser.error("--out is required (or --check FILE)")
    wanted = [s for s in args.only.split(",") if s]
    unknown = sorted(set(wanted) - {s.name for s in STEPS})
    if unknown:
        parser.error(f"unknown steps {unknown}; the steps are {[s.name for s in STEPS]}")
    start = time.perf_counter()
    env = environment()
    print(
        f"GL: {env['gl']['renderer']} ({env['gl']['vendor']}, {env['gl']['version']}); GPU: {env['gpu']}"
    )
    result: dict = {
        "dry_run": args.dry_run,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "environment": env,
        "steps": {},
    }
    if args.require_gpu and is_software(env["gl"]):
        result["error"] = f"EGL gave a software renderer ({env['gl']['renderer']}), not the GPU"
        args.out.write_text(json.dumps(result, indent=2) + "\n")
        print(result["error"], file=sys.stderr)
        return 2
    log = args.log.open("a", encoding="utf-8") if args.log else sys.stdout
    for step in STEPS:
        if wanted and step.name not in wanted:
            continue
        left = args.budget_s - (time.perf_counter() - start)
        if step.display and not has_display():
            result["steps"][step.name] = {"skipped": "no X display and no Xvfb on this machine"}
        elif left < 20:
            result["steps"][step.name] = {
                "skipped": f"the run's budget of {args.budget_s:g} s was spent"
            }
        else:
            got = run_step(step, args.dry_run, min(args.limit_scale * step.limit_s, left), log)
            result["steps"][step.name] = got
            print(
                f"{step.name}: {'ok' if got['ok'] else 'FAILED'} in {got['seconds']:.0f} s",
                flush=True,
            )
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    result["seconds"] = round(time.perf_counter() - start, 1)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    if args.log:
        log.close()
    if wanted:
        return 0 if all(v.get("ok") for v in result["steps"].values()) else 1
    problems = check(result, args.dry_run)
    for p in problems:
        print(f"shape: {p}", file=sys.stderr)
    print(f"written {args.out} in {result['seconds']:.0f} s")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
