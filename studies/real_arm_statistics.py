"""Which score separates real pushes from a real arm's own model errors? A study on residuals.

For each rotation of the real Doosan M0609's six logs (test log i, validation log i+1, the
other four to fit), the identified model is fitted through the library (no CLI, to keep the
per-sample residuals), and candidate scores are computed from the same residuals:

- ``sum``: Σ_j (r_j/s_j)², s_j the joint's residual RMS on clean training samples (today's
  whitened score);
- ``speed``: the same with s_j(|q̇_j|), the joint's clean residual RMS in bins of its own speed
  (at rest a friction-dominated joint's current sits anywhere in its stiction band, so its
  residual is widest there: a state-dependent noise scale, as in dynamic thresholds);
- ``depth``: a push on link k loads joints 1…k only, so the score is the largest over k of the
  χ²_k-normalised energy of the first k whitened joints (Wilson–Hilferty z), with the speed
  scale: a generalised likelihood ratio over the touched link's depth, on one scale for every k.

Per score: AUC per rotation, the pushes an oracle threshold (the test log's own clean maximum)
would find, and at fixed thresholds the pushes found, median delay and false alarms pooled
over the rotations (as ``evaluate`` counts them: a flag run touching no labelled push ±200 ms).
The data stay in ``../shared/data``; nothing is written.

    python studies/real_arm_statistics.py [--cutoff 1] [--model identified]
    python studies/real_arm_statistics.py --synth /tmp/dev2   # a synth set (train/val/test)
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "doosan_m0609"
SPEED_BINS = np.array([0.0, 0.003, 0.01, 0.03, 0.1, 0.3, np.inf])  # rad/s
TOLERANCE_S = 0.2


@dataclass
class Residuals:
    """One log's residual under one rotation's model, with what scoring needs."""

    r: FloatArray  # (N, D)
    speed: FloatArray  # (N, D) |q̇|
    labels: BoolArray
    judged: BoolArray  # outside the filter's edge spans
    period_s: float


@dataclass
class Rotation:
    test: Residuals
    val: Residuals
    train: Residuals  # the clean training samples only


def residuals_of(log, model) -> Residuals:  # type: ignore[no-untyped-def]
    from twincd.calibration.models import model_inputs

    judged = np.ones(len(log), bool) if log.edge is None else ~log.edge
    labels = log.labels if log.labels is not None else np.zeros(len(log), bool)
    return Residuals(
        model.residual(model_inputs(log)),
        np.abs(log.states.velocity),
        labels,
        judged,
        float(np.median(np.diff(log.states.stamp_ns))) * 1e-9,
    )


def rotations(
    logs: Sequence[Path], robot: str, model: str, cutoff: float, plan: list[tuple[int, int]]
) -> list[Rotation]:
    """Fit once per (test, val) pair of ``plan`` on the other logs, through the library."""
    from twincd.calibration.setup import fit_log, merge_fits, setup_for_model
    from twincd.pipeline import Setup
    from twincd.signal.filters import LowPass

    base = Setup(robot=robot, lowpass=LowPass(cutoff_hz=cutoff, order=2, kind="critical"))
    setup = setup_for_model(base, model)
    fits = [fit_log(p, setup) for p in logs]
    prepared = [setup.prepare(p) for p in logs]
    out = []
    for test, val in plan:
        train = [i for i in range(len(logs)) if i not in (test, val)]
        cal = merge_fits([fits[i] for i in train], setup, model)
        parts = [residuals_of(prepared[i], cal.model) for i in train]
        keep = [p.judged & ~p.labels for p in parts]
        clean = Residuals(
            np.concatenate([p.r[k] for p, k in zip(parts, keep, strict=True)]),
            np.concatenate([p.speed[k] for p, k in zip(parts, keep, strict=True)]),
            np.zeros(sum(int(k.sum()) for k in keep), bool),
            np.ones(sum(int(k.sum()) for k in keep), bool),
            parts[0].period_s,
        )
        out.append(
            Rotation(
                residuals_of(prepared[test], cal.model),
                residuals_of(prepared[val], cal.model),
                clean,
            )
        )
    return out


# ------------------------------------------------------------------ scores

Score = Callable[[Residuals, Residuals], FloatArray]  # (log, clean training) → per sample


def _bin(speed: FloatArray) -> NDArray[np.intp]:
    return np.clip(np.searchsorted(SPEED_BINS, speed, side="right") - 1, 0, len(SPEED_BINS) - 2)


def speed_scale(clean: Residuals) -> FloatArray:
    """(D, bins): each joint's clean residual RMS in bins of its own speed."""
    d = clean.r.shape[1]
    scale = np.empty((d, len(SPEED_BINS) - 1))
    k = _bin(clean.speed)
    for j in range(d):
        for b in range(scale.shape[1]):
            sel = clean.r[k[:, j] == b, j]
            scale[j, b] = np.sqrt(np.mean(sel**2)) if len(sel) > 50 else clean.r[:, j].std()
    return scale


def whitened(log: Residuals, clean: Residuals, by_speed: bool) -> FloatArray:
    if not by_speed:
        return log.r / np.sqrt(np.mean(clean.r**2, axis=0))
    scale = speed_scale(clean)
    cols = np.arange(log.r.shape[1])
    return log.r / scale[cols[None, :], _bin(log.speed)]


