"""``evaluate``'s results (contract: Exit codes and streams ``evaluate --json``; Metrics): a
method's row (``MethodResult``) and the evaluation's table (``Evaluation``) with their JSON, and
how one run's figures are made from its test units and event counts (``run_figures``) and the
runs of a randomised method averaged into its row (``combine_runs``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from twincd.evaluation.methods import MethodSkipped
from twincd.evaluation.metrics import EventCounts, ScoredUnits, best_of

# figures averaged over repeats; each gets a ``<key>_std`` companion
_AVERAGED = (
    "f1_best",
    "f1_at_threshold",
    "precision_at_threshold",
    "recall_at_threshold",
    "auc",
    "train_s",
    "test_s",
)
# each method's scores, first in its row of ``evaluate --json`` (contract: --json documents)
SCORE_KEYS = (
    "f1_best",
    "best_k",
    "f1_at_threshold",
    "auc",
    "precision_at_threshold",
    "recall_at_threshold",
    "train_s",
    "test_s",
)
# event metrics (contract: Metrics), averaged over repeats like the figures above
EVENT_KEYS = (
    "events_total",
    "events_detected",
    "delay_ms_median",
    "delay_ms_p95",
    "false_alarms",
    "false_alarms_per_hour",
    "events_per_detected",
    "events_not_judged",
    "force_events_total",
    "force_events_detected",
    "force_delay_ms_median",
    "isolation_accuracy",
    "isolation_named",
    "val_false_alarms",
    "val_false_alarms_per_hour",
)


@dataclass
class MethodResult:
    """One method's row of Table II (contract: Exit codes and streams ``evaluate --json``)."""

    name: str
    unit: str = "sample"
    skipped: str | None = None
    f1_best: float | None = None
    best_k: float | None = None
    f1_at_threshold: float | None = None
    precision_at_threshold: float | None = None
    recall_at_threshold: float | None = None
    auc: float | None = None
    train_s: float | None = None
    test_s: float | None = None
    k_sigma: float | None = None
    mu: float | None = None
    sigma: float | None = None
    threshold: float | None = None
    units: int = 0
    positives: int = 0
    sweep: list[tuple[float, float]] = field(default_factory=list)
    repeats: int = 1
    std: dict[str, float | None] = field(default_factory=dict)
    note: str | None = None  # what the method had to do differently (e.g. subsampling)
    # the threshold the method is run at, as people read it: what the F1 gate judges
    judged_at: str = ""
    events: dict[str, float | None] = field(default_factory=dict)  # EVENT_KEYS present
    # (fpr, tpr) points of the first run's ROC curve, for figures (not in the JSON)
    roc: list[tuple[float, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        if self.skipped is not None:
            return {"name": self.name, "skipped": self.skipped}
        d: dict[str, Any] = {"name": self.name}
        if self.unit != "sample":
            d["unit"] = self.unit
        for key in (
            *SCORE_KEYS,
            "k_sigma",
            "mu",
            "sigma",
            "threshold",
            "units",
            "positives",
        ):
            d[key] = getattr(self, key)
        d["judged_at"] = self.judged_at
        d.update(self.events)
        d["sweep"] = [{"k": k, "f1": f} for k, f in self.sweep]
        if self.note:
            d["note"] = self.note
        if self.repeats > 1:
            d["repeats"] = self.repeats
            d.update({f"{k}_std": v for k, v in self.std.items()})
        return d


@dataclass
class Evaluation:
    """Results over one test set (per sample), one row per method."""

    samples: int
    positives: int
    methods: list[MethodResult]
    test_logs: list[str] = field(default_factory=list)
    train_logs: list[str] = field(default_factory=list)
    val_logs: list[str] = field(default_factory=list)
    # the low-pass every method's logs went through (the identified models fit with the
    # critical kind by default; evaluate filters all methods alike)
    lowpass: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "samples": self.samples,
            "positives": self.positives,
            "methods": [m.to_dict() for m in self.methods],
            "logs": {"test": self.test_logs, "train": self.train_logs, "val": self.val_logs},
        }
        if self.lowpass is not None:
            out["filter"] = self.lowpass
        return out

    def missed_gates(self, min_f1: float | None, min_auc: float | None) -> list[str]:
        """Why the gates fail (empty: passed); a gate judges every method that ran, its F1 at
        the threshold it is run at (what it would flag deployed, not the best over μ + iσ)."""
        missed = []
        for m in self.methods:
            if m.skipped is not None:
                continue
            f1 = m.f1_at_threshold
            if min_f1 is not None and (f1 is None or f1 < min_f1):
                shown = "n/a" if f1 is None else f"{f1:.3f}"
                missed.append(f"{m.name}: F1 {shown} at {m.judged_at} < {min_f1}")
            if min_auc is not None and (m.auc is None or m.auc < min_auc):
                shown = "n/a" if m.auc is None else f"{m.auc:.3f}"
                missed.append(f"{m.name}: AUC {shown} < {min_auc}")
        return missed


@dataclass
class Sources:
    """The logs read (those that failed with ``--keep-going`` left out) and the test samples:
    what the Evaluation reports of them."""

    samples: int = 0
    positives: int = 0
    test: list[str] = field(default_factory=list)
    train: list[str] = field(default_factory=list)
    val: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class RunFigures:
    """One run's figures (a method, a seed): its F1 sweep, scores and event metrics, and the
    μ, σ and threshold it was judged at."""

    sweep: list[tuple[float, float]]
    figures: dict[str, float | None]
    mu: float
    sigma: float
    threshold: float
    units: int
    positives: int
    note: str | None
    roc: list[tuple[float, float]] = field(default_factory=list)


def run_figures(
    units: ScoredUnits,
    mu: float,
    sigma: float,
    threshold: float,
    times: tuple[float | None, float],
    events: EventCounts,
    val_events: EventCounts | None,
    note: str | None,
) -> RunFigures:
    """One run's figures from its test units' scores and labels (``times``: train and test
    seconds) and its event counts on the test (and validation) logs."""
    sweep = units.f1_sweep(mu, sigma)
    best_k, f1_best = best_of(sweep)
    at = units.at_threshold(threshold)
    figures: dict[str, float | None] = {
        "f1_best": f1_best,
        "best_k": best_k,
        "f1_at_threshold": at.f1,
        "precision_at_threshold": at.precision,
        "recall_at_threshold": at.recall,
        "auc": units.auc(),
        "train_s": times[0],
        "test_s": times[1],
    }
    figures.update(events.to_dict())
    if val_events is not None:
        figures["val_false_alarms"] = val_events.false_alarms
        figures["val_false_alarms_per_hour"] = val_events.false_alarms_per_hour
    return RunFigures(
        sweep, figures, mu, sigma, threshold, units.units, units.positives, note, units.roc_points()
    )


def _mean_std(values: list[float | None]) -> tuple[float | None, float | None]:
    vals = [v for v in values if v is not None]
    if not vals:
        return None, None
    return float(np.mean(vals)), float(np.std(vals))


def combine_runs(name: str, unit: str, k_sigma: float, runs: list[RunFigures]) -> MethodResult:
    """A method's row from its runs: each figure the runs' mean (its std beside it), its
    sweep their mean F1 curve."""
    first = runs[0]
    result = MethodResult(
        name=name,
        unit=unit,
        k_sigma=k_sigma,
        units=first.units,
        positives=first.positives,
        repeats=len(runs),
        note=first.note,
        roc=first.roc,
    )
    # best_k: where the mean F1 curve peaks; f1_best: mean of each run's own best
    ks = [k for k, _ in first.sweep]
    mean_curve = [float(np.mean([r.sweep[i][1] for r in runs])) for i in range(len(ks))]
    result.sweep = list(zip(ks, mean_curve, strict=True))
    result.best_k = best_of(result.sweep)[0]
    for key in _AVERAGED:
        mean, std = _mean_std([r.figures[key] for r in runs])
        setattr(result, key, mean)
        result.std[key] = std
    for key in EVENT_KEYS:
        if key in first.figures:
            result.events[key] = _mean_std([r.figures.get(key) for r in runs])[0]
    result.mu = float(np.mean([r.mu for r in runs]))
    result.sigma = float(np.mean([r.sigma for r in runs]))
    result.threshold = float(np.mean([r.threshold for r in runs]))
    return result


def skipped_result(name: str, unit: str, exc: MethodSkipped) -> MethodResult:
    """The row of a method that could not run, with why."""
    return MethodResult(name=name, unit=unit, skipped=str(exc) or "cannot run on these logs")
