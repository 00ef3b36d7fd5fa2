"""README's picture of the browser map beside the viewer during a live feed (docs/share.png):
an autopilot's drone (the sample site seen from a weaving flight, its MAVLink telemetry beside
the video: `geofuse simulate feed --mavlink`) sent over the loopback to `geofuse view URL` in a
private Xvfb; the viewer's script turns Share on once the feed is drawn, headless Chromium opens
the map's URL, and both are captured together, then put side by side (tools/side_by_side.py).

    python tools/share_screenshot.py [--out docs/share.png] [--width 800]
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

from PIL import Image
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.simulate import drone  # noqa: E402
from app.simulate.autopilot import MavlinkSender  # noqa: E402
from app.simulate.feed import Sender, free_udp_port, port_held  # noqa: E402
from bench.bench_playback import Display  # noqa: E402
from tools.side_by_side import labelled  # noqa: E402

SIZE = (1280, 720)
FEED_S = 60.0
MAVLINK_LEAD_S = 0.3  # the telemetry leaves this much ahead of its video (as `simulate feed`)


def wait_for(path: Path, proc: subprocess.Popen, limit_s: float = 300.0) -> None:
    end = time.monotonic() + limit_s
    while not path.is_file():
        if proc.poll() is not None or time.monotonic() > end:
            raise SystemExit(f"the viewer ended or took too long before writing {path.name}")
        time.sleep(0.1)
    time.sleep(0.3)  # written whole


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "share.png")
    parser.add_argument("--width", type=int, default=800, help="pixels, each half")
    args = parser.parse_args(argv)
    with Display() as display, tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        clip = drone.write_video(d / "drone.ts", FEED_S, (640, 360))
        video, telemetry = free_udp_port(), free_udp_port()
        script = d / "script.txt"
        script.write_text(
            f"""0.0 wait live 45
0.0 lines off
0.0 share on
0.0 state {d / "url.json"}
0.0 share wait
4.0 screenshot {d / "viewer.png"}
4.0 state {d / "shot.json"}
10.0 quit
"""
        )
        env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(d / "config"))
        viewer = subprocess.Popen(
            [sys.executable, "-m", "app", "view", f"udp://127.0.0.1:{video}", "--mavlink",
             f"udp:127.0.0.1:{telemetry}", "--script", str(script), "--size", f"{SIZE[0]}x{SIZE[1]}"],
            cwd=d, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        end = time.monotonic() + 120.0
        while not port_held(video) and time.monotonic() < end:  # the viewer listens first
            time.sleep(0.05)
        sender = Sender(clip.read_bytes(), ("127.0.0.1", video))
        mavlink = MavlinkSender(("127.0.0.1", telemetry), FEED_S, time.monotonic(), MAVLINK_LEAD_S)
        mavlink.start()
        sender.start()
        browser = None
        try:
            wait_for(d / "url.json", viewer)
            info = json.loads((d / "url.json").read_text())["info"]
            url = next(n.split(" at ", 1)[1] for n in info if "the browser map is at" in n)
            options = webdriver.ChromeOptions()
            options.binary_location = shutil.which("chromium")
            for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"):
                options.add_argument(arg)
            options.add_argument(f"--window-size={SIZE[0]},{SIZE[1]}")
            browser = webdriver.Chrome(
                service=Service(shutil.which("chromedriver")), options=options
            )
            browser.execute_cdp_cmd(  # the page's own size, whatever the window's frame takes
                "Emulation.setDeviceMetricsOverride",
                {"width": SIZE[0], "height": SIZE[1], "deviceScaleFactor": 1, "mobile": False},
            )
            browser.get(url)
            wait_for(d / "viewer.png", viewer)
            browser.save_screenshot(str(d / "map.png"))
            _, err = viewer.communicate(timeout=120)
            if viewer.returncode != 0:
                raise SystemExit(f"the viewer failed:\n{err[-3000:]}")
        finally:
            if browser is not None:
                browser.quit()
            sender.stop()
            mavlink.stop()
            if viewer.poll() is None:
                viewer.kill()
                viewer.wait()
        left = labelled(d / "viewer.png", "the viewer: the live feed draped, Share on", args.width)
        right = labelled(d / "map.png", "a browser: the map it serves", args.width)
        gap = 8
        out = Image.new("RGB", (2 * args.width + gap, max(left.height, right.height)), "white")
        out.paste(left, (0, 0))
        out.paste(right, (args.width + gap, 0))
        out = out.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        out.save(args.out, optimize=True)
        print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
