"""Which score, and which threshold rule, separate real pushes from a real arm's own model errors?

For each rotation of the real Doosan M0609's six logs (test log i, validation log i+1, the
other four to fit), the model is fitted through the library (no CLI, to keep per-sample
scores), and each log scored with it. Scores compared (``--score``):

- ``library``: the calibration's own score (for a whitened model: the depth statistic of the
  residuals whitened per bin of each joint's speed, ``twincd.calibration.models``);
- ``sum``: Σ_j (r_j/s_j)², s_j the joint's clean training RMS (the whitened score before the
  speed bins).

Threshold rules, each set on the validation log's collision-free samples only:

- ``k4``: μ + 4σ over its unlabelled samples (the paper's rule);
- ``robust4``: median + 4 × 1.4826 MAD over its unlabelled samples (``twincd threshold``'s
  default for the depth statistic);
- ``k4-guard``: the same without the samples within ``GUARD_S`` of a labelled push (the
  filtered efforts carry a push's force that long before and after its labels);
- ``rice-1/h``: the 1/h budget by Rice's formula on the robust z (``twincd threshold``'s
  default for the depth statistic);
- ``budget``: the false-alarm budget of ``twincd threshold --false-alarms-per-hour 1`` (peaks
  over threshold, generalised Pareto tail) on the guarded samples;
- ``z``: a fixed level of the score (for the depth statistic, a z).

Per score: AUC per rotation and the pushes an oracle threshold (the test log's own clean
maximum) would find; per rule the pushes found, median delay and false alarms pooled over the
rotations (as ``evaluate`` counts them: a flag run touching no labelled push ±200 ms).
The data stay in ``../shared/data``; nothing is written.

    python studies/real_arm_statistics.py [--model identified-whitened]
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
TOLERANCE_S = 0.2
GUARD_S = 0.5


@dataclass
class Scored:
    """One log's scores under one rotation's calibration, with what judging needs."""

    scores: dict[str, FloatArray]
    labels: BoolArray
    judged: BoolArray  # outside the filter's edge spans
    period_s: float

    def clean(self, guard_s: float) -> BoolArray:
        """Judged, unlabelled samples, and none within ``guard_s`` of a labelled one."""
        near = self.labels.copy()
        g = round(guard_s / self.period_s)
        if g:
            near = np.convolve(self.labels.astype(float), np.ones(2 * g + 1), "same") > 0
        out: BoolArray = self.judged & ~near
        return out


@dataclass
class Rotation:
    test: Scored
    val: Scored


def scored(log, cal, clean_rms: FloatArray) -> Scored:  # type: ignore[no-untyped-def]
    from twincd.calibration.models import model_inputs

    inputs = model_inputs(log)
    r = cal.model.residual(inputs)
    judged = np.ones(len(log), bool) if log.edge is None else ~log.edge
    labels = log.labels if log.labels is not None else np.zeros(len(log), bool)
    return Scored(
        {
            "library": cal.model.score(r, inputs["velocity"]),
            "sum": ((r / clean_rms) ** 2).sum(axis=1),
        },
        labels,
        judged,
        float(np.median(np.diff(log.states.stamp_ns))) * 1e-9,
    )


def rotations(
    logs: Sequence[Path],
    robot: str,
    model: str,
    plan: list[tuple[int, int]],
    kind: str,
    cutoff: float = 1.0,
) -> list[Rotation]:
    """Fit once per (test, val) pair of ``plan`` on the other logs, through the library."""
    from twincd.calibration.fitting import fit_log, merge_fits
    from twincd.calibration.models import fit_features
    from twincd.pipeline import Setup
    from twincd.signal.filters import LowPass

    base = Setup(robot=robot, lowpass=LowPass(cutoff_hz=cutoff, kind=kind))
    setup = base
    features = fit_features(model)
    fits = [fit_log(p, setup, (), features) for p in logs]
    prepared = [setup.prepare(p, features) for p in logs]
    out = []
    for test, val in plan:
        train = [i for i in range(len(logs)) if i not in (test, val)]
        cal = merge_fits([fits[i] for i in train], setup, model)
        rms = cal.model.rmse_ if cal.model.rmse_ is not None else np.ones(len(cal.model.a_))
        out.append(Rotation(scored(prepared[test], cal, rms), scored(prepared[val], cal, rms)))
    return out


# ------------------------------------------------------------------ threshold rules

Rule = Callable[[Scored, str], float]  # (validation log, score name) → threshold


def k_sigma(k: float, guard_s: float) -> Rule:
    def rule(val: Scored, score: str) -> float:
        s = val.scores[score][val.clean(guard_s)]
        return float(s.mean() + k * s.std())

    return rule


def budget(per_hour: float, guard_s: float) -> Rule:
    def rule(val: Scored, score: str) -> float:
        from twincd.tail import ExcursionCounter, fit_tail

        counter = ExcursionCounter(val.period_s)
        counter.push(val.scores[score], val.clean(guard_s))
        tail = fit_tail(counter.excursions, per_hour)
        return float("nan") if tail is None else tail.estimate

    return rule


def robust(k: float) -> Rule:
    """Median + k · 1.4826 MAD of the unlabelled samples (``twincd threshold``'s default for
    the depth statistic, there from a histogram)."""

    def rule(val: Scored, score: str) -> float:
        s = val.scores[score][val.clean(0.0)]
        med = float(np.median(s))
        return med + k * 1.4826 * float(np.median(np.abs(s - med)))

    return rule


def rice(per_hour: float) -> Rule:
    """The budget by Rice's formula for a smooth Gaussian score on the robust z, from the
    excursions' rate at μ + 2σ (``twincd threshold``'s default when this study was run; since
    then an exponential tail above the bulk, studies/choose_budget.py)."""

    def rule(val: Scored, score: str) -> float:
        from twincd.tail import LEVELS, ExcursionCounter

        clean = val.clean(0.0)
        s = val.scores[score][clean]
        med = float(np.median(s))
        sigma = 1.4826 * float(np.median(np.abs(s - med)))
        counter = ExcursionCounter(val.period_s)
        counter.push(val.scores[score], clean)
        ex = counter.excursions
        j = int(np.searchsorted(LEVELS, med + 2.0 * sigma, side="right")) - 1
        if not ex.counts[j] or sigma <= 0:
            return float("nan")
        z_u = (float(LEVELS[j]) - med) / sigma
        rate = ex.counts[j] / (ex.seconds / 3600.0)
        return med + sigma * float(np.sqrt(z_u**2 + 2.0 * max(np.log(rate / per_hour), 0.0)))

    return rule


def fixed(level: float) -> Rule:
    return lambda val, score: level


RULES: dict[str, Rule] = {
    "k4": k_sigma(4.0, 0.0),
    "k4-guard": k_sigma(4.0, GUARD_S),
    "robust4": robust(4.0),
    "budget-guard": budget(1.0, GUARD_S),
    "rice-1/h": rice(1.0),
    "z4": fixed(4.0),
    "z5": fixed(5.0),
}


# ------------------------------------------------------------------ judging


def push_spans(labels: BoolArray) -> list[tuple[int, int]]:
    from twincd.detection.events import runs

    return runs(labels)


def judge(log: Scored, score: FloatArray, threshold: float) -> tuple[int, int, list[float], int]:
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


def oracle(log: Scored, score: FloatArray) -> int:
    """Pushes whose peak beats the log's own largest clean score (no false alarm at all)."""
    tol = round(TOLERANCE_S / log.period_s)
    top = score[log.clean(TOLERANCE_S)].max()
    return sum(bool(score[a : b + tol + 1].max() > top) for a, b in push_spans(log.labels))


