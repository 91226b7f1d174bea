"""Does ``twincd synth`` make long logs in flat memory? One path per length at 1 kHz, each as
its own process, with its wall time and peak resident set.

    python benchmarks/bench_synth.py                    # 10 and 60 min (≈ 3 min on 2 cores)
    python benchmarks/bench_synth.py --minutes 1,10     # quicker

Columns: ``s`` wall seconds (start-up included); ``RSS MB`` the process's peak resident set
(``os.wait4`` ru_maxrss; MB = 10⁶ bytes); ``samples`` the /joint_states messages of the file
(from its MCAP summary statistics). The last line is the RSS of the longest over the shortest:
≈ 1 when memory does not grow with the length. Exits 1 if a run fails, a file misses samples,
or a peak RSS passes --max-rss-mb (default 300).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


def run(argv: list[str]) -> tuple[int, float, float]:
    """(exit code, wall seconds, peak RSS MB) of one command, its stdout discarded."""
    start = time.perf_counter()
    pid = os.posix_spawnp(
        argv[0],
        argv,
        os.environ,
        file_actions=[(os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0)],
    )
    _, status, usage = os.wait4(pid, 0)
    return os.waitstatus_to_exitcode(status), time.perf_counter() - start, usage.ru_maxrss * 1024e-6


def joint_states(path: Path) -> int:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        return 0
    counts = summary.statistics.channel_message_counts
    return sum(n for cid, n in counts.items() if summary.channels[cid].topic == "/joint_states")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", default="10,60", help="path lengths, comma-separated")
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--max-rss-mb", type=float, default=300.0)
    args = parser.parse_args()
    minutes = [float(m) for m in args.minutes.split(",")]
    failed = False
    peaks = []
    print(f"{'min':>6} {'s':>8} {'RSS MB':>8} {'samples':>10}")
    with tempfile.TemporaryDirectory(prefix="bench-synth-") as tmp:
        for length in minutes:
            out = Path(tmp) / f"m{length:g}"
            seconds = f"{length * 60:g}"
            code, wall, rss = run(
                ["twincd", "synth", str(out), "--seed", str(args.seed), "--train", "1",
                 "--val", "0", "--test", "0", "--min-duration", seconds, "--max-duration",
                 seconds, "--rate-hz", f"{args.rate_hz:g}", "--no-rosbag2-copy", "-q"]
            )  # fmt: skip
            log = out / "train" / "train_000.mcap"
            samples = joint_states(log) if code == 0 and log.exists() else 0
            expected = int(length * 60 * args.rate_hz) + 1
            ok = code == 0 and samples == expected and rss <= args.max_rss_mb
            failed |= not ok
            peaks.append(rss)
            print(f"{length:>6g} {wall:>8.1f} {rss:>8.0f} {samples:>10,}{'' if ok else '  ✗'}")
            log.unlink(missing_ok=True)
    if len(peaks) > 1:
        print(f"peak RSS {minutes[-1]:g} min / {minutes[0]:g} min: {peaks[-1] / peaks[0]:.2f}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
