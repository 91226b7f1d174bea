"""Does a false-alarm budget set from minutes of clean data hold on other clean data?

``twincd threshold`` extrapolates the threshold of a budget (false alarms per hour of
collision-free time) from the peaks of the score's excursions on the validation logs (a
generalised Pareto tail, ``twincd.tail``). This study sets it from short clean validation
stretches and counts the false alarms it gives on other clean data, with μ + 4σ beside it:

1. ``synth`` (synthetic xArm 7, dev seeds ≥ 2): fit on short training paths, then per draw a
   100 s stretch of one long clean validation path sets the threshold and the other long paths
   (an hour of clean time) are the test. Every stretch of every path is one draw.
2. ``real`` (the Doosan M0609 recordings, read from beside the repository as
   ``studies/real_arm.py`` reads them, when present; nothing derived from them is written):
   its six rotations (fit on four logs, threshold on the clean samples of one, test on the
   clean time of another), with the pushes found at each threshold.

For each way of setting the threshold: false alarms per hour observed (pooled, and the spread
over draws), and for the budget's threshold its interval's upper end as the alternative.

    python studies/choose_threshold.py synth --seed 2 --seed 3 [--model identified-whitened]
    python studies/choose_threshold.py real [--model identified-whitened] [--budget 1 --budget 10]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from statistics import median

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import Calibration, clean_rows
from twincd.detection.events import runs
from twincd.pipeline import Setup
from twincd.signal.features import ModelInputs
from twincd.tail import ExcursionCounter
from twincd.threshold import ScoreStats, budget_threshold

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "doosan_m0609"
TOLERANCE_S = 0.2  # as evaluate's event metrics: a flag ≤ 200 ms after a push finds it

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def twincd(*args: object) -> None:
    cmd = [sys.executable, "-m", "twincd_cli.main", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr}")


@dataclass
class Scored:
    """One log's score per sample, judged samples (not at a filter edge), labels, period."""

    scores: FloatArray
    judged: BoolArray
    labels: BoolArray
    period_s: float

    @property
    def clean(self) -> BoolArray:
        return self.judged & ~self.labels

    @property
    def clean_hours(self) -> float:
        return float(np.count_nonzero(self.clean)) * self.period_s / 3600.0


def score(path: Path, cal: Calibration) -> Scored:
    setup = Setup.from_calibration(cal)
    parts: list[tuple[FloatArray, BoolArray, BoolArray]] = []
    with setup.open(path, model=cal.model) as stream:
        for frame in stream:
            theta = stream.features.theta
            s = cal.model.scores(
                ModelInputs.of(frame, stream.coulomb_eps, stream.regressor_mask, theta)
            )
            judged = clean_rows(None, frame.n, frame.get("edge"))
            labels = frame.get("labels")
            lab = np.zeros(frame.n, bool) if labels is None else np.asarray(labels, bool)
            parts.append((np.asarray(s, np.float64), judged, lab))
        period = stream.period_s
    scores, judged, labels = (np.concatenate(c) for c in zip(*parts, strict=True))
    return Scored(scores, judged.astype(bool), labels.astype(bool), period)


def thresholds(val: Scored, budgets: list[float]) -> dict[str, float]:
    """The ways of setting the threshold from a validation stretch: μ + 4σ, and per budget the
    tail's estimate and its interval's upper end."""
    usable = val.clean
    stats = ScoreStats.from_scores(val.scores, usable)
    peaks = ExcursionCounter(val.period_s)
    peaks.push(val.scores, usable)
    out = {"mu+4sigma": stats.mu + 4 * stats.sigma}
    for budget in budgets:
        th = budget_threshold(peaks.excursions, stats, budget)
        assert th.tail is not None
        out[f"pot {budget:g}/h"] = th.value
        out[f"high {budget:g}/h"] = np.inf if th.tail.high is None else th.tail.high
    return out


def false_alarms(test: Scored, x: float) -> int:
    """Runs of flags on judged samples that touch no labelled push (nor its 200 ms after)."""
    flags = (test.scores >= x) & test.judged
    near = _widen(test.labels, round(TOLERANCE_S / test.period_s))
    return sum(1 for a, b in runs(flags) if not near[a : b + 1].any())


def pushes_found(test: Scored, x: float) -> tuple[int, int]:
    flags = (test.scores >= x) & test.judged
    tol = round(TOLERANCE_S / test.period_s)
    spans = runs(test.labels)
    return sum(1 for a, b in spans if flags[a : b + 1 + tol].any()), len(spans)


def _widen(mask: BoolArray, after: int) -> BoolArray:
    out: BoolArray = mask.copy()
    for a, b in runs(mask):
        out[a : b + 1 + after] = True
    return out


