"""Judge scoring methods as the seed paper does (section IV-B/C, Table II; contract: Metrics,
Methods).

Each method fits on the training logs, μ and σ of its score come from the validation logs, and
its scores on the test logs give the F1 sweep over μ + iσ, F1/precision/recall at μ + kσ (k the
calibration's) and the ROC AUC. Training time is the time of ``fit``; test time the time to
score every test log. Randomised methods run ``repeats`` times (seeds 0..N-1): mean and std.
"""

from __future__ import annotations

import inspect
import logging
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from twincd.calibration import Calibration
from twincd.calibration.models import EPSILON_GRID, MODEL_KINDS, model_class
from twincd.defaults import DEFAULT_K_SIGMA, DEFAULT_LINK_TOPIC, DEFAULT_REPEATS
from twincd.detection.detect import FlagCount
from twincd.detection.events import EventRules
from twincd.errors import DataError, UsageError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, available, make_method
from twincd.evaluation.metrics import (
    EventCounts,
    at_threshold,
    auc,
    best_of,
    event_counts,
    f1_sweep,
    roc_points,
)
from twincd.io.links import read_links
from twincd.io.logs import expand_logs
from twincd.io.named import settle_named
from twincd.io.options import LogOptions
from twincd.pipeline import PreparedLog, Setup, agreed_joints
from twincd.threshold import ScoreStats, same_rule, threshold_prepared_logs
from twincd.types import BoolArray, FloatArray

T = TypeVar("T")
Progress = Callable[[Sequence[Any], str], Iterable[Any]]
Loader = Callable[[Sequence[Path], Setup, str], list[PreparedLog]]

log = logging.getLogger("twincd")


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
# event metrics (contract: Metrics), averaged over repeats like the figures above
EVENT_KEYS = (
    "events_total",
    "events_detected",
    "delay_ms_median",
    "delay_ms_p95",
    "false_alarms",
    "false_alarms_per_hour",
    "events_per_detected",
    "force_events_total",
    "force_events_detected",
    "force_delay_ms_median",
    "isolation_accuracy",
    "isolation_named",
    "val_false_alarms",
    "val_false_alarms_per_hour",
)
Links = dict[str, "tuple[str, ...] | None"]


def _no_progress(items: Sequence[Any], _desc: str) -> Iterable[Any]:
    return items


def method_for(kind: str) -> str:
    """The ``evaluate`` method that scores with a calibration model of this kind (the seed
    paper's affine model is ``proposed``)."""
    return "proposed" if kind == "affine" else kind


def parse_methods(text: str | None, default: str = "proposed") -> list[str]:
    """``--methods``: comma-separated names or ``all`` (none given: ``default``, e.g. the
    calibration's own model, ``method_for(kind)``); unknown names are a usage error."""
    names = [n.strip() for n in (text or default).split(",") if n.strip()]
    known = available()
    if "all" in names:
        return known
    unknown = [n for n in names if n not in known]
    if unknown:
        raise UsageError(
            f"unknown method(s) {', '.join(unknown)}",
            "methods",
            f"choose from {', '.join(known)}, all",
            option="methods",
        )
    return list(dict.fromkeys(names))


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
            "f1_best",
            "best_k",
            "f1_at_threshold",
            "auc",
            "precision_at_threshold",
            "recall_at_threshold",
            "train_s",
            "test_s",
            "k_sigma",
            "mu",
            "sigma",
            "threshold",
            "units",
            "positives",
        ):
            d[key] = getattr(self, key)
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
        """Why the gates fail (empty: passed); a gate judges every method that ran."""
        missed = []
        for m in self.methods:
            if m.skipped is not None:
                continue
            if min_f1 is not None and (m.f1_best or 0.0) < min_f1:
                missed.append(f"{m.name}: F1 {m.f1_best or 0.0:.3f} < {min_f1}")
            if min_auc is not None and (m.auc is None or m.auc < min_auc):
                shown = "n/a" if m.auc is None else f"{m.auc:.3f}"
                missed.append(f"{m.name}: AUC {shown} < {min_auc}")
        return missed


def require_labels(logs: Sequence[PreparedLog], option: str) -> None:
    for lg in logs:
        if lg.labels is None:
            raise DataError(
                "the log has no collision labels",
                f"{lg.source}, {option}",
                "evaluate needs ground truth: record std_msgs/Bool collision labels on the "
                "label topic",
                option="label_topic",
            )


def _has_seed(method: ScoringMethod) -> bool:
    return "seed" in inspect.signature(type(method)).parameters


