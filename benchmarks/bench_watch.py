"""Latency of ``twincd watch`` on a Foxglove WebSocket source, measured in one process.

A foxglove_sdk server replays a log at its recorded rate (``--speed 1``) and ``twincd.watch``
scores it; the summary's ``latency_ms`` is the time from a message's arrival at the client to
its score (the reorder window's hold plus the chain's work); the causal filter's delay
(``filter_delay_ms``) comes on top. Needs foxglove-sdk (the dev extra).

    python benchmarks/bench_watch.py LOG.mcap -c CAUSAL_CAL.json [--seconds 10] [--reorder-ms 20]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))


def main() -> None:
    from support.replay import Replay

    from twincd.live import WatchSummary, watch

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("log", type=Path)
    p.add_argument("-c", "--calibration", type=Path, required=True)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--reorder-ms", type=float, default=20.0)
    a = p.parse_args()
    with Replay(a.log, speed=a.speed) as replay:
        items = list(
            watch(
                replay.url,
                a.calibration,
                duration_s=a.seconds,
                idle_timeout_s=1.0,
                reorder_ns=int(a.reorder_ms * 1e6),
            )
        )
    summary = items[-1]
    assert isinstance(summary, WatchSummary)
    rate = summary.samples / max(summary.elapsed_s, 1e-9)
    out = {
        "samples": summary.samples,
        "rate_hz": round(rate, 1),
        "reorder_ms": a.reorder_ms,
        "latency_ms": summary.latency_ms,
        "filter_delay_ms": summary.filter_delay_ms,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
