"""Judge scoring methods as the seed paper does (section IV-B/C, Table II; contract: Metrics,
Methods).

Each method fits on the training logs, μ and σ of its score come from the validation logs, and
its scores on the test logs give the F1 sweep over μ + iσ, F1/precision/recall at μ + kσ (k the
calibration's) and the ROC AUC. Training time is the time of ``fit``; test time the time to
score every test log. Randomised methods run ``repeats`` times (seeds 0..N-1): mean and std.

Memory: test logs are judged one at a time and only each judged unit's score and label are
kept (float64 and bool, 9 bytes a unit per run; ``ScoredUnits`` computes the metrics from them),
with each log's event counts. The calibration's own model (``-c`` without training logs, what
``evaluate`` runs by default) streams every test and validation log block by block down
``detect``'s chain (``twincd.evaluation.streamed``), so its memory stays flat whatever the
log's length and it flags and groups events exactly as ``detect`` does. The other methods
work on whole prepared logs: the training and validation logs are held while they fit and set
their thresholds, and the test logs are prepared ``batch`` at a time.
"""

from __future__ import annotations

import inspect
import logging
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from twincd.calibration import Calibration, Threshold
from twincd.calibration.clean import ScoreStats
from twincd.calibration.models import EPSILON_GRID, MODEL_KINDS, model_class
from twincd.calibration.threshold import (
    LogScores,
    same_rule,
    score_log,
)
from twincd.defaults import DEFAULT_K_SIGMA, DEFAULT_REPEATS
from twincd.detection.detect import FlagCount
from twincd.detection.events import EventRules
from twincd.detection.files import threshold_logs
from twincd.errors import DataError, UsageError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, available, make_method
from twincd.evaluation.metrics import EventCounts, ScoredUnits, best_of, event_counts
from twincd.evaluation.streamed import JudgedLog, judge_log
from twincd.executors.local import Bound
from twincd.io.links import read_links
from twincd.io.logs import expand_logs
from twincd.io.named import settle_named
from twincd.prepare.joints import agreed_joints
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.setup import Setup, prepare_log
from twincd.signal.features import ModelFeatures
from twincd.types import BoolArray, FloatArray

T = TypeVar("T")
Progress = Callable[[Sequence[Any], str], Iterable[Any]]
# maps a per-log function over logs: (func, paths, what they are) -> results in paths' order
Mapper = Callable[[Callable[[Path], Any], Sequence[Path], str], list[Any]]

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


def require_labels(logs: Sequence[PreparedLog | JudgedLog], option: str) -> None:
    for lg in logs:
        if (lg.labels is None) if isinstance(lg, PreparedLog) else not lg.labelled:
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
        total = total + ScoreStats.from_scores(scores[-1], mask)
    return total, scores


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
        flags = np.asarray(score) >= threshold
        hold = np.asarray(score) >= release
        if method.calibrated and method.unit == "sample":
            counts = FlagCount()
            counts.add(flags, np.ones(len(flags), dtype=bool), lg.labels)
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


