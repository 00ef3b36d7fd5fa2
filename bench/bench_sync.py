"""How well `geofuse sync` finds time offsets: the sample's video moved by known amounts (timed by
its gyroscope), and a simulated drone clip whose subtitle's GNSS track lags the video by known
amounts (timed by its course: no gyroscope, no gimbal angles). With --mavlink, the live feed's
lag estimator instead (app.live.lag): each 10 s window (every 2 s) of an autopilot's drone video fitted
against its MAVLink attitudes, on two weaves (the sample's lazy 12 s one and a 6 s one).

    python bench/bench_sync.py [--skip-sample] [--keep DIR] [--mavlink]

The drone clip is app.simulate.drone's (24 s over the sample site, weaving +-40 deg at 9 m/s),
rendered once into a temporary folder (or --keep DIR) and opened as a DJI clip would be.
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

from bench.common import table  # noqa: E402

SAMPLE_SHIFTS_S = (0.0, 0.25, -0.4, 0.1, -1 / 30, 0.017)
DRONE_LAGS_S = (0.0, 0.3, -0.2, 0.6, 0.017, -0.5)


def _ms(x: float) -> str:
    return f"{1000 * x:+.1f} ms"


def sample_rows() -> list[list[str]]:
    from app.session import open_session
    from app.simulate.sample import SAMPLE_DIR
    from app.sync import bearings_of, estimate_offset, gyro_rates, video_rates

    s = open_session(SAMPLE_DIR / "session.toml")
    t0 = time.perf_counter()
    rates = video_rates(s.video, bearings_of(s), s.rotation_cw)
    flow_s = time.perf_counter() - t0
    gyro = gyro_rates(s)
    truth = float(np.mean(s.truth_frame_times - s.frame_times))
    rows = []
    for shift in SAMPLE_SHIFTS_S:
        r = estimate_offset(rates, gyro, float(s.frame_times[0] - s.video.pts_s[0]) - shift)
        want = truth + shift
        rows.append(
            [
                "sample walk, gyroscope",
                _ms(shift),
                _ms(r.offset_s),
                _ms(want),
                f"{1000 * abs(r.offset_s - want):.1f} ms",
                f"{r.confidence:.3f}",
                str(len(r.windows)),
            ]
        )
    print(f"sample: optical flow over {len(s.video.pts_s)} frames took {flow_s:.1f} s")
    return rows


def drone_rows(folder: Path) -> list[list[str]]:
    from app.footage.clips import open_clip
    from app.simulate import drone
    from app.sync import bearings_of, estimate_offset, gyro_rates, video_rates

    video = folder / "DJI_0001.MP4"
    if not video.is_file():
        t0 = time.perf_counter()
        drone.write_video(video)
        print(f"drone: rendered {video} in {time.perf_counter() - t0:.1f} s")
    rates = None
    rows = []
    for lag in DRONE_LAGS_S:
        (folder / "DJI_0001.SRT").write_text(drone.srt_text(24.0, lag), encoding="utf-8")
        s = open_clip(video)
        if rates is None:
            rates = video_rates(s.video, bearings_of(s), s.rotation_cw)
        r = estimate_offset(rates, gyro_rates(s), float(s.frame_times[0] - s.video.pts_s[0]))
        rows.append(
            [
                "drone, GNSS course",
                _ms(lag),
                _ms(r.offset_s),
                _ms(lag),
                f"{1000 * abs(r.offset_s - lag):.1f} ms",
                f"{r.confidence:.3f}",
                str(len(r.windows)),
            ]
        )
    return rows


def _applied(offsets: list[float]) -> str:
    """The error (ms) of what the estimator has applied after each window: the median of the
    estimates whenever AGREEING of them agree with it (app.live.lag), kept until they next do;
    '-' before the first."""
    from app.live.lag import AGREE_S, AGREEING

    out, applied = [], None
    for k in range(1, len(offsets) + 1):
        o = np.array(offsets[:k])
        m = float(np.median(o))
        if np.sum(np.abs(o - m) <= AGREE_S) >= AGREEING:
            applied = m
        out.append("-" if applied is None else f"{1000 * abs(applied):.0f}")
    return " ".join(out) + " ms"


def mavlink_rows(folder: Path) -> list[list[str]]:
    """The live lag estimator's windows (app.live.lag.fit_window: WINDOW_S of video every
    EVERY_S) on an autopilot's drone, its telemetry made by app.simulate.autopilot on the boot
    clock (boot = media + BOOT_MS: the true offset is 0 once that is taken off)."""
    import functools

    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from app.camera.intrinsics import Intrinsics
    from app.io.mavlink import MavlinkTelemetry
    from app.io.video import probe
    from app.live.lag import EVERY_S, WINDOW_S, fit_window
    from app.simulate import autopilot, drone
    from app.sync.flow import video_rates
    from app.sync.rates import RateCurve, pinhole_bearings

    rows = []
    seconds = 24.0
    for name, period, weave in (
        ("12 s weave +-40 deg", 12.0, 40.0),
        ("6 s weave +-30 deg", 6.0, 30.0),
    ):
        flight = functools.partial(drone.flight, period_s=period, weave_deg=weave)
        video = folder / f"autopilot_{period:g}.ts"
        if not video.is_file():
            drone.write_video(video, seconds, (320, 180), path_of=flight)
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        telemetry = MavlinkTelemetry()
        for t in np.arange(0.0, seconds, 1.0 / autopilot.RATES_HZ["ATTITUDE"]):
            for kind in autopilot.RATES_HZ:
                for m in autopilot.messages_at(float(t), kind, "device", mav, flight):
                    telemetry.add(m.get_type(), m.to_dict(), float(t))
        info = probe(video)
        rates = video_rates(
            info, pinhole_bearings(Intrinsics.from_fov(320, 180, drone.HFOV_DEG)), 0
        )
        c = autopilot.BOOT_MS / 1000.0
        found, applied, refused = [], [], 0
        for start in np.arange(0.0, seconds - WINDOW_S + 1e-9, EVERY_S):
            sel = (rates.t >= start) & (rates.t < start + WINDOW_S)
            r = fit_window(RateCurve(rates.t[sel], rates.omega[sel]), telemetry, c)
            if isinstance(r, str) or r is None:
                refused += 1
                found.append("refused")
            else:
                found.append(f"{1000 * r.offset_s:+.0f}")
                applied.append(r.offset_s)
        rows.append(
            [
                name,
                " ".join(found) + " ms",
                str(refused),
                f"{1000 * float(np.median(np.abs(applied))):.0f} ms" if applied else "-",
                _applied(applied),
            ]
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-sample", action="store_true")
    parser.add_argument("--keep", type=Path, help="render the drone clip here (and reuse it)")
    parser.add_argument(
        "--mavlink", action="store_true", help="the live MAVLink lag estimator instead"
    )
    args = parser.parse_args(argv)
    if args.mavlink:
        with tempfile.TemporaryDirectory() as tmp:
            rows = mavlink_rows(args.keep or Path(tmp))
        print("# the live MAVLink lag estimator, window by window (true lag: 0)\n")
        print(
            table(
                [
                    "flight",
                    "each window's offset (true: 0)",
                    "refused",
                    "median error",
                    "applied after each window: error",
                ],
                rows,
            )
        )
        return 0
    rows = [] if args.skip_sample else sample_rows()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        rows += drone_rows(args.keep)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            rows += drone_rows(Path(tmp))
    print("# time offsets found by geofuse sync\n")
    print(
        table(
            [
                "clip, timed by",
                "moved / lagged by",
                "found",
                "expected",
                "error",
                "confidence",
                "windows",
            ],
            rows,
        )
    )
    errors = [float(r[4].split()[0]) for r in rows]
    print(f"\nlargest error {max(errors):.1f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
