"""README's picture of a spoofed flight (docs/spoofed.png, issue 52): a drone orbiting the sample
site (`geofuse simulate session --flight orbit`, its video rendered from a world that differs
from the model) whose GNSS is dragged east from 20 s on (app.simulate.lies: a spoofer walking
the receiver off), opened in `geofuse view` in a private Xvfb under the `registered` source: the
receiver's track (white, then red where rejected) walks away from the orbit while the track the
scene made (cyan) stays on it and the video stays on the hall; the timeline's band turns red and
the Stats panel names the lie.

    python tools/spoof_screenshot.py [--out docs/spoofed.png] [--at 48] [--speed 3]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.simulate.lies import Lie, falsify  # noqa: E402
from app.simulate.sample import SAMPLE_SCENE  # noqa: E402
from app.simulate.session import SampleConfig, write_sample_session  # noqa: E402
from bench.bench_playback import Display  # noqa: E402

SIZE = "1280x720"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "spoofed.png")
    p.add_argument("--seconds", type=float, default=60.0, help="the clip's length")
    p.add_argument("--from-s", type=float, default=20.0, help="when the drag begins (clip s)")
    p.add_argument("--speed", type=float, default=3.0, help="the drag's speed, m/s east")
    p.add_argument("--at", type=float, default=48.0, help="the frame shown (media s)")
    p.add_argument("--look", default="-60,-260,230 -20,0,0", help="the window camera: EYE TARGET")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="geofuse-spoofed-") as tmp:
        d = Path(tmp)
        write_sample_session(
            d / "clean",
            SAMPLE_SCENE,
            replace(SampleConfig(), duration_s=args.seconds, flight="orbit"),
        )
        manifest = falsify(
            d / "clean", d / "drag", Lie("drag", from_s=args.from_s, speed_mps=args.speed)
        )
        script = d / "script.txt"
        script.write_text(
            f"""0 clock 0.0333333
0 wait registered
0 source registered
0 seek {args.at}
0 pause
0.1 look {args.look}
0.5 screenshot {args.out.resolve()}
0.6 quit
"""
        )
        with Display() as display:
            env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(d / "config"))
            done = subprocess.run(
                [sys.executable, "-m", "app", "view", str(manifest), "--script", str(script)]
                + ["--size", SIZE],
                cwd=ROOT,
                env=env,
                capture_output=True,
                text=True,
            )
        sys.stderr.write(done.stderr[-4000:])
        if done.returncode != 0:
            return done.returncode
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
