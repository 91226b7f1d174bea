"""How the default low-pass cut-off was chosen — on training and validation logs only.

a, b are fitted on the training logs for every candidate cut-off; hand-press-like sin² bumps
(0.4–1.6 s, 1–6 N·m on 2–4 random joints, random sign) are added to the measured effort of the
validation logs, and the detector has to find them with μ, σ from the clean validation scores.
The test logs are never read. The bump shape is an assumed prior on how long a press lasts.

    python studies/choose_cutoff.py sample_logs/train sample_logs/val [--causal] [--orders 2 4]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from twincd.calibration import AffineStats, solve
from twincd.calibration.threshold import ScoreStats
from twincd.detection import affine_score
from twincd.evaluation.metrics import at_threshold, auc, best_of, f1_sweep
from twincd.io.logs import expand_logs
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.setup import Setup
from twincd.signal.filters import LowPass

CUTOFFS_HZ = (0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 5.0)


def inject_bumps(log: PreparedLog, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(effort with six bumps added, their labels) for one validation log."""
    t = log.states.t_s
    effort = log.effort.copy()
    labels = np.zeros(len(t), dtype=bool)
    slots = np.linspace(1.5, t[-1] - 2, 7)
    for s0 in slots[:-1]:
        duration = rng.uniform(0.4, 1.6)
        start = s0 + rng.uniform(0, 1.0)
        inside = (t >= start) & (t <= start + duration)
        shape = np.sin(np.pi * (t[inside] - start) / duration) ** 2
        amp = np.zeros(effort.shape[1])
        joints = rng.choice(effort.shape[1] - 1, rng.integers(2, 5), replace=False)
        amp[joints] = rng.uniform(1, 6, len(joints)) * rng.choice([-1, 1], len(joints))
        effort[inside] += shape[:, None] * amp
        labels[inside] = True
    return effort, labels


def study(train: Sequence[PreparedLog], val: Sequence[PreparedLog], lp: LowPass) -> str:
    stats = AffineStats.zeros(len(train[0].joint_names))
    for log in train:
        t = log.states.t_s
        stats = stats + AffineStats.from_arrays(
            lp.apply(t, log.sim_effort), lp.apply(t, log.effort)
        )
    sol = solve(stats)
    rng = np.random.default_rng(1)
    clean = ScoreStats()
    scores, labels = [], []
    for log in val:
        t = log.states.t_s
        sim = lp.apply(t, log.sim_effort)
        clean = clean + ScoreStats.from_scores(
            affine_score(lp.apply(t, log.effort), sim, sol.a, sol.b)
        )
        bumped, lab = inject_bumps(log, rng)
        scores.append(affine_score(lp.apply(t, bumped), sim, sol.a, sol.b))
        labels.append(lab)
    y, lab_all = np.concatenate(scores), np.concatenate(labels)
    k, f1 = best_of(f1_sweep(lab_all, y, clean.mu, clean.sigma))
    at4 = at_threshold(lab_all, y, clean.mu + 4 * clean.sigma)
    return f"F1 best {f1:.3f} (k={k})  F1@4σ {at4.f1:.3f}  AUC {auc(lab_all, y):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("train", type=Path)
    parser.add_argument("val", type=Path)
    parser.add_argument("--causal", action="store_true")
    parser.add_argument("--orders", type=int, nargs="+", default=[2, 4])
    args = parser.parse_args()
    setup = Setup()
    train = list(setup.prepare_all(expand_logs([args.train])))
    val = list(setup.prepare_all(expand_logs([args.val])))
    for order in args.orders:
        for cutoff in CUTOFFS_HZ:
            lp = LowPass(cutoff, order, causal=args.causal)
            print(f"order {order} cut-off {cutoff:4.1f} Hz: {study(train, val, lp)}")


if __name__ == "__main__":
    main()
