"""Delays of the real arm's pushes, at rest and moving, from per-sample scores.

The six rotations of ``real_arm.py`` (test on log i, threshold on log i + 1, fit on the other
four, at the defaults or with the options given), each test log scored per sample by
``twincd detect -o LOG.csv``. For every labelled push: whether the arm was at rest when it began
(every joint |q̇| < ``REST_SPEED`` over the ``REST_BEFORE_S`` before), and the delay from its
first labelled sample to the first sample whose score reaches f × the calibration's threshold,
within the push or ``AFTER_S`` after it, for f in ``FACTORS``; and how many runs of such samples
lie ``CLEAR_S`` or more away from every push (clean excursions: what a lower threshold would
add as false alarms); and each joint's slow-band noise scale in the calibrations, at rest (the
model's lowest speed bin) against moving (its other bins). Reads ``../shared/data/doosan_m0609/``
when present; writes nothing into the project:

    python studies/rest_delays.py
    python studies/rest_delays.py --fit-args=--causal
"""

from __future__ import annotations

import argparse
import csv
import shlex
import sys
import tempfile
from pathlib import Path

import numpy as np
from real_arm import LOGS, URDF, must, twincd

REST_SPEED = 0.003  # rad/s: a joint this slow or slower is still
REST_BEFORE_S = 0.2
AFTER_S = 0.2  # as evaluate counts a found push
CLEAR_S = 0.5
FACTORS = (1.0, 0.9, 0.8, 0.7, 0.6)


def scored(i: int, work: Path, args: argparse.Namespace) -> tuple[Path, Path]:
    """Rotation ``i``'s calibration and its test log's per-sample CSV."""
    test, val = LOGS[i], LOGS[(i + 1) % 6]
    train = [p for p in LOGS if p not in (test, val)]
    cal, out = work / f"cal{i}.json", work / f"scores{i}.csv"
    must(twincd("fit", *train, "--robot", URDF, "-o", cal, "-q", *shlex.split(args.fit_args)))
    must(twincd("threshold", val, "-c", cal, "-q", *shlex.split(args.threshold_args)))
    must(twincd("detect", test, "-c", cal, "-o", out, "-q"), ok=(0, 1))
    return cal, out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit-args", default="", help="extra options of twincd fit")
    parser.add_argument("--threshold-args", default="", help="extra options of twincd threshold")
    args = parser.parse_args()
    if not all(p.exists() for p in LOGS):
        print(f"the real recordings are not here ({LOGS[0].parent}): nothing to study")
        return 0
    from twincd import Calibration, read_log
    from twincd.detection.events import runs

    delays: dict[tuple[bool, float], list[float | None]] = {}
    clean_runs = dict.fromkeys(FACTORS, 0)
    scales: list[np.ndarray] = []  # per rotation, (joints, speed bins)
    with tempfile.TemporaryDirectory() as tmp:
        for i, log in enumerate(LOGS):
            cal_path, out = scored(i, Path(tmp), args)
            calibration = Calibration.load(cal_path)
            threshold = calibration.require_threshold().value
            scales.append(np.asarray(calibration.model.scale_))
            with out.open() as f:
                rows = list(csv.reader(f))[1:]
            stamp = np.array([int(r[0]) for r in rows])
            score = np.array([float(r[1]) for r in rows])
            states = read_log(log)
            assert states.labels is not None
            period = float(np.median(np.diff(stamp))) * 1e-9
            still = (np.abs(states.velocity) < REST_SPEED).all(axis=1)
            near = np.zeros(len(stamp), dtype=bool)
            for a, b in runs(states.labels):
                lo, hi = np.searchsorted(stamp, states.stamp_ns[[a, b]])
                near[max(0, lo - round(CLEAR_S / period)) : hi + round(CLEAR_S / period)] = True
                before = still[max(0, a - round(REST_BEFORE_S / period)) : a + 1]
                for f in FACTORS:
                    hit = np.nonzero(score[lo : hi + round(AFTER_S / period) + 1] >= f * threshold)
                    first = hit[0][0] * period * 1e3 if len(hit[0]) else None
                    delays.setdefault((bool(before.all()), f), []).append(first)
            for f in FACTORS:
                above = score >= f * threshold
                clean_runs[f] += sum(1 for a, b in runs(above) if not near[a : b + 1].any())
    scale = np.mean(scales, axis=0)
    for j, row in enumerate(scale):
        print(
            f"joint {j + 1}: slow-band noise {row[0]:.2f} N·m at rest, "
            f"{row[1:].min():.2f}–{row[1:].max():.2f} N·m moving (mean of the rotations)"
        )
    for f in FACTORS:
        line = [f"{f:.1f} × threshold:"]
        for rest in (True, False):
            got = [d for d in delays[(rest, f)] if d is not None]
            late = sum(d >= 150 for d in got)
            line.append(
                f"{'at rest' if rest else 'moving'} {len(got)}/{len(delays[(rest, f)])}, median "
                f"{np.median(got):.0f} ms, p95 {np.quantile(got, 0.95):.0f} ms, ≥150 ms: {late};"
            )
        every = [d for rest in (True, False) for d in delays[(rest, f)] if d is not None]
        line.append(f"all: p95 {np.quantile(every, 0.95):.0f} ms; clean runs {clean_runs[f]}")
        print(" ".join(line))
    return 0


if __name__ == "__main__":
    sys.exit(main())