def _val_stats(
    method: ScoringMethod, val: Sequence[PreparedLog]
) -> tuple[ScoreStats, list[FloatArray]]:
    total = ScoreStats()
    scores = []
    for lg in val:
        scores.append(method.score(lg))
        mask = ~method.unit_labels(lg) if lg.labels is not None else None
        judged = _judged(method, lg, len(scores[-1]))  # as `threshold` does
        mask = judged if mask is None else mask & judged
        total = total + ScoreStats.from_scores(scores[-1], mask)
    return total, scores


def _judged(method: ScoringMethod, lg: PreparedLog, units: int) -> BoolArray:
    """The units of ``lg`` that count: all but the samples within the filter's edge spans,
    which ``detect`` never flags (where start-up transients may still show)."""
    if method.unit == "sample" and lg.edge is not None and len(lg.edge) == units:
        return ~np.asarray(lg.edge, dtype=bool)
    return np.ones(units, dtype=bool)


def _events(
    method: ScoringMethod,
    logs: Sequence[PreparedLog],
    scores: Sequence[FloatArray],
    threshold: float,
    mu: float,
    links: Links,
) -> EventCounts:
    """Event counts of ``logs`` flagged at ``threshold``, with the events ``detect`` would
    report (``EventRules``, released at its level above ``mu``), merged over the logs. A
    calibration model's log flagged mostly is said (as ``detect`` says it)."""
    release = EventRules().release_level(threshold, mu)
    total = EventCounts()
    for lg, score in zip(logs, scores, strict=True):
        judged = _judged(method, lg, len(score))
        flags = (np.asarray(score) >= threshold) & judged
        hold = (np.asarray(score) >= release) & judged
        if method.calibrated and method.unit == "sample":
            counts = FlagCount()
            counts.add(flags, judged, lg.labels)
            counts.warn(lg.source, by=method.name)
        labels = lg.labels if lg.labels is not None else np.zeros(len(lg), dtype=bool)
        truth = links.get(lg.source)
        events = method.events(lg, np.asarray(score), flags, hold)
        isolation = truth is not None and method.isolates and lg.robot is not None
        stamps, unit_ns = lg.states.stamp_ns, method.unit_stamps(lg)
        total = total + event_counts(stamps, labels, unit_ns, flags, truth, events, isolation)
    return total


@dataclass(frozen=True)
class _Run:
    sweep: list[tuple[float, float]]
    figures: dict[str, float | None]
    mu: float
    sigma: float
    threshold: float
    units: int
    positives: int
    note: str | None
    roc: list[tuple[float, float]] = field(default_factory=list)


def _run_once(
    method: ScoringMethod,
    train: Sequence[PreparedLog],
    val: Sequence[PreparedLog],
    test: Sequence[PreparedLog],
    calibration: Calibration | None,
    k_sigma: float,
    links: Links,
    own_rule: bool = False,
) -> _Run:
    """One run of a method; ``own_rule``: a model that comes from the calibration is judged at
    the calibration's threshold, or with validation logs at what its rule sets on them (else
    at μ + ``k_sigma``·σ)."""
    from_calibration = method.calibrated and not train
    train_s: float | None = None
    if from_calibration:
        assert calibration is not None
        train_s = calibration.fit_s
    elif method.learns:
        start = time.perf_counter()
        method.fit(train)
        train_s = time.perf_counter() - start
    else:
        method.fit(train)
    val_scores: list[FloatArray] = []
    threshold: float | None = None
    if from_calibration and not val:
        assert calibration is not None
        # μ + iσ of the metrics is the clean scores' mean and standard deviation, whatever
        # estimator set the threshold itself; the threshold itself is the calibration's
        mu, sigma = calibration.require_threshold().mean_sd
        threshold = calibration.require_threshold().value if own_rule else None
    else:
        stats, val_scores = _val_stats(method, val)
        mu, sigma = stats.mu, stats.sigma
        if from_calibration and own_rule:
            # the calibration's own model on other validation logs: its threshold rule there
            assert calibration is not None
            again = threshold_prepared_logs(val, calibration, *same_rule(calibration))
            threshold = again.require_threshold().value
    start = time.perf_counter()
    scores = [method.score(lg) for lg in test]
    test_s = time.perf_counter() - start
    # what detect judges: never a sample within the filter's edge span
    judged = [_judged(method, lg, len(score)) for lg, score in zip(test, scores, strict=True)]
    y_score = np.concatenate([s[j] for s, j in zip(scores, judged, strict=True)] or [np.zeros(0)])
    y_true = np.concatenate([method.unit_labels(lg)[j] for lg, j in zip(test, judged, strict=True)])
    if len(y_score) != len(y_true) or not np.isfinite(y_score).all():
        raise DataError(
            f"method {method.name!r} gave {len(y_score)} scores for {len(y_true)} units, "
            "or non-finite ones",
            ", ".join(lg.source for lg in test[:3]),
            "report this as a bug in the method",
        )
    sweep = f1_sweep(y_true, y_score, mu, sigma)
    best_k, f1_best = best_of(sweep)
    if threshold is None:
        threshold = mu + k_sigma * sigma
    at = at_threshold(y_true, y_score, threshold)
    figures: dict[str, float | None] = {
        "f1_best": f1_best,
        "best_k": best_k,
        "f1_at_threshold": at.f1,
        "precision_at_threshold": at.precision,
        "recall_at_threshold": at.recall,
        "auc": auc(y_true, y_score),
        "train_s": train_s,
        "test_s": test_s,
    }
    figures.update(_events(method, test, scores, threshold, mu, links).to_dict())
    if val_scores:
        on_val = _events(method, val, val_scores, threshold, mu, {})
        figures["val_false_alarms"] = on_val.false_alarms
        figures["val_false_alarms_per_hour"] = on_val.false_alarms_per_hour
    note = getattr(method, "note", None)
    return _Run(
        sweep,
        figures,
        mu,
        sigma,
        threshold,
        len(y_true),
        int(y_true.sum()),
        note,
        roc_points(y_true, y_score),
    )


