"""Where the time goes on a long log, measured side by side in one run (the machines are noisy:
compare the ratios, not the seconds).

    python benchmarks/bench_io.py [--seconds 60] [--rate-hz 1000]

Builds a synthetic 7-joint JointState log at --rate-hz in a temporary folder, then times:
raw MCAP iteration (no decoding), rosbags decoding, twincd's read_log, the twin (RNEA per
sample) and a whole `simulate` (read + twin + lossless copy + new channel), each as a ratio to
rosbags decoding alone — the floor any rosbags-based reader pays.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from twincd.io.cdr import JOINT_STATE, joint_state_cdr
from twincd.io.mcap import McapLogWriter
from twincd.io.sources import open_reader
from twincd.prepare.setup import read_log
from twincd.prepare.simulate import simulate_log
from twincd.twin.dynamics import simulate_effort
from twincd.twin.robot import load_robot


def build_log(path: Path, seconds: float, rate_hz: float) -> int:
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    q = 0.5 * np.sin(2 * np.pi * 0.2 * t[:, None] + np.arange(7))
    qd = 0.5 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t[:, None] + np.arange(7))
    stamps = 1_700_000_000_000_000_000 + (t * 1e9).astype(np.int64)
    names = [f"joint{i}" for i in range(1, 8)]
    with McapLogWriter(path) as out:
        channel = out.add_topic("/joint_states", JOINT_STATE)
        for stamp, data in zip(stamps, joint_state_cdr(stamps, names, q, qd, np.zeros_like(q))):
            out.write(channel, int(stamp), data)
    return n


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "long.mcap"
        n = build_log(log, args.seconds, args.rate_hz)

        def raw_iteration() -> None:
            with open(log, "rb") as f:
                for _ in make_reader(f).iter_messages(log_time_order=False):
                    pass

        def rosbags_decode() -> None:
            reader = open_reader(log)
            for conn, _, raw in reader.messages():
                reader.deserialize(raw, conn.msgtype)
            reader.close()

        states = read_log(log)
        robot = load_robot("xarm7", states.joint_names)
        stages = {
            "raw MCAP iteration": raw_iteration,
            "rosbags decode": rosbags_decode,
            "read_log": lambda: read_log(log),
            "twin (RNEA)": lambda: simulate_effort(robot, states),
            "simulate (whole)": lambda: simulate_log(log, Path(tmp) / "out.mcap", "xarm7"),
        }
        seconds = {name: timed(fn) for name, fn in stages.items()}
    floor = seconds["rosbags decode"]
    print(f"{n} samples ({args.seconds:g} s at {args.rate_hz:g} Hz)")
    for name, s in seconds.items():
        print(f"  {name:20s} {s:7.2f} s  {n / s:9.0f} samples/s  {s / floor:5.2f} × rosbags decode")


if __name__ == "__main__":
    main()
