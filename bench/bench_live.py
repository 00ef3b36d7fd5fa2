"""Live benchmark: a drone's downlink (app.simulate.feed: H.264 MPEG-TS with a KLV set per frame)
sent over the loopback in real time, paced by its program clock, to `geofuse live`'s pipeline
(app.live.run: receive, record, decode, jitter buffer, draw off screen at 1280x720), at 720p30
and 1080p30, with 0 % and 5 % of the datagrams dropped.

Latency is taken two ways, both ending when the frame's drawing has finished (the GPU waited
for): from the frame's arrival in geofuse (the demuxer handing its packet over), and from the
moment its last datagram left the sender (the same clock, the same process: what the network
and FFmpeg's demuxer add is included). "Past the buffer" is from the jitter buffer's due time.
Joining, the demuxer hands over what it read while probing in one burst, which the display plays
out 25 % fast (app.live.buffer): the figures "from 4 s on" leave that catching-up out.
Frames lost by geofuse are those that arrived and were not drawn (the display behind, late,
overflow); frames lost by the network are counted apart. Medians over --repeats runs.

    python bench/bench_live.py [--seconds 15] [--repeats 3] [--buffer-ms 100]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.live.run import LiveOptions, run_live  # noqa: E402
from app.simulate.feed import Sender, free_udp_port, sending_clock, write_feed  # noqa: E402
from bench.common import machine, table, write_json  # noqa: E402

JOIN_S = 4.0  # the first seconds after joining, while the display catches up the probe's burst


def one_run(feed: Path, loss: float, seconds: float, buffer_ms: float, seed: int) -> dict:
    """One feed sent and received; the figures of that run."""
    port = free_udp_port()
    sender = Sender(feed.read_bytes(), ("127.0.0.1", port), loss=loss, seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        run = run_live(
            f"udp://127.0.0.1:{port}",
            LiveOptions(
                seconds=seconds + 4.0,
                silence_s=2.0,
                delay_s=buffer_ms / 1000.0,
                record=Path(tmp) / "rec.ts",
            ),
            clock=sending_clock(sender, port),
        )
    sender.stop()
    origin = run.origin_s or 0.0
    from_sender = []
    first = run.drawn[0].drawn_s if run.drawn else 0.0
    steady = [1000.0 * (d.drawn_s - d.arrival_s) for d in run.drawn if d.drawn_s - first >= JOIN_S]
    for d in run.drawn:
        sent = sender.sent.get(int(round((d.pts_s + origin) * 90000)))
        if sent is not None:
            from_sender.append(1000.0 * (d.drawn_s - sent))
    return {
        "received": run.received,
        "drawn": len(run.drawn),
        "lost_by_geofuse": run.skipped + run.late + run.overflow,
        "lost_by_network": run.missing,
        "datagrams_dropped": sender.dropped,
        "arrival_p50_ms": run.latency_ms(50),
        "arrival_p95_ms": run.latency_ms(95),
        "steady_p50_ms": float(np.percentile(steady, 50)) if steady else float("nan"),
        "steady_p95_ms": float(np.percentile(steady, 95)) if steady else float("nan"),
        "added_p50_ms": run.added_ms(50),
        "added_p95_ms": run.added_ms(95),
        "sender_p50_ms": float(np.percentile(from_sender, 50)) if from_sender else float("nan"),
        "sender_p95_ms": float(np.percentile(from_sender, 95)) if from_sender else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--buffer-ms", type=float, default=100.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="geofuse-bench-live-"))
    results = {}
    rows = []
    for name, size in (("720p30", (1280, 720)), ("1080p30", (1920, 1080))):
        feed = write_feed(folder / f"{name}.ts", args.seconds, size, crf=23)
        for loss in (0.0, 0.05):
            runs = [
                one_run(feed, loss, args.seconds, args.buffer_ms, seed)
                for seed in range(args.repeats)
            ]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            results[f"{name} loss {loss:.0%}"] = {"median": med, "runs": runs}
            rows.append(
                [
                    name,
                    f"{loss:.0%}",
                    f"{med['received']:.0f}",
                    f"{med['lost_by_network']:.0f}",
                    f"{med['lost_by_geofuse']:.0f}",
                    f"{med['arrival_p50_ms']:.1f} / {med['arrival_p95_ms']:.1f}",
                    f"{med['steady_p50_ms']:.1f} / {med['steady_p95_ms']:.1f}",
                    f"{med['added_p50_ms']:.1f} / {med['added_p95_ms']:.1f}",
                    f"{med['sender_p50_ms']:.1f} / {med['sender_p95_ms']:.1f}",
                ]
            )
            print(rows[-1], flush=True)
    print(
        f"\n{machine()}; {args.seconds:g} s a run, median of {args.repeats} runs, buffer {args.buffer_ms:g} ms, drawn at 1280x720\n"
    )
    print(
        table(
            [
                "feed",
                "datagrams lost",
                "frames received",
                "lost by the network",
                "lost by geofuse",
                "arrival -> drawn p50 / p95 ms",
                f"the same from {JOIN_S:g} s on",
                "past the buffer p50 / p95 ms",
                "sender -> drawn p50 / p95 ms",
            ],
            rows,
        )
    )
    write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