def _mean_std(values: list[float | None]) -> tuple[float | None, float | None]:
    vals = [v for v in values if v is not None]
    if not vals:
        return None, None
    return float(np.mean(vals)), float(np.std(vals))


def _combine(name: str, unit: str, k_sigma: float, runs: list[_Run]) -> MethodResult:
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


def evaluate_method(
    name: str,
    train: Sequence[PreparedLog],
    val: Sequence[PreparedLog],
    test: Sequence[PreparedLog],
    calibration: Calibration | None = None,
    k_sigma: float = DEFAULT_K_SIGMA,
    repeats: int = DEFAULT_REPEATS,
    links: Links | None = None,
    own_rule: bool = False,
) -> MethodResult:
    """One method's figures; a method that cannot run comes back with ``skipped`` set.

    ``links``: the true contact link per sample of each test log (by source), for isolation.
    ``own_rule``: the calibration's own model is judged by the calibration's threshold (its
    value, or its rule on ``val``); ``evaluate`` sets it unless ``k_sigma`` was given.
    """
    probe = make_method(name)
    unit = probe.unit
    try:
        # a calibrated method without training logs is the calibration's own model
        own = probe.calibrated and not train
        if own and calibration is None:
            raise MethodSkipped("needs a calibration, or training and validation logs")
        if own:
            assert calibration is not None
            if calibration.kind != probe.model_kind:
                raise MethodSkipped(
                    f"the calibration holds the {calibration.kind} model, not "
                    f"{probe.model_kind}; give training and validation logs to fit it"
                )
            probe = probe.from_calibration(calibration)
        probe.check([*train, *val, *test])
        if probe.learns and not train and not own:
            raise MethodSkipped("needs collision-free training logs")
        if not val and not own:
            raise MethodSkipped("needs collision-free validation logs to set its threshold")
        if own and not val:
            assert calibration is not None
            calibration.require_threshold()
        seeded = _has_seed(probe)
        runs = []
        for seed in range(repeats if seeded else 1):
            method = make_method(name, seed=seed) if seeded else probe
            runs.append(
                _run_once(method, train, val, test, calibration, k_sigma, links or {}, own_rule)
            )
    except MethodSkipped as exc:
        return MethodResult(name=name, unit=unit, skipped=str(exc) or "cannot run on these logs")
    result = _combine(name, unit, k_sigma, runs)
    th = calibration.threshold if calibration is not None and own and own_rule else None
    if th is not None and th.estimator != "mean-sd" and result.sigma:
        # judged by the calibration's threshold rule, on other μ and σ: its k over the metrics'
        result.k_sigma = ((result.threshold or 0.0) - (result.mu or 0.0)) / result.sigma
    return result


def load_logs(
    paths: Sequence[Path], setup: Setup, progress: Progress = _no_progress, desc: str = "reading"
) -> list[PreparedLog]:
    return list(progress_iter(setup.prepare_all(paths), len(paths), desc, progress))


def _by_source(logs: Iterable[PreparedLog]) -> list[PreparedLog]:
    """Logs in one order whatever order they were given or prepared in: methods that learn
    (and sums over logs) then see the same sequence on every run."""
    return sorted(logs, key=lambda lg: lg.source)


def progress_iter(items: Iterable[T], total: int, desc: str, progress: Progress) -> Iterable[T]:
    """Drive a lazy iterable through a progress callback that wants a sized sequence."""
    iterator = iter(items)
    for _ in progress(range(total), desc):
        yield next(iterator)


