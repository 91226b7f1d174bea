"""Latency of ``twincd watch`` on a Foxglove WebSocket source, at 100 Hz and 1 kHz.

For each rate, a synthetic xArm 7 set (``twincd synth``: three training paths, one validation
and one test path of 20–25 s) is calibrated as a user would for ``watch`` (``twincd fit
--causal``, the default model; ``twincd threshold``); a foxglove_sdk server in a child process
replays the test path at its recorded rate, and ``twincd.watch`` scores it. Per message, the
latency is the time from its arrival at the client (taken off the WebSocket) to its score (the
reorder window's hold, the coarse grid's hold at 1 kHz, and the chain's work); the summary's
``latency_ms`` gives its p50, p95, p99 and maximum. The causal filter's own delay
(``filter_delay_ms``: how late a step shows in the score) comes on top. No assertion: figures
only. Needs foxglove-sdk (the dev extra).

    python benchmarks/bench_watch.py                         # 100 Hz and 1 kHz, ~5 min
    python benchmarks/bench_watch.py --rates 1000 --seconds 20 --workdir /tmp/bench-watch
    python benchmarks/bench_watch.py --log LOG.mcap -c CAUSAL_CAL.json   # your own log
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

TESTS = Path(__file__).resolve().parent.parent / "tests"


def twincd(*args: object) -> None:
    cmd = [sys.executable, "-m", "twincd_cli.main", *map(str, args), "-q"]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def prepare(folder: Path, rate_hz: int) -> tuple[Path, Path]:
    """(test log, causal calibration) at ``rate_hz``, built once in ``folder``."""
    cal = folder / "causal.json"
    if not cal.exists():
        lengths = ("--min-duration", "20", "--max-duration", "25")
        counts = ("--train", "3", "--val", "1", "--test", "1")
        twincd("synth", folder, "--seed", "1", *counts, *lengths, "--rate-hz", rate_hz)
        twincd("fit", folder / "train", "-o", cal, "--causal")
        twincd("threshold", folder / "val", "-c", cal)
    return next((folder / "test").glob("*.mcap")), cal


def serve(log: str, speed: float, url: Any, stop: Any) -> None:
    """The replaying server, in its own process (its publishing does not share our GIL)."""
    sys.path.insert(0, str(TESTS))
    from support.replay import Replay

    with Replay(Path(log), speed=speed, loop=True) as replay:
        url.put(replay.url)
        stop.wait()


def measure(
    log: Path, cal: Path, seconds: float, speed: float, reorder_ms: float
) -> dict[str, Any]:
    from twincd.live import WatchSummary, watch

    ctx = mp.get_context("spawn")
    url, stop = ctx.Queue(), ctx.Event()
    server = ctx.Process(target=serve, args=(str(log), speed, url, stop), daemon=True)
    server.start()
    try:
        items = list(
            watch(
                url.get(timeout=60),
                cal,
                duration_s=seconds,
                connect_timeout_s=30,
                reorder_ns=int(reorder_ms * 1e6),
            )
        )
    finally:
        stop.set()
        server.join(10)
    summary = items[-1]
    assert isinstance(summary, WatchSummary)
    return {
        "log": log.name,
        "samples": summary.samples,
        "rate_hz": round(summary.samples / max(summary.elapsed_s, 1e-9), 1),
        "reorder_ms": reorder_ms,
        "latency_ms": summary.latency_ms,
        "filter_delay_ms": summary.filter_delay_ms,
        "late": summary.late,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--rates", default="100,1000", help="joint-state rates (Hz) of the synth logs")
    p.add_argument("--workdir", type=Path, help="build (or reuse) the logs here")
    p.add_argument("--log", type=Path, help="measure on this log instead")
    p.add_argument("-c", "--calibration", type=Path, help="its causal calibration (with --log)")
    p.add_argument("--seconds", type=float, default=15.0, help="how long to watch each")
    p.add_argument("--speed", type=float, default=1.0, help="replay this much faster")
    p.add_argument("--reorder-ms", type=float, default=20.0)
    p.add_argument("--json", type=Path, help="also write the figures here")
    a = p.parse_args()
    runs: list[tuple[str, Path, Path]] = []
    with tempfile.TemporaryDirectory(prefix="bench-watch-") as tmp:
        if a.log is not None:
            if a.calibration is None:
                p.error("--log needs -c")
            runs.append((a.log.name, a.log, a.calibration))
        else:
            root = a.workdir or Path(tmp)
            for rate in (int(r) for r in a.rates.split(",")):
                folder = root / f"{rate}hz"
                folder.mkdir(parents=True, exist_ok=True)
                runs.append((f"{rate} Hz", *prepare(folder, rate)))
        results = []
        for name, log, cal in runs:
            result = {"run": name, **measure(log, cal, a.seconds, a.speed, a.reorder_ms)}
            results.append(result)
            print(json.dumps(result), flush=True)
    print(f"\n{'run':>8}  {'rate Hz':>8}  {'p50 ms':>7}  {'p99 ms':>7}  {'max ms':>7}  filter ms")
    for r in results:
        lat = r["latency_ms"]
        print(
            f"{r['run']:>8}  {r['rate_hz']:8.1f}  {lat.get('p50', float('nan')):7.2f}  "
            f"{lat.get('p99', float('nan')):7.2f}  {lat.get('max', float('nan')):7.2f}  "
            f"{r['filter_delay_ms']:.1f}"
        )
    if a.json is not None:
        a.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