def report(rots: list[Rotation]) -> None:
    from sklearn.metrics import roc_auc_score

    total = sum(len(push_spans(r.test.labels)) for r in rots)
    for name in rots[0].test.scores:
        aucs = [
            roc_auc_score(r.test.labels[r.test.judged], r.test.scores[name][r.test.judged])
            for r in rots
        ]
        best = sum(oracle(r.test, r.test.scores[name]) for r in rots)
        print(
            f"{name:<8} AUC {np.mean(aucs):.3f} ({min(aucs):.3f}–{max(aucs):.3f}); "
            f"oracle threshold finds {best}/{total}"
        )
        for rule_name, rule in RULES.items():
            found = pushes = alarms = 0
            delays: list[float] = []
            levels = []
            for r in rots:
                thr = rule(r.val, name)
                levels.append(thr)
                f, n, d, a = judge(r.test, r.test.scores[name], thr)
                found, pushes, alarms = found + f, pushes + n, alarms + a
                delays += d
            med = float(np.median(delays)) if delays else float("nan")
            print(
                f"    {rule_name:<13} thresholds {' '.join(f'{x:.3g}' for x in levels)}: "
                f"found {found}/{pushes} ({found / pushes:.1%}), median delay {med:.0f} ms, "
                f"false alarms {alarms}"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="identified-whitened", help="calibration model")
    parser.add_argument("--filter-kind", default="critical", help="low-pass kind")
    parser.add_argument("--cutoff", type=float, default=1.0, help="low-pass cut-off, Hz")
    parser.add_argument("--synth", type=Path, help="a twincd synth set instead of the real arm")
    args = parser.parse_args()
    if args.synth is not None:
        train = sorted((args.synth / "train").glob("*.mcap"))
        tests = sorted((args.synth / "test").glob("*.mcap"))
        val = sorted((args.synth / "val").glob("*.mcap"))[:1]
        logs = [*train, *val, *tests]
        v = len(train)
        plan = [(v + 1 + i, v) for i in range(len(tests))]
        rots = rotations(logs, "xarm7", args.model, plan, args.filter_kind, args.cutoff)
        print(f"synth {args.synth}: {len(train)} train, {len(tests)} test logs, {args.model}")
    else:
        if not DATA.is_dir():
            print(f"the real arm's recordings are not at {DATA}: nothing to study")
            return 0
        logs = [DATA / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
        plan = [(i, (i + 1) % 6) for i in range(6)]
        rots = rotations(
            logs, str(DATA / "m0609.urdf"), args.model, plan, args.filter_kind, args.cutoff
        )
        print(f"real arm, six rotations, {args.model}, {args.filter_kind} {args.cutoff:g} Hz")
    report(rots)
    return 0


if __name__ == "__main__":
    sys.exit(main())