def _warn_on_overlap(
    test_paths: Sequence[Path],
    train_paths: Sequence[Path],
    val_paths: Sequence[Path],
    calibration: Calibration | None,
) -> None:
    """Test logs that also trained or thresholded a method make its figures optimistic."""
    learned = {Path(p).resolve() for p in (*train_paths, *val_paths)}
    if calibration is not None:
        learned |= {Path(p).resolve() for p in calibration.fit_logs}
        if calibration.threshold is not None:
            learned |= {Path(p).resolve() for p in calibration.threshold.logs}
    shared = [str(p) for p in test_paths if Path(p).resolve() in learned]
    if shared:
        log.warning(
            "test log(s) also used for fitting or thresholds: %s; the figures are optimistic",
            ", ".join(shared),
        )
    train = {Path(p).resolve() for p in train_paths}
    both = [str(p) for p in val_paths if Path(p).resolve() in train]
    if both:
        log.warning(
            "validation log(s) also used for training: %s; the thresholds are optimistic",
            ", ".join(both),
        )


def evaluate(
    test_paths: Sequence[Path],
    methods: Sequence[str],
    setup: Setup,
    calibration: Calibration | None = None,
    train_paths: Sequence[Path] = (),
    val_paths: Sequence[Path] = (),
    k_sigma: float | None = None,
    repeats: int = DEFAULT_REPEATS,
    progress: Progress = _no_progress,
    load: Loader | None = None,
    link_topic: str | None = None,
) -> Evaluation:
    """Every method in ``methods`` over the same prepared logs; isolation is judged where the
    test logs carry the contact link on ``link_topic`` (None: the default topic, where logs
    have it; a topic named that no test log has is an error, ``twincd.io.named``).

    ``load(paths, setup, description)`` prepares logs (default: one after another here; the
    CLI passes one that maps ``prepare_log`` over local processes or a cluster)."""
    if not test_paths:
        raise UsageError("no test logs given", "evaluate", "pass labelled logs with collisions")
    # each set's logs once (a log given twice would count its events twice)
    test_paths = expand_logs(test_paths)
    train_paths = expand_logs(train_paths) if train_paths else []
    val_paths = expand_logs(val_paths) if val_paths else []
    # a named option that none of the logs has is refused before any work
    setup = setup.for_logs([*test_paths, *train_paths, *val_paths])
    if link_topic is not None:
        settle_named(test_paths, LogOptions(), link_topic)
    link_topic = link_topic or DEFAULT_LINK_TOPIC
    if repeats < 1:
        raise UsageError(
            "repeats must be at least 1", f"repeats={repeats}", "give 1 or more", option="repeats"
        )
    own_rule = False
    if k_sigma is None:
        th = calibration.threshold if calibration is not None else None
        k_sigma = th.k_sigma if th is not None else DEFAULT_K_SIGMA
        # the calibration's own model is judged at the calibration's threshold (contract:
        # Metrics), whatever estimator set it; other methods at μ + kσ of their validation
        own_rule = th is not None
    _warn_on_overlap(test_paths, train_paths, val_paths, calibration)
    models = [model_class(name)[0] for name in methods if name in MODEL_KINDS]
    if any(m.needs_coulomb for m in models):
        setup = replace(setup, coulomb_eps=EPSILON_GRID)  # every ε candidate, for fitting
    if any(m.needs_regressor for m in models):
        # the whole regressor, which the identified methods fit on (not a calibration's Ỹθ)
        setup = replace(setup, regressor=True, regressor_optional=True, regressor_weights=None)
    if load is None:

        def load(paths: Sequence[Path], setup: Setup, desc: str) -> list[PreparedLog]:
            return load_logs(paths, setup, progress, desc)

    test = _by_source(load(test_paths, setup, "reading test logs"))
    require_labels(test, "test")
    links = {
        lg.source: read_links(lg.source, link_topic, lg.states.log_time_ns, setup.strict)
        for lg in test
    }
    train = _by_source(load(train_paths, setup, "reading train logs"))
    val = _by_source(load(val_paths, setup, "reading val logs"))
    # every method must see the same columns: the order comes from the robot model or the
    # calibration, so logs of one robot agree whatever their message order
    agreed_joints([*test, *train, *val])
    results = [
        evaluate_method(name, train, val, test, calibration, k_sigma, repeats, links, own_rule)
        for name in progress(list(methods), "evaluating")
    ]
    if all(r.skipped is not None for r in results):
        reasons = "; ".join(f"{r.name}: {r.skipped}" for r in results)
        raise UsageError(
            f"no method could run ({reasons})",
            "evaluate",
            "give a calibration, or collision-free training and validation logs",
            option="calibration,train,val",
        )
    return Evaluation(
        samples=sum(len(lg) for lg in test),
        positives=sum(int(np.sum(lg.labels)) for lg in test if lg.labels is not None),
        methods=results,
        test_logs=[lg.source for lg in test],
        train_logs=[lg.source for lg in train],
        val_logs=[lg.source for lg in val],
        lowpass=setup.lowpass.to_dict(),
    )