def wilson_hilferty(x: FloatArray, k: int) -> FloatArray:
    """χ²_k values as standard-normal z (finite for any x ≥ 0)."""
    c = 2.0 / (9.0 * k)
    return ((x / k) ** (1.0 / 3.0) - (1.0 - c)) / np.sqrt(c)


def score_sum(log: Residuals, clean: Residuals) -> FloatArray:
    return (whitened(log, clean, False) ** 2).sum(axis=1)


def score_speed(log: Residuals, clean: Residuals) -> FloatArray:
    return (whitened(log, clean, True) ** 2).sum(axis=1)


def score_depth(log: Residuals, clean: Residuals) -> FloatArray:
    energy = np.cumsum(whitened(log, clean, True) ** 2, axis=1)
    z = [wilson_hilferty(energy[:, k], k + 1) for k in range(energy.shape[1])]
    return np.max(np.stack(z, axis=1), axis=1)


SCORES: dict[str, Score] = {"sum": score_sum, "speed": score_speed, "depth": score_depth}


# ------------------------------------------------------------------ judging


def push_spans(labels: BoolArray) -> list[tuple[int, int]]:
    from twincd.detection.events import runs

    return runs(labels)


def judge(log: Residuals, score: FloatArray, threshold: float) -> tuple[int, int, list[float], int]:
    """(pushes found, pushes, delays ms, false alarms) as evaluate counts them."""
    from twincd.detection.events import runs

    tol = round(TOLERANCE_S / log.period_s)
    flags = (score >= threshold) & log.judged
    hits = np.flatnonzero(flags)
    spans = push_spans(log.labels)
    cover = np.zeros(len(flags), bool)
    found, delays = 0, []
    for a, b in spans:
        cover[max(0, a - tol) : b + tol + 1] = True
        k = int(np.searchsorted(hits, a))
        if k < len(hits) and hits[k] <= b + tol:
            found += 1
            delays.append((hits[k] - a) * log.period_s * 1e3)
    alarms = sum(1 for a, b in runs(flags) if not cover[a : b + 1].any())
    return found, len(spans), delays, alarms


def oracle(log: Residuals, score: FloatArray) -> int:
    """Pushes whose peak beats the log's own largest clean score (no false alarm at all)."""
    tol = round(TOLERANCE_S / log.period_s)
    cover = np.zeros(len(score), bool)
    for a, b in push_spans(log.labels):
        cover[max(0, a - tol) : b + tol + 1] = True
    top = score[log.judged & ~cover].max()
    return sum(bool(score[a : b + tol + 1].max() > top) for a, b in push_spans(log.labels))


def report(rots: list[Rotation], thresholds: dict[str, list[float]]) -> None:
    from sklearn.metrics import roc_auc_score

    total = sum(len(push_spans(r.test.labels)) for r in rots)
    for name, score in SCORES.items():
        scores = [score(r.test, r.train) for r in rots]
        aucs = [
            roc_auc_score(r.test.labels[r.test.judged], s[r.test.judged])
            for r, s in zip(rots, scores, strict=True)
        ]
        best = sum(oracle(r.test, s) for r, s in zip(rots, scores, strict=True))
        print(
            f"{name:<6} AUC {np.mean(aucs):.3f} ({min(aucs):.3f}–{max(aucs):.3f}); "
            f"oracle threshold finds {best}/{total}"
        )
        for thr in thresholds[name]:
            found = pushes = alarms = 0
            delays: list[float] = []
            for r, s in zip(rots, scores, strict=True):
                f, n, d, a = judge(r.test, s, thr)
                found, pushes, alarms = found + f, pushes + n, alarms + a
                delays += d
            med = float(np.median(delays)) if delays else float("nan")
            print(
                f"    at {thr:>6.3g}: found {found}/{pushes} ({found / pushes:.1%}), "
                f"median delay {med:.0f} ms, false alarms {alarms}"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cutoff", type=float, default=1.0, help="low-pass cut-off, Hz")
    parser.add_argument("--model", default="identified", help="calibration model to fit")
    parser.add_argument("--synth", type=Path, help="a twincd synth set instead of the real arm")
    args = parser.parse_args()
    thresholds = {"sum": [30, 60, 120], "speed": [30, 60, 120], "depth": [4, 5, 6, 8]}
    if args.synth is not None:
        train = sorted((args.synth / "train").glob("*.mcap"))
        tests = sorted((args.synth / "test").glob("*.mcap"))
        val = sorted((args.synth / "val").glob("*.mcap"))[:1]
        logs = [*train, *val, *tests]
        v = len(train)
        plan = [(v + 1 + i, v) for i in range(len(tests))]
        rots = rotations(logs, "xarm7", args.model, args.cutoff, plan)
        # each fit also takes the other test logs' unlabelled samples, as fit does
        print(f"synth {args.synth}: {len(train)} train, {len(tests)} test logs")
    else:
        if not DATA.is_dir():
            print(f"the real arm's recordings are not at {DATA}: nothing to study")
            return 0
        logs = [DATA / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
        plan = [(i, (i + 1) % 6) for i in range(6)]
        rots = rotations(logs, str(DATA / "m0609.urdf"), args.model, args.cutoff, plan)
        print(f"real arm, six rotations, {args.model}, {args.cutoff:g} Hz")
    report(rots, thresholds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
