"""``evaluate``'s strategy for the methods on whole prepared logs (the paper's baselines and
any method not read from a calibration): each fits (every seed of a randomised one) on the
training logs and takes μ and σ of its score from the validation logs; then the test logs are
prepared ``batch`` at a time, scored by every run and let go, each run keeping only its test
units' labels and scores and its event counts (``evaluate_whole``)."""

from __future__ import annotations

import inspect
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from twincd.calibration.clean import ScoreStats
from twincd.calibration.models import EPSILON_GRID, MODEL_KINDS, model_class
from twincd.detection.detect import FlagCount
from twincd.detection.events import EventRules
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, make_method
from twincd.evaluation.metrics import EventCounts, ScoredUnits, event_counts
from twincd.evaluation.planner import (
    Progress,
    by_source,
    require_labels,
    require_scores,
)
from twincd.evaluation.results import (
    MethodResult,
    RunFigures,
    Sources,
    combine_runs,
    run_figures,
    skipped_result,
)
from twincd.executors.local import Bound
from twincd.executors.run import Each
from twincd.io.links import read_links
from twincd.prepare.joints import agreed_joints
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.setup import Setup, prepare_log
from twincd.signal.features import ModelFeatures
from twincd.types import BoolArray, FloatArray

# per log (its source), the touched link per sample (None: the log has no link topic)
Links = dict[str, "tuple[str, ...] | None"]


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
        require_scores(lg.source, self.method.name, len(score), len(labels), finite)
        self.parts.append((labels, score))
        self.events = self.events + _events(
            self.method, [lg], [score], self.threshold, self.mu, {lg.source: links}
        )

    def result(self) -> RunFigures:
        units = ScoredUnits.from_parts(self.parts)
        times = (self.train_s, self.test_s)
        note = getattr(self.method, "note", None)
        return run_figures(
            units, self.mu, self.sigma, self.threshold, times, self.events, self.val_events, note
        )


@dataclass(frozen=True)
class _Joints:
    source: str
    joint_names: tuple[str, ...]


def _chunks(paths: Sequence[Path], size: int) -> Iterator[list[Path]]:
    for start in range(0, len(paths), max(1, size)):
        yield list(paths[start : start + max(1, size)])


def evaluate_whole(
    methods: dict[str, ScoringMethod],
    setup: Setup,
    train_paths: Sequence[Path],
    val_paths: Sequence[Path],
    test_paths: Sequence[Path],
    k_sigma: float,
    repeats: int,
    link_topic: str,
    run: Each,
    progress: Progress,
    batch: int,
) -> tuple[dict[str, MethodResult], Sources]:
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
    train: list[PreparedLog] = by_source(run(prepare, train_paths, "train logs"))
    val: list[PreparedLog] = by_source(run(prepare, val_paths, "val logs"))
    # every method must see the same columns: the order comes from the robot model or the
    # calibration, so logs of one robot agree whatever their message order
    seen = [_Joints(lg.source, lg.joint_names) for lg in [*train, *val]]
    agreed_joints(seen)
    tested = Sources(train=[lg.source for lg in train], val=[lg.source for lg in val])
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
            skipped[name] = skipped_result(name, probe.unit, exc)
    del train, val
    for chunk in _chunks(test_paths, batch):
        logs: list[PreparedLog] = by_source(run(prepare, chunk, "test logs"))
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
                    skipped[name] = skipped_result(name, methods[name].unit, exc)
                    del active[name]
                    continue
                for one in active[name]:
                    one.judge(lg, links)
        del logs
    results = dict(skipped)
    for name, runs in active.items():
        results[name] = combine_runs(name, methods[name].unit, k_sigma, [r.result() for r in runs])
        results[name].judged_at = f"μ + {k_sigma:g}σ of the validation logs"
    return results, tested
