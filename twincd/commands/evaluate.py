"""``evaluate``: the seed paper's Table II on labelled test logs (contract: Metrics, Methods),
its three sets of logs read on one executor, then the reports (all or nothing)."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.commands.runs import (
    CommandRun,
    Options,
    check_reports,
    input_files,
    split_options,
)
from twincd.defaults import DEFAULT_REPEATS

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration
    from twincd.evaluation.planner import Progress
    from twincd.evaluation.results import Evaluation
    from twincd.executors.run import LogRun, Running
    from twincd.prepare.setup import Setup

log = logging.getLogger("twincd")


@dataclass(frozen=True, kw_only=True)
class EvaluateRun(CommandRun):
    """What ``evaluate_logs`` gives: the evaluation (a row per method) and the gates it missed
    (one line each; empty: passed)."""

    evaluation: Evaluation
    missed: list[str] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """2 when a log failed (3 for a defect), else 1 when a gate was missed, else 0."""
        return super().exit_code or int(bool(self.missed))

    def to_dict(self) -> dict[str, Any]:
        """``evaluate --json`` (contract: ``--json`` documents) but for its errors and
        warnings."""
        return self.evaluation.to_dict()


def evaluate_logs(
    logs: Iterable[str | Path],
    calibration: Calibration | str | Path | None = None,
    *,
    methods: str | Sequence[str] | None = None,
    train: Iterable[str | Path] = (),
    val: Iterable[str | Path] = (),
    k_sigma: float | None = None,
    repeats: int = DEFAULT_REPEATS,
    min_f1: float | None = None,
    min_auc: float | None = None,
    report: str | Path | None = None,
    junit: str | Path | None = None,
    step_summary: bool = True,
    force: bool = False,
    **options: Unpack[Options],
) -> EvaluateRun:
    """``twincd evaluate``: score ``methods`` (comma-separated names or a list, ``"all"``;
    None: the calibration's own model, ``proposed`` without one) on labelled test ``logs``:
    F1 over μ + iσ, F1 at the threshold, ROC AUC, event metrics and times
    (``twincd.evaluation.runner.evaluate``).

    With ``calibration`` alone its own model runs at its threshold; with ``train`` and ``val``
    every method fits on ``train`` and sets μ and σ on ``val`` (at μ + ``k_sigma`` σ). The three
    sets of logs are read on one executor (``jobs`` local processes, or the Dask cluster at
    ``scheduler``). ``min_f1`` and ``min_auc``: gates (``EvaluateRun.missed``). ``report``,
    ``junit``, ``step_summary`` and ``options`` as ``detect_files``'."""
    from twincd.calibration import Calibration
    from twincd.executors.local import gathered_warnings
    from twincd.executors.run import LogRun
    from twincd.io.logs import expand_logs

    with gathered_warnings() as warnings:
        running, asked = split_options(options)
        cal = None if calibration is None else Calibration.given(calibration)
        names = _method_names(methods, cal)
        test_paths = expand_logs(logs)
        train_paths = expand_logs(train) if train else []
        val_paths = expand_logs(val) if val else []
        inputs = [*test_paths, *train_paths, *val_paths, *input_files([calibration])]
        report_path, junit_path = check_reports(report, junit, force=force, inputs=inputs)
        setup = asked.resolve(cal)
        failed: LogRun[Any] = LogRun()
        paths = (test_paths, train_paths, val_paths)
        given = (k_sigma, repeats, asked.fast_cutoff_hz)
        result = _evaluated(running, failed, paths, names, setup, cal, *given)
        if result.positives == 0:
            log.warning(
                "no test sample is labelled as a collision: F1 is 0 and AUC undefined "
                "(evaluate wants logs with collisions and their %s labels)",
                setup.options.label_topic,
            )
        missed = result.missed_gates(min_f1, min_auc)
        gates = (min_f1, min_auc)
        _write_reports(result, missed, cal, report_path, junit_path, step_summary, gates)
        _warn_skipped_and_missed(result, missed, failed)
    return EvaluateRun(
        evaluation=result,
        missed=missed,
        warnings=tuple(warnings),
        failures=tuple(failed.failures),
    )


def _method_names(methods: str | Sequence[str] | None, cal: Calibration | None) -> list[str]:
    """The methods asked for (none: the calibration's own model, ``proposed`` without one)."""
    from twincd.evaluation.methods import method_for, parse_methods

    text = methods if methods is None or isinstance(methods, str) else ",".join(methods)
    return parse_methods(text, method_for(cal.model.kind) if cal is not None else "proposed")


def _evaluated(
    running: Running,
    failed: LogRun[Any],
    paths: tuple[list[Path], list[Path], list[Path]],
    names: list[str],
    setup: Setup,
    cal: Calibration | None,
    k_sigma: float | None,
    repeats: int,
    fast_cutoff_hz: float | None,
) -> Evaluation:
    """``evaluate`` of the test, training and validation ``paths``, their logs read on one
    executor (``running``'s: local processes or a Dask cluster), each log that failed (with
    ``keep_going``) gathered once in ``failed``."""
    from twincd.evaluation.runner import evaluate
    from twincd.executors.cluster import open_executor

    test_paths, train_paths, val_paths = paths
    every_log = [*test_paths, *train_paths, *val_paths]
    with open_executor(running.jobs, running.scheduler, every_log) as executor:
        return evaluate(
            test_paths,
            names,
            setup,
            calibration=cal,
            train_paths=train_paths,
            val_paths=val_paths,
            k_sigma=k_sigma,
            repeats=repeats,
            progress=_progress_bar(running),
            fast_cutoff_hz=fast_cutoff_hz,
            run=running.mapper(failed.failures, executor, "reading "),
            batch=max(1, getattr(executor, "workers", 1) or 1),
        )


def _progress_bar(running: Running) -> Progress:
    """``evaluate``'s progress: items passed on through ``running``'s display, if any."""

    def bar(items: Sequence[Any], what: str) -> Iterator[Any]:
        display = running.progress
        if display is None:
            yield from items
            return
        with display(len(items), what) as advance:
            for item in items:
                yield item
                advance(1, 0)

    return bar


def _warn_skipped_and_missed(result: Evaluation, missed: list[str], failed: LogRun[Any]) -> None:
    """A warning for each method skipped, then for each gate missed (unless a log failed: that
    is the run's answer, before any gate)."""
    for m in result.methods:
        if m.skipped is not None:
            log.warning("method %s skipped: %s", m.name, m.skipped)
    if not failed.failures:  # a log that failed is the run's answer, before any gate
        for line in missed:
            log.warning("gate missed: %s", line)


def _write_reports(
    result: Evaluation,
    missed: list[str],
    cal: Calibration | None,
    report: Path | None,
    junit: Path | None,
    step_summary: bool,
    gates: tuple[float | None, float | None],
) -> None:
    """The report and the JUnit file, both or neither (``all_or_nothing``), and the job
    summary."""
    from twincd.evaluation.markdown import evaluation_markdown
    from twincd.executors.run import all_or_nothing
    from twincd.reports import (
        append_step_summary,
        calibration_settings,
        evaluation_junit,
        evaluation_report,
    )
    from twincd.reports.documents import write_text

    with all_or_nothing() as written:
        written.extend(p for p in (report, junit) if p is not None)
        settings = calibration_settings(cal) if cal is not None else []
        if report is not None:
            evaluation_report(report, result, missed, settings, gates)
            log.info("wrote %s", report)
        if junit is not None:
            write_text(junit, evaluation_junit(result, *gates))
            log.info("wrote %s", junit)
        if step_summary:
            append_step_summary(evaluation_markdown(result, missed))
