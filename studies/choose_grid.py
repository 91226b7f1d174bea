"""How fine the coarse grid (``twincd.grid``) is: what the twin and the filter on cell means cost
in accuracy against the same chain sample by sample, at 1 kHz, for grids of 32, 64 and 128 nodes
per cut-off period — on a development set of its own, never on `sample_logs/test`.

For each filter (zero-phase, fit's default critically damped 1.5 Hz; causal, 3 Hz) the best
model is fitted sample by sample on the set's train paths and thresholded on its validation
paths; then each test path is scored by ``detect``'s chain sample by sample and on each grid.
Away from a path's first and last second (where the edge transients differ, and no zero-phase
sample is judged), it reports per grid: the grid's period, the RMS and largest difference of the
whitened residual (each joint's residual over its noise scale at its speed: 1.0 is the noise),
the largest difference of the depth score (thresholds are ≈ 5) and the samples whose flag
differs, then ``detect``'s CPU seconds on the set's test paths.

    twincd synth /tmp/grid1k --seed 3 --train 4 --val 3 --test 3 --rate-hz 1000 --no-rosbag2-copy
    python studies/choose_grid.py /tmp/grid1k

docs/models-and-results.md (The coarse grid) quotes its output.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

import twincd.grid
from twincd.calibration import Calibration
from twincd.commands import filter_settings, fit_calibration, threshold_calibration
from twincd.detection import detect_streamed
from twincd.pipeline import Setup
from twincd.signal.filters import LowPass

FILTERS = {
    "zero-phase 1.5 Hz": LowPass(1.5, 2, False, "critical"),
    "causal 3 Hz": LowPass(3.0, 2, True, "critical"),
}
OVERSAMPLING = (32, 64, 128)


RULE = twincd.grid.GRID_MIN_PERIODS


def per_sample(on: bool) -> None:
    """Every log sample by sample (as before the grid), or back to the grid's rule."""
    twincd.grid.GRID_MIN_PERIODS = 10**9 if on else RULE


def scored(log: Path, cal: Calibration) -> dict[str, np.ndarray]:
    rows: list[dict[str, np.ndarray]] = []

    class Keep:
        def write(self, frame: Any, events: Any) -> None:
            if frame.n:
                rows.append({k: frame[k] for k in ("stamp_ns", "score", "residual", "velocity")})

    detect_streamed(log, cal, Setup.from_calibration(cal), [Keep()])
    return {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}


def compare(cal: Calibration, tests: list[Path], reference: list[dict[str, np.ndarray]]) -> str:
    model, threshold = cal.model, cal.require_threshold().value
    diffs, scores, flags, judged = [], [], 0, 0
    start = time.process_time()
    coarse = [scored(log, cal) for log in tests]
    cpu = time.process_time() - start
    for a, b in zip(coarse, reference, strict=True):
        t = (a["stamp_ns"] - a["stamp_ns"][0]) * 1e-9
        inside = (t > 1.0) & (t < t[-1] - 1.0)
        wa = model.whitened_residual(a["residual"], a["velocity"])
        wb = model.whitened_residual(b["residual"], b["velocity"])
        assert wa is not None and wb is not None
        diffs.append((wa - wb)[inside])
        scores.append((a["score"] - b["score"])[inside])
        differ = (a["score"] >= threshold) != (b["score"] >= threshold)
        flags += int(np.count_nonzero(differ[inside]))
        judged += int(inside.sum())
    d, s = np.concatenate(diffs), np.concatenate(scores)
    return (
        f"whitened RMS {np.sqrt(np.mean(d**2)):.3f} max {np.abs(d).max():.2f}; "
        f"score max {np.abs(s).max():.3f}; flags differ {flags}/{judged}; detect {cpu:.1f} CPU s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("dev", type=Path, help="a `twincd synth` folder at 1 kHz")
    args = parser.parse_args()
    train = sorted((args.dev / "train").glob("*.mcap"))
    val = sorted((args.dev / "val").glob("*.mcap"))
    tests = sorted((args.dev / "test").glob("*.mcap"))
    for name, lowpass in FILTERS.items():
        per_sample(True)
        cal = fit_calibration(train, jobs=1, **filter_settings(lowpass)).calibration
        cal = threshold_calibration(val, cal, jobs=1).calibration
        start = time.process_time()
        reference = [scored(log, cal) for log in tests]
        print(f"{name}: per sample, detect {time.process_time() - start:.1f} CPU s")
        per_sample(False)
        for r in OVERSAMPLING:
            twincd.grid.GRID_OVERSAMPLING = r
            grid = twincd.grid.grid_period_ns(lowpass.cutoff_hz, cal.period_s or 0.001)
            print(
                f"  {r:3d} nodes a cut-off period, grid {grid} ns: {compare(cal, tests, reference)}"
            )
        twincd.grid.GRID_OVERSAMPLING = 64


if __name__ == "__main__":
    main()