@dataclass
class Tally:
    alarms: dict[str, list[int]] = field(default_factory=dict)
    hours: list[float] = field(default_factory=list)
    found: dict[str, list[int]] = field(default_factory=dict)
    pushes: list[int] = field(default_factory=list)
    values: dict[str, list[float]] = field(default_factory=dict)

    def add(self, th: dict[str, float], tests: list[Scored]) -> None:
        self.hours.append(sum(t.clean_hours for t in tests))
        for name, x in th.items():
            self.alarms.setdefault(name, []).append(sum(false_alarms(t, x) for t in tests))
            self.values.setdefault(name, []).append(x)
            got = [pushes_found(t, x) for t in tests]
            self.found.setdefault(name, []).append(sum(g[0] for g in got))
        self.pushes.append(sum(pushes_found(t, np.inf)[1] for t in tests))

    def report(self, budgets: list[float]) -> None:
        hours = sum(self.hours)
        print(f"  {len(self.hours)} draws, {hours:.3g} h of clean test time")
        for name, counts in self.alarms.items():
            rates = [c / h for c, h in zip(counts, self.hours, strict=True)]
            budget = float(name.split()[1].removesuffix("/h")) if " " in name else min(budgets)
            within = np.mean([r <= budget for r in rates])
            line = (
                f"  {name:12s} pooled {sum(counts) / hours:8.3g}/h  per draw median "
                f"{median(rates):.3g}/h [{min(rates):.3g}, {max(rates):.3g}]  "
                f"draws within budget {100 * within:.0f} %"
            )
            if sum(self.pushes):
                line += f"  pushes found {100 * sum(self.found[name]) / sum(self.pushes):.1f} %"
            vals = self.values[name]
            print(line + f"  threshold median {median(vals):.4g}")


def fit(args: list[object], work: Path, model: str | None) -> Calibration:
    out = work / "cal.json"
    twincd("fit", *args, "-o", out, "-q", *(["--model", model] if model else []), "--force")
    return Calibration.load(out)


def synth(seeds: list[int], model: str | None, budgets: list[float], stretch_s: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            work = Path(tmp) / f"s{seed}"
            twincd("synth", work / "short", "--seed", seed, "--train", 10, "--val", 0,
                   "--test", 0, "--no-rosbag2-copy", "-q")  # fmt: skip
            long = ["--train", 0, "--val", 7, "--test", 0, "--min-duration", 600]
            twincd("synth", work / "long", "--seed", seed, *long, "--max-duration", 600,
                   "--no-rosbag2-copy", "-q")  # fmt: skip
            cal = fit([work / "short" / "train"], work, model)
            logs = [score(p, cal) for p in sorted((work / "long" / "val").glob("*.mcap"))]
            tally = Tally()
            for i, val in enumerate(logs):
                n = round(stretch_s / val.period_s)
                for start in range(0, len(val.scores) - n + 1, n):
                    tally.add(_threshold_on(val, start, n, budgets), logs[:i] + logs[i + 1 :])
            print(
                f"synth seed {seed}, model {cal.model.kind}, {stretch_s:g} s of clean validation:"
            )
            tally.report(budgets)


def _threshold_on(val: Scored, start: int, n: int, budgets: list[float]) -> dict[str, float]:
    part = slice(start, start + n)
    cut = Scored(val.scores[part], val.judged[part], val.labels[part], val.period_s)
    return thresholds(cut, budgets)


def real(model: str | None, budgets: list[float], no_urdf: bool) -> None:
    logs = [DATA / "logs" / f"doosan_dev_{i:02d}" for i in range(6)]
    if not all(p.exists() for p in logs):
        print(f"the real arm's logs are not at {DATA}: nothing to study")
        return
    twin = (
        ["--sim-topic", "/controller/model_effort"] if no_urdf else ["--robot", DATA / "m0609.urdf"]
    )
    tally = Tally()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(6):
            test, val = logs[i], logs[(i + 1) % 6]
            train = [p for p in logs if p not in (test, val)]
            cal = fit([*train, *twin], Path(tmp), model)
            tally.add(thresholds(score(val, cal), budgets), [score(test, cal)])
    print(f"real arm, six rotations, model {cal.model.kind}:")
    tally.report(budgets)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("where", choices=["synth", "real"])
    ap.add_argument("--seed", type=int, action="append", help="synth seeds (dev: ≥ 2)")
    ap.add_argument("--model", default=None, help="fit --model (default: fit's default)")
    ap.add_argument(
        "--budget", type=float, action="append", help="false alarms per hour (default 1)"
    )
    ap.add_argument("--stretch", type=float, default=100.0, help="synth: validation seconds")
    ap.add_argument("--no-urdf", action="store_true", help="real: twin = the controller's")
    args = ap.parse_args()
    if args.where == "synth":
        synth(args.seed or [2, 3], args.model, args.budget or [1.0], args.stretch)
    else:
        real(args.model, args.budget or [1.0], args.no_urdf)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
