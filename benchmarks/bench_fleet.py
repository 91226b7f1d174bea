"""Fleet benchmark: ``fit`` and ``detect`` over 40 sample-sized logs with ``-j 1``, ``-j 2`` and
``--scheduler local`` in one run, speed-up ratios, and a paper estimate for a 100 000-log fleet
on a 32-worker cluster from the measured per-log cost and result sizes.

    python benchmarks/bench_fleet.py                        # 40 logs, best of 2 per command
    python benchmarks/bench_fleet.py --logs 80 --repeats 3 --json fleet.json

What it does, in one run:

1. Builds the fleet: copies of sample_logs/{train,val,test}/*.mcap (17 xArm 7 logs of 20–35 s
   at 100 Hz, ≈ 2000–3500 samples each), cycled to --logs files in a temporary folder.
2. Times each command as its own subprocess, as a user runs it (start-up included): ``twincd
   fit FLEET -o CAL``, ``twincd detect FLEET -c sample_logs/calibration.json`` and the same with
   ``-o FOLDER`` (outputs written by the workers), each with ``-j 1``, ``-j 2`` and
   ``--scheduler local`` (a LocalCluster of one worker process per core, started and stopped
   inside the command). Executors are interleaved within each repeat (noise hits them alike);
   the best of --repeats counts. ``twincd --version`` is timed too: the fixed start-up cost.
3. Checks that every executor gives the same answer: the calibration's a, b (to 1e-12
   relative) and ``detect --json`` (equal).
4. Measures the per-log cost in this process (``fit_log`` and ``detect_streamed``, one log after
   another, one twin thread, after a warm-up) and the pickled size of each per-log result
   (what travels back from a worker), and prints the estimate.

Ratios are ``s(-j 1) / s(executor)``: higher is faster. The goal for ``-j 2`` is ≥ 1.7× on a
2-core machine. Note the automatic rule: with ``-j 0`` (the default) a run of fewer than 8 small
logs stays in this process, so small runs never pay for a pool; this benchmark always names
the executor. The machines are shared and noisy: compare ratios within one run. Exits 1 when a
command fails or the executors disagree.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "sample_logs"
TWINCD = [sys.executable, "-m", "twincd_cli.main"]
EXECUTORS = {"-j 1": ["-j", "1"], "-j 2": ["-j", "2"], "local cluster": ["--scheduler", "local"]}
GOAL_J2 = 1.7

# the cluster the estimate is for, and what it assumes beyond this machine's measurements
FLEET_LOGS = 100_000
FLEET_WORKERS = 32
SCHEDULER_S_PER_TASK = 0.001  # Dask's documented order of overhead per task, at the scheduler
CLIENT_BYTES_PER_S = 100e6  # results arriving at the client over a 1 Gb/s link
STORAGE_BYTES_PER_S = 1e9  # aggregate read bandwidth of the shared storage


def build_fleet(folder: Path, count: int) -> list[Path]:
    sources = sorted(
        p for split in ("train", "val", "test") for p in (SAMPLES / split).glob("*.mcap")
    )
    folder.mkdir(parents=True)
    logs = []
    for i in range(count):
        target = folder / f"log_{i:03d}.mcap"
        shutil.copyfile(sources[i % len(sources)], target)
        logs.append(target)
    return logs


def timed(
    args: list[str], ok: tuple[int, ...] = (0,)
) -> tuple[float, subprocess.CompletedProcess[str]]:
    start = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, timeout=900)
    seconds = time.perf_counter() - start
    if done.returncode not in ok or "Traceback" in done.stderr:
        sys.stderr.write(f"FAILED ({done.returncode}): {' '.join(args)}\n{done.stderr}\n")
        raise SystemExit(1)
    return seconds, done


def commands(fleet: Path, work: Path, name: str) -> dict[str, tuple[list[str], tuple[int, ...]]]:
    tag = name.replace(" ", "_")
    cal = SAMPLES / "calibration.json"
    out = work / f"out_{tag}"
    return {
        "fit": ([*TWINCD, "fit", str(fleet), "-o", str(work / f"cal_{tag}.json"), "-q"], (0,)),
        "detect": ([*TWINCD, "detect", str(fleet), "-c", str(cal), "--json", "-q"], (0, 1)),
        "detect -o": (
            [*TWINCD, "detect", str(fleet), "-c", str(cal), "-o", str(out), "-q"],
            (0, 1),
        ),
    }


def phase_seconds(command: str, executor: str, fleet: Path) -> float:
    """Seconds of the fleet phase of ``command`` on ``executor``, in this process: the per-log
    map (a local pool's start included) and the merge, after the imports every executor pays
    alike (a command's interpreter and module start-up, which no executor can share out).
    A Dask cluster is started, and its workers warmed on two logs, before the clock starts: a
    cluster outlives one run."""
    import importlib

    from twincd.calibration import Calibration, fit_log, merge_fits
    from twincd.cluster import open_executor
    from twincd.detection import detect_streamed
    from twincd.executors import PRELOAD, Bound
    from twincd.pipeline import Setup

    for module in PRELOAD:
        importlib.import_module(module)
    paths = sorted(fleet.glob("*.mcap"))
    jobs, scheduler = (0, "local") if executor == "local cluster" else (int(executor[-1]), None)
    cal = Calibration.load(SAMPLES / "calibration.json")
    with open_executor(jobs, scheduler, paths) as pool:
        if scheduler:
            pool.map(Bound(fit_log, Setup()), paths[:2])
        start = time.perf_counter()
        if command == "fit":
            setup = Setup()
            merge_fits(pool.map(Bound(fit_log, setup), paths), setup)
        else:
            pool.map(Bound(detect_streamed, cal, Setup.from_calibration(cal)), paths)
        return time.perf_counter() - start


def per_log_costs(logs: list[Path]) -> dict[str, dict[str, float]]:
    """Seconds per log (one core) and pickled result bytes, fit and detect, in this process."""
    os.environ["TWINCD_TWIN_THREADS"] = "1"  # one core's worth, as on a worker
    from twincd.calibration import Calibration, fit_log
    from twincd.detection import detect_streamed
    from twincd.pipeline import Setup

    cal = Calibration.load(SAMPLES / "calibration.json")
    fit_setup, detect_setup = Setup(), Setup.from_calibration(cal)
    steps = {
        "fit": lambda p: fit_log(p, fit_setup),
        "detect": lambda p: detect_streamed(p, cal, detect_setup),
    }
    costs = {}
    for name, step in steps.items():
        step(logs[0])  # warm-up: imports, robot model
        start = time.perf_counter()
        results = [step(p) for p in logs]
        seconds = (time.perf_counter() - start) / len(logs)
        size = sum(len(pickle.dumps(r)) for r in results) / len(results)
        costs[name] = {"s_per_log": seconds, "result_bytes": size}
    return costs


def estimate(costs: dict[str, dict[str, float]], log_bytes: float) -> list[str]:
    lines = [
        f"paper estimate: {FLEET_LOGS:,} logs like these on {FLEET_WORKERS} one-core workers",
        f"  assumptions: {SCHEDULER_S_PER_TASK * 1e3:g} ms scheduler time per task, results at "
        f"{CLIENT_BYTES_PER_S / 1e6:g} MB/s to the client, shared storage at "
        f"{STORAGE_BYTES_PER_S / 1e9:g} GB/s, {log_bytes / 1e6:.2f} MB per log",
    ]
    for name, cost in costs.items():
        compute = FLEET_LOGS * cost["s_per_log"] / FLEET_WORKERS
        scheduler = FLEET_LOGS * SCHEDULER_S_PER_TASK
        results = FLEET_LOGS * cost["result_bytes"] / CLIENT_BYTES_PER_S
        storage = FLEET_LOGS * log_bytes / STORAGE_BYTES_PER_S
        bound = max(compute, scheduler, results, storage)
        limit = {compute: "compute", scheduler: "scheduler", results: "results", storage: "storage"}
        lines.append(
            f"  {name:7s} {cost['s_per_log'] * 1e3:7.1f} ms/log, result "
            f"{cost['result_bytes'] / 1e3:6.1f} kB: compute {compute / 60:6.1f} min, scheduler "
            f"{scheduler / 60:4.1f} min, results {results:5.1f} s "
            f"({FLEET_LOGS * cost['result_bytes'] / 1e6:,.0f} MB), storage {storage / 60:4.1f} min"
            f" → ≈ {bound / 60:.1f} min ({limit[bound]}-bound)"
        )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    # internal: one fleet-phase measurement, in a process of its own (prints seconds)
    parser.add_argument("--phase", nargs=3, metavar=("COMMAND", "EXECUTOR", "FLEET"))
    args = parser.parse_args()
    if args.phase:
        command, executor, fleet = args.phase
        print(phase_seconds(command, executor, Path(fleet)))
        return 0

    with tempfile.TemporaryDirectory(prefix="twincd-fleet-") as tmp:
        work = Path(tmp)
        logs = build_fleet(work / "fleet", args.logs)
        log_bytes = sum(p.stat().st_size for p in logs) / len(logs)
        print(f"{len(logs)} logs, {log_bytes / 1e6:.2f} MB each on average; {os.cpu_count()} cores")
        best: dict[tuple[str, str], float] = {}
        outputs: dict[tuple[str, str], str] = {}
        startup = min(timed([*TWINCD, "--version"])[0] for _ in range(3))
        for _ in range(args.repeats):
            for command in ("fit", "detect", "detect -o"):
                for name in EXECUTORS:
                    cmd, ok = commands(work / "fleet", work, name)[command]
                    shutil.rmtree(work / f"out_{name.replace(' ', '_')}", ignore_errors=True)
                    seconds, done = timed([*cmd, *EXECUTORS[name]], ok)
                    best[command, name] = min(seconds, best.get((command, name), seconds))
                    outputs[command, name] = done.stdout
            for command in ("fit", "detect"):
                for name in EXECUTORS:
                    cmd = [sys.executable, __file__, "--phase", command, name, str(work / "fleet")]
                    seconds = float(timed(cmd)[1].stdout.split()[-1])
                    best[f"{command} phase", name] = min(
                        seconds, best.get((f"{command} phase", name), seconds)
                    )
        agree = check_agreement(work, outputs)
        costs = per_log_costs(logs)

    print(f"\nstart-up (twincd --version, best of 3): {startup:.2f} s")
    header = f"{'command':12s}" + "".join(f"{n:>16s}" for n in EXECUTORS) + "   ratios vs -j 1"
    print(header)
    ratios: dict[str, dict[str, float]] = {}
    for command in ("fit", "detect", "detect -o", "fit phase", "detect phase"):
        row = f"{command:12s}" + "".join(f"{best[command, n]:15.2f}s" for n in EXECUTORS)
        serial = best[command, "-j 1"]
        ratios[command] = {n: serial / best[command, n] for n in EXECUTORS if n != "-j 1"}
        row += "   " + ", ".join(f"{n} {r:.2f}×" for n, r in ratios[command].items())
        print(row)
    print(
        "whole command: what a user waits for, start-up included; phase: the map over the logs"
        " and the merge, after the imports every executor pays alike"
    )
    for command in ("fit phase", "detect phase", "fit", "detect"):
        r = ratios[command]["-j 2"]
        print(f"goal -j 2 ≥ {GOAL_J2}× on {command}: {r:.2f}× {'PASS' if r >= GOAL_J2 else 'FAIL'}")
    print("executors agree (a, b to 1e-12; detect --json equal):", "yes" if agree else "NO")
    print()
    lines = estimate(costs, log_bytes)
    print("\n".join(lines))
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "logs": len(logs),
                    "seconds": {f"{c} / {n}": s for (c, n), s in best.items()},
                    "ratios": ratios,
                    "startup_s": startup,
                    "per_log": costs,
                    "estimate": lines,
                },
                indent=2,
            )
        )
    return 0 if agree else 1


def check_agreement(work: Path, outputs: dict[tuple[str, str], str]) -> bool:
    import numpy as np

    names = list(EXECUTORS)
    models = []
    for name in names:
        doc: dict[str, Any] = json.loads((work / f"cal_{name.replace(' ', '_')}.json").read_text())
        joints = doc["model"]["joints"].values()
        models.append(np.array([[j["a"], j["b"]] for j in joints]))
    same_fit = all(np.allclose(m, models[0], rtol=1e-12, atol=0) for m in models[1:])
    same_detect = all(outputs["detect", n] == outputs["detect", names[0]] for n in names[1:])
    return same_fit and same_detect


if __name__ == "__main__":
    raise SystemExit(main())
