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

``evaluate`` plans each method (``twincd.evaluation.planner``) and runs it by its strategy: the
calibration models in ``twincd.evaluation.calibrated``, the others in
``twincd.evaluation.whole``; the rows and their JSON are ``twincd.evaluation.results``'.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from twincd.calibration import Calibration
from twincd.defaults import DEFAULT_K_SIGMA, DEFAULT_REPEATS
from twincd.errors import UsageError
from twincd.evaluation.calibrated import evaluate_fitted, evaluate_own
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, make_method
from twincd.evaluation.planner import Progress, plan, sorted_paths, warn_on_overlap
from twincd.evaluation.results import Evaluation, MethodResult, Sources, skipped_result
from twincd.evaluation.whole import evaluate_whole
from twincd.executors.run import Each
from twincd.io.named import settle_named
from twincd.prepare.setup import Setup


def _no_progress(items: Sequence[Any], _desc: str) -> Iterable[Any]:
    return items


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
    run: Each | None = None,
    batch: int = 1,
    fast_cutoff_hz: float | None = None,
) -> Evaluation:
    """Every method in ``methods`` over the same test logs (each set's log files, each once:
    ``twincd.io.logs.expand_logs``, which ``twincd.commands.evaluate_logs`` runs; a log given
    twice would count its events twice); isolation is judged where the
    test logs carry the contact link on ``setup.options.link_topic`` (a link topic named
    that no test log has is an error, ``twincd.io.named``).

    ``run(func, paths, description)`` maps a per-log function over logs, results in the order
    of ``paths`` (default: one after another here; the CLI passes one that runs them on local
    processes or a cluster, ``--keep-going`` leaving failed logs out). ``batch``: test logs
    prepared at once for the methods that score whole logs (the executor's workers).
    ``fast_cutoff_hz``: the fast band of the models fitted here (``fit --fast-cutoff``)."""
    if not test_paths:
        raise UsageError("no test logs given", "evaluate", "pass labelled logs with collisions")
    setup, link_topic = _settle_links(setup, test_paths, [*test_paths, *train_paths, *val_paths])
    if repeats < 1:
        raise UsageError(
            "repeats must be at least 1", f"repeats={repeats}", "give 1 or more", option="repeats"
        )
    k_sigma, own_rule = _judged_at(k_sigma, calibration)
    warn_on_overlap(test_paths, train_paths, val_paths, calibration)
    if run is None:
        run = _one_by_one(progress)
    tests, train, val = (sorted_paths(p) for p in (test_paths, train_paths, val_paths))
    results: dict[str, MethodResult] = {}
    whole: dict[str, ScoringMethod] = {}
    tested: Sources | None = None
    for name in methods:
        try:
            method, how = plan(name, calibration, bool(train), bool(val))
            if how == "own":
                assert calibration is not None
                args = (calibration, setup, tests, val, k_sigma, own_rule, link_topic, run)
                results[name], tested = evaluate_own(name, method, *args)
            elif how == "fitted":
                fitted = (setup, train, val, tests, k_sigma, link_topic, run, fast_cutoff_hz)
                results[name], judged = evaluate_fitted(name, method, *fitted)
                tested = tested or judged
            else:
                whole[name] = method
        except MethodSkipped as exc:
            results[name] = skipped_result(name, make_method(name).unit, exc)
    if whole:
        more, judged = evaluate_whole(
            whole, setup, train, val, tests, k_sigma, repeats, link_topic, run, progress, batch
        )
        results.update(more)
        tested = tested or judged
    return _evaluation(tested, [results[name] for name in methods], setup)


def _settle_links(
    setup: Setup, test_paths: Sequence[Path], every_log: Sequence[Path]
) -> tuple[Setup, str]:
    """``setup`` for these logs and the link topic: a named option that none of the logs has
    is refused before any work; the contact links are read from the test logs only."""
    options = setup.options
    setup = replace(setup, options=options.unnamed("link_topic"))
    setup = setup.for_logs(every_log)
    settle_named(test_paths, options, topics=("link_topic",))
    return setup, options.link_topic


def _judged_at(k_sigma: float | None, calibration: Calibration | None) -> tuple[float, bool]:
    """The k of μ + kσ (given, else the calibration's, else the default) and whether the
    calibration's own model is judged at the calibration's threshold (contract: Metrics),
    whatever estimator set it (no k given and the calibration has a threshold); other methods
    are judged at μ + kσ of their validation logs."""
    if k_sigma is not None:
        return k_sigma, False
    th = calibration.threshold if calibration is not None else None
    return (th.k_sigma if th is not None else DEFAULT_K_SIGMA), th is not None


def _one_by_one(progress: Progress) -> Each:
    """The default mapper: each log after the other, here."""

    def run(func: Callable[[Path], Any], paths: Sequence[Path], desc: str) -> list[Any]:
        return [func(p) for p in progress(list(paths), f"reading {desc}")]

    return run


def _evaluation(tested: Sources | None, ordered: list[MethodResult], setup: Setup) -> Evaluation:
    """The evaluation of the logs read, a row per method in the order asked; a usage error
    when no method could run."""
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
