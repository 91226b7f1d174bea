"""``evaluate``'s strategy for the calibration models (contract: Metrics): the calibration's
own model, every test and validation log streamed down ``detect``'s chain (``judge_log``,
``twincd.evaluation.streamed``) and judged at the calibration's threshold or at μ + kσ
(``evaluate_own``); and a calibration model fitted on the training logs and thresholded on the
validation logs as ``fit`` and ``threshold -k`` make one, then judged as its own
(``evaluate_fitted``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from twincd.calibration import Calibration, Threshold
from twincd.calibration.clean import ScoreStats
from twincd.calibration.threshold import LogScores, same_rule, score_log
from twincd.detection.files import threshold_logs
from twincd.errors import DataError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod
from twincd.evaluation.metrics import EventCounts, ScoredUnits
from twincd.evaluation.planner import by_source, require_labels, require_scores
from twincd.evaluation.results import MethodResult, Sources, combine_runs, run_figures
from twincd.evaluation.streamed import JudgedLog, judge_log
from twincd.executors.local import Bound
from twincd.executors.run import Each
from twincd.prepare.setup import Setup


def evaluate_own(
    name: str,
    method: ScoringMethod,
    calibration: Calibration,
    setup: Setup,
    test_paths: Sequence[Path],
    val_paths: Sequence[Path],
    k_sigma: float,
    own_rule: bool,
    link_topic: str,
    run: Each,
) -> tuple[MethodResult, Sources]:
    """The calibration's own model, every log streamed (``judge_log``): judged at the
    calibration's threshold (``own_rule``; with validation logs, at what its rule sets on them),
    else at μ + ``k_sigma``·σ."""
    # what the model scores from is its own features (detect's chain), whatever other methods
    # of this evaluation fit on
    th = calibration.require_threshold()
    sources = Sources()
    if val_paths:
        scoring: Bound[Path, LogScores] = Bound(score_log, calibration, setup)
        parts = by_source(run(scoring, val_paths, "val logs"))
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
    tests = by_source(run(work, test_paths, "test logs"))
    require_labels(tests, "test")
    for lg in tests:
        require_scores(lg.source, name, lg.judged, lg.judged, lg.units.finite)
    val_events = None
    if val_paths:
        counting: Bound[Path, JudgedLog] = Bound(
            judge_log, judge, setup, None, name, method.isolates, False
        )
        val_events = EventCounts()
        for lg in by_source(run(counting, val_paths, "val false alarms")):
            val_events = val_events + lg.events
    events = EventCounts()
    for lg in tests:
        events = events + lg.events
    units = ScoredUnits.concat([lg.units for lg in tests])
    times = (calibration.fit.seconds, sum(lg.score_s for lg in tests))
    threshold = judge.require_threshold().value
    figures = run_figures(units, mu, sigma, threshold, times, events, val_events, None)
    result = combine_runs(name, method.unit, k_sigma, [figures])
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


def _at_k(calibration: Calibration, k_sigma: float, mu: float, sigma: float) -> Calibration:
    """The calibration judging at μ + kσ of the metrics' μ and σ (flags and events alike)."""
    return replace(calibration, threshold=Threshold(k_sigma, mu, sigma, estimator="mean-sd"))


def _fitted(
    method: ScoringMethod,
    setup: Setup,
    train: Sequence[Path],
    val: Sequence[Path],
    k_sigma: float,
    run: Each,
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
    parts = by_source(run(scoring, val, "val logs"))
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


def evaluate_fitted(
    name: str,
    method: ScoringMethod,
    setup: Setup,
    train_paths: Sequence[Path],
    val_paths: Sequence[Path],
    test_paths: Sequence[Path],
    k_sigma: float,
    link_topic: str,
    run: Each,
    fast_cutoff_hz: float | None = None,
) -> tuple[MethodResult, Sources]:
    """A calibrated ``method`` fitted on the training logs and thresholded at μ + ``k_sigma``·σ
    of the validation logs (``_fitted``), then judged as the calibration's own model
    (``evaluate_own``, at that threshold)."""
    fitted = _fitted(method, setup, train_paths, val_paths, k_sigma, run, fast_cutoff_hz)
    reading = setup_for(fitted, setup)
    args = (fitted, reading, test_paths, val_paths, k_sigma, True, link_topic, run)
    result, sources = evaluate_own(name, method, *args)
    result.judged_at = f"μ + {k_sigma:g}σ of the validation logs"
    return result, replace(sources, train=[str(p) for p in train_paths])