def _figures(
    units: ScoredUnits,
    mu: float,
    sigma: float,
    threshold: float,
    times: tuple[float | None, float],
    events: EventCounts,
    val_events: EventCounts | None,
    note: str | None,
) -> _Run:
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
    return _Run(
        sweep, figures, mu, sigma, threshold, units.units, units.positives, note, units.roc_points()
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


def _skipped(name: str, unit: str, exc: MethodSkipped) -> MethodResult:
    return MethodResult(name=name, unit=unit, skipped=str(exc) or "cannot run on these logs")


def _plan(
    name: str, calibration: Calibration | None, train: bool, val: bool
) -> tuple[ScoringMethod, str]:
    """The method to run and how: ``"own"`` the calibration's own model (read from the file,
    judged streamed), ``"fitted"`` a calibration model fitted on the training logs and
    thresholded on the validation logs as ``fit`` and ``threshold -k`` make one (then judged
    as its own), ``"whole"`` the others on whole prepared logs; MethodSkipped when it cannot
    run with the logs and file given (whatever the logs hold: ``check`` judges that once they
    are read)."""
    probe = make_method(name)
    # a calibrated method without training logs is the calibration's own model
    own = probe.calibrated and not train
    if own and calibration is None:
        raise MethodSkipped("needs a calibration, or training and validation logs")
    if own:
        assert calibration is not None
        if calibration.model.kind != probe.model_kind:
            raise MethodSkipped(
                f"the calibration holds the {calibration.model.kind} model, not "
                f"{probe.model_kind}; give training and validation logs to fit it"
            )
        return probe.from_calibration(calibration), "own"
    if probe.learns and not train:
        raise MethodSkipped("needs collision-free training logs")
    if not val:
        raise MethodSkipped("needs collision-free validation logs to set its threshold")
    return probe, "fitted" if probe.calibrated else "whole"


def _source(item: PreparedLog | JudgedLog | LogScores) -> str:
    return item.source


def _by_source(logs: Iterable[T]) -> list[T]:
    """Logs in one order whatever order they were given or prepared in: methods that learn
    (and sums over logs) then see the same sequence on every run."""
    return sorted(logs, key=_source)  # type: ignore[arg-type]


def _sorted_paths(paths: Sequence[Path]) -> list[Path]:
    """Paths in the order of their logs' sources (``str(Path(p))``)."""
    return sorted((Path(p) for p in paths), key=str)


def _at_k(calibration: Calibration, k_sigma: float, mu: float, sigma: float) -> Calibration:
    """The calibration judging at μ + kσ of the metrics' μ and σ (flags and events alike)."""
    return replace(calibration, threshold=Threshold(k_sigma, mu, sigma, estimator="mean-sd"))


def _require_scores(source: str, name: str, scores: int, units: int, finite: bool) -> None:
    if scores != units or not finite:
        raise DataError(
            f"method {name!r} gave {scores} scores for {units} units, or non-finite ones",
            source,
            "report this as a bug in the method",
        )


@dataclass
class _Sources:
    """The logs read (those that failed with ``--keep-going`` left out) and the test samples:
    what the Evaluation reports of them."""

    samples: int = 0
    positives: int = 0
    test: list[str] = field(default_factory=list)
    train: list[str] = field(default_factory=list)
    val: list[str] = field(default_factory=list)


def _evaluate_own(
    name: str,
    method: ScoringMethod,
    calibration: Calibration,
    setup: Setup,
    test_paths: Sequence[Path],
    val_paths: Sequence[Path],
    k_sigma: float,
    own_rule: bool,
    link_topic: str,
    run: Mapper,
) -> tuple[MethodResult, _Sources]:
    """The calibration's own model, every log streamed (``judge_log``): judged at the
    calibration's threshold (``own_rule``; with validation logs, at what its rule sets on them),
    else at μ + ``k_sigma``·σ."""
    # what the model scores from is its own features (detect's chain), whatever other methods
    # of this evaluation fit on
    th = calibration.require_threshold()
    sources = _Sources()
    if val_paths:
        scoring: Bound[Path, LogScores] = Bound(score_log, calibration, setup)
        parts = _by_source(run(scoring, val_paths, "val logs"))
        stats = ScoreStats()
        for part in parts:
            stats = stats + part.combined  # the score itself (its bands combined)
        mu, sigma = stats.mu, stats.sigma
        if own_rule:  # the calibration's own model on other validation logs: its rule there
            k, budget = same_rule(calibration)
            judge = threshold_logs(parts, calibration, setup, run, k, budget, refuse=False)
        sources.val = [part.source for part in parts]
    else:
        # μ + iσ of the metrics is the clean scores' mean and standard deviation, whatever
        # estimator set the threshold itself; the threshold itself is the calibration's
        mu, sigma = th.mean_sd
        judge = calibration
    if not own_rule:
        judge = _at_k(calibration, k_sigma, mu, sigma)
    work: Bound[Path, JudgedLog] = Bound(judge_log, judge, setup, link_topic, name, method.isolates)
    tests = _by_source(run(work, test_paths, "test logs"))
    require_labels(tests, "test")
    for lg in tests:
        _require_scores(lg.source, name, lg.judged, lg.judged, lg.units.finite)
    val_events = None
    if val_paths:
        counting: Bound[Path, JudgedLog] = Bound(
            judge_log, judge, setup, None, name, method.isolates, False
        )
        val_events = EventCounts()
        for lg in _by_source(run(counting, val_paths, "val false alarms")):
            val_events = val_events + lg.events
    events = EventCounts()
    for lg in tests:
        events = events + lg.events
    units = ScoredUnits.concat([lg.units for lg in tests])
    times = (calibration.fit.seconds, sum(lg.score_s for lg in tests))
    threshold = judge.require_threshold().value
    figures = _figures(units, mu, sigma, threshold, times, events, val_events, None)
    result = _combine(name, method.unit, k_sigma, [figures])
    result.judged_at = (
        f"μ + {k_sigma:g}σ = {threshold:.4g}"
        if not own_rule
        else f"its rule's threshold on the validation logs, {threshold:.4g}"
        if val_paths
        else f"the calibration's threshold, {threshold:.4g}"
    )
    other_scale = th.estimator != "mean-sd" or judge.score.bands > 1
    if own_rule and other_scale and result.sigma:
        # judged by the calibration's threshold rule, on other μ and σ (the median and MAD, or
        # each band's own): its k over the metrics' (the score's mean and sd)
        result.k_sigma = ((result.threshold or 0.0) - (result.mu or 0.0)) / result.sigma
    sources.samples = sum(lg.samples for lg in tests)
    sources.positives = sum(lg.positives for lg in tests)
    sources.test = [lg.source for lg in tests]
    return result, sources


def _fitted(
    method: ScoringMethod,
    setup: Setup,
    train: Sequence[Path],
    val: Sequence[Path],
    k_sigma: float,
    run: Mapper,
    fast_cutoff_hz: float | None = None,
) -> Calibration:
    """The calibration a calibrated ``method`` (one of our models, or the paper's) makes of the
    training logs, as ``fit --model`` makes it with this evaluation's filter (``fit_logs``: its
    noise cross-fitted and its fast band for a model scored by depth), thresholded at μ + kσ of
    the validation logs (each band's, ``threshold -k``): so ``evaluate -m KIND --train --val``
    scores as ``evaluate -c`` with that calibration. ``fast_cutoff_hz``: ``fit --fast-cutoff``
    for the models scored by depth (the others have one band)."""
    from twincd.calibration.fitting import fast_cutoff, fit_logs, scored_by_depth

    kind = method.model_kind
    asked = fast_cutoff_hz if scored_by_depth(kind) else None
    reading = replace(setup, fast_hz=fast_cutoff(kind, asked))
    try:
        calibration = fit_logs(train, reading, kind, run)
    except DataError as exc:  # the logs this method cannot fit on (no robot model, …)
        raise MethodSkipped(str(exc)) from exc
    scoring: Bound[Path, LogScores] = Bound(score_log, calibration, setup_for(calibration, setup))
    parts = _by_source(run(scoring, val, "val logs"))
    reading = setup_for(calibration, setup)
    return threshold_logs(parts, calibration, reading, run, k_sigma, refuse=False)


def setup_for(calibration: Calibration, setup: Setup) -> Setup:
    """How a calibration fitted in this evaluation reads logs: its own settings (joints,
    sampling period, bands, …), read with this evaluation's options."""
    return replace(
        Setup.from_calibration(calibration),
        options=setup.options,
        strict=setup.strict,
        allow_urdf_change=setup.allow_urdf_change,
        twin_threads=setup.twin_threads,
    )


@dataclass
class _Active:
    """One run (a method, a seed) fitted and thresholded, gathering its test units log by log."""

    method: ScoringMethod
    mu: float
    sigma: float
    threshold: float
    train_s: float | None
    val_events: EventCounts | None
    test_s: float = 0.0
    parts: list[tuple[BoolArray, FloatArray]] = field(default_factory=list)
    events: EventCounts = field(default_factory=EventCounts)

    @classmethod
    def fit(
        cls,
        method: ScoringMethod,
        train: Sequence[PreparedLog],
        val: Sequence[PreparedLog],
        k_sigma: float,
    ) -> _Active:
        train_s: float | None = None
        if method.learns:
            start = time.perf_counter()
            method.fit(train)
            train_s = time.perf_counter() - start
        else:
            method.fit(train)
        stats, val_scores = _val_stats(method, val)
        mu, sigma = stats.mu, stats.sigma
        threshold = mu + k_sigma * sigma
        val_events = _events(method, val, val_scores, threshold, mu, {}) if val_scores else None
        return cls(method, mu, sigma, threshold, train_s, val_events)

    def judge(self, lg: PreparedLog, links: tuple[str, ...] | None) -> None:
        """Score one test log; keep its judged units' labels and scores, count its events."""
        start = time.perf_counter()
        score = np.asarray(self.method.score(lg), dtype=np.float64)
        self.test_s += time.perf_counter() - start
        labels = np.asarray(self.method.unit_labels(lg), dtype=bool)
        finite = bool(np.isfinite(score).all())
        _require_scores(lg.source, self.method.name, len(score), len(labels), finite)
        self.parts.append((labels, score))
        self.events = self.events + _events(
            self.method, [lg], [score], self.threshold, self.mu, {lg.source: links}
        )

    def result(self) -> _Run:
        units = ScoredUnits.from_parts(self.parts)
        times = (self.train_s, self.test_s)
        note = getattr(self.method, "note", None)
        return _figures(
            units, self.mu, self.sigma, self.threshold, times, self.events, self.val_events, note
        )


@dataclass(frozen=True)
class _Joints:
    source: str
    joint_names: tuple[str, ...]


def _chunks(paths: Sequence[Path], size: int) -> Iterator[list[Path]]:
    for start in range(0, len(paths), max(1, size)):
        yield list(paths[start : start + max(1, size)])


def _evaluate_whole(
    methods: dict[str, ScoringMethod],
    setup: Setup,
    train_paths: Sequence[Path],
    val_paths: Sequence[Path],
    test_paths: Sequence[Path],
    k_sigma: float,
    repeats: int,
    link_topic: str,
    run: Mapper,
    progress: Progress,
    batch: int,
) -> tuple[dict[str, MethodResult], _Sources]:
    """Methods on whole prepared logs: each fits (every seed) on the training logs and takes
    μ, σ from the validation logs; then the test logs, ``batch`` at a time, are scored by every
    run and let go."""
    models = [model_class(name)[0] for name in methods if name in MODEL_KINDS]
    # every ε candidate, for fitting; the whole regressor, which the identified methods fit on
    # (skipped where no robot model is known)
    features = ModelFeatures(
        coulomb_eps=EPSILON_GRID if any(m.needs_coulomb for m in models) else (),
        regressor=any(m.needs_regressor for m in models),
        regressor_optional=True,
    )
    prepare: Bound[Path, PreparedLog] = Bound(prepare_log, setup, features)
    train: list[PreparedLog] = _by_source(run(prepare, train_paths, "train logs"))
    val: list[PreparedLog] = _by_source(run(prepare, val_paths, "val logs"))
    # every method must see the same columns: the order comes from the robot model or the
    # calibration, so logs of one robot agree whatever their message order
    seen = [_Joints(lg.source, lg.joint_names) for lg in [*train, *val]]
    agreed_joints(seen)
    tested = _Sources(train=[lg.source for lg in train], val=[lg.source for lg in val])
    skipped: dict[str, MethodResult] = {}
    active: dict[str, list[_Active]] = {}
    for name in progress(list(methods), "fitting"):
        probe = methods[name]
        try:
            probe.check([*train, *val])
            seeded = _has_seed(probe)
            seeds = range(repeats) if seeded else range(1)
            fitted = [make_method(name, seed=seed) if seeded else probe for seed in seeds]
            active[name] = [_Active.fit(m, train, val, k_sigma) for m in fitted]
        except MethodSkipped as exc:
            skipped[name] = _skipped(name, probe.unit, exc)
    del train, val
    for chunk in _chunks(test_paths, batch):
        logs: list[PreparedLog] = _by_source(run(prepare, chunk, "test logs"))
        require_labels(logs, "test")
        seen += [_Joints(lg.source, lg.joint_names) for lg in logs]
        agreed_joints(seen)
        for lg in logs:
            tested.samples += len(lg)
            tested.positives += int(np.sum(lg.labels)) if lg.labels is not None else 0
            tested.test.append(lg.source)
            links = read_links(lg.source, link_topic, lg.states.log_time_ns, setup.strict)
            for name in list(active):
                try:
                    methods[name].check([lg])
                except MethodSkipped as exc:
                    skipped[name] = _skipped(name, methods[name].unit, exc)
                    del active[name]
                    continue
                for one in active[name]:
                    one.judge(lg, links)
        del logs
    results = dict(skipped)
    for name, runs in active.items():
        results[name] = _combine(name, methods[name].unit, k_sigma, [r.result() for r in runs])
        results[name].judged_at = f"μ + {k_sigma:g}σ of the validation logs"
    return results, tested


def _warn_on_overlap(
    test_paths: Sequence[Path],
    train_paths: Sequence[Path],
    val_paths: Sequence[Path],
    calibration: Calibration | None,
) -> None:
    """Test logs that also trained or thresholded a method make its figures optimistic."""
    learned = {Path(p).resolve() for p in (*train_paths, *val_paths)}
    if calibration is not None:
        learned |= {Path(p).resolve() for p in calibration.fit.logs}
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
    run: Mapper | None = None,
    batch: int = 1,
    fast_cutoff_hz: float | None = None,
) -> Evaluation:
    """Every method in ``methods`` over the same test logs; isolation is judged where the
    test logs carry the contact link on ``setup.options.link_topic`` (a link topic named
    that no test log has is an error, ``twincd.io.named``).

    ``run(func, paths, description)`` maps a per-log function over logs, results in the order
    of ``paths`` (default: one after another here; the CLI passes one that runs them on local
    processes or a cluster, ``--keep-going`` leaving failed logs out). ``batch``: test logs
    prepared at once for the methods that score whole logs (the executor's workers).
    ``fast_cutoff_hz``: the fast band of the models fitted here (``fit --fast-cutoff``)."""
    if not test_paths:
        raise UsageError("no test logs given", "evaluate", "pass labelled logs with collisions")
    # each set's logs once (a log given twice would count its events twice)
    test_paths = expand_logs(test_paths)
    train_paths = expand_logs(train_paths) if train_paths else []
    val_paths = expand_logs(val_paths) if val_paths else []
    # a named option that none of the logs has is refused before any work; the contact
    # links are read from the test logs only
    options = setup.options
    setup = replace(setup, options=options.unnamed("link_topic"))
    setup = setup.for_logs([*test_paths, *train_paths, *val_paths])
    settle_named(test_paths, options, topics=("link_topic",))
    link_topic = options.link_topic
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
    if run is None:

        def run(func: Callable[[Path], Any], paths: Sequence[Path], desc: str) -> list[Any]:
            return [func(p) for p in progress(list(paths), f"reading {desc}")]

    tests, train, val = (_sorted_paths(p) for p in (test_paths, train_paths, val_paths))
    results: dict[str, MethodResult] = {}
    whole: dict[str, ScoringMethod] = {}
    tested: _Sources | None = None
    for name in methods:
        try:
            method, how = _plan(name, calibration, bool(train), bool(val))
            if how == "own":
                assert calibration is not None
                args = (calibration, setup, tests, val, k_sigma, own_rule, link_topic, run)
                results[name], tested = _evaluate_own(name, method, *args)
            elif how == "fitted":
                fitted = _fitted(method, setup, train, val, k_sigma, run, fast_cutoff_hz)
                args = (
                    fitted,
                    setup_for(fitted, setup),
                    tests,
                    val,
                    k_sigma,
                    True,
                    link_topic,
                    run,
                )
                results[name], own_tested = _evaluate_own(name, method, *args)
                results[name].judged_at = f"μ + {k_sigma:g}σ of the validation logs"
                tested = tested or replace(own_tested, train=[str(p) for p in train])
            else:
                whole[name] = method
        except MethodSkipped as exc:
            results[name] = _skipped(name, make_method(name).unit, exc)
    if whole:
        more, judged = _evaluate_whole(
            whole, setup, train, val, tests, k_sigma, repeats, link_topic, run, progress, batch
        )
        results.update(more)
        tested = tested or judged
    ordered = [results[name] for name in methods]
    if all(r.skipped is not None for r in ordered):
        reasons = "; ".join(f"{r.name}: {r.skipped}" for r in ordered)
        raise UsageError(
            f"no method could run ({reasons})",
            "evaluate",
            "give a calibration, or collision-free training and validation logs",
            option="calibration,train,val",
        )
    assert tested is not None
    return Evaluation(
        samples=tested.samples,
        positives=tested.positives,
        methods=ordered,
        test_logs=tested.test,
        train_logs=tested.train,
        val_logs=tested.val,
        lowpass=setup.lowpass.to_dict(),
    )
