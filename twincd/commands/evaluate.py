"""``evaluate``: the seed paper's Table II on labelled test logs (contract: Metrics, Methods),
its three sets of logs read on one executor, then the reports (all or nothing)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.commands.runs import (
    CommandRun,
    Options,
    as_path,
    check_reports,
    input_files,
    setup_options,
    split_options,
)
from twincd.defaults import DEFAULT_REPEATS

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration
    from twincd.evaluation.runner import Evaluation

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
    from twincd.evaluation.runner import evaluate, method_for, parse_methods
    from twincd.executors.cluster import open_executor
    from twincd.executors.local import gathered_warnings
    from twincd.executors.run import LogRun, all_or_nothing
    from twincd.io.logs import expand_logs

    with gathered_warnings() as warnings:
        running, settings = split_options(options)
        cal = None if calibration is None else Calibration.given(calibration)
        text = methods if methods is None or isinstance(methods, str) else ",".join(methods)
        names = parse_methods(text, method_for(cal.model.kind) if cal is not None else "proposed")
        test_paths = expand_logs(logs)
        train_paths = expand_logs(train) if train else []
        val_paths = expand_logs(val) if val else []
        inputs = [*test_paths, *train_paths, *val_paths, *input_files([calibration])]
        report_path, junit_path = as_path(report), as_path(junit)
        check_reports(report_path, junit_path, force=force, inputs=inputs)
        setup = setup_options(settings).resolve(cal)
        failed: LogRun[Any] = LogRun()

        def bar(items: Sequence[Any], what: str) -> Iterator[Any]:
            display = running.progress
            if display is None:
                yield from items
                return
            with display(len(items), what) as advance:
                for item in items:
                    yield item
                    advance(1, 0)

        every_log = [*test_paths, *train_paths, *val_paths]
        with open_executor(running.jobs, running.scheduler, every_log) as executor:

            def run(func: Callable[[Path], Any], paths: Sequence[Path], what: str) -> list[Any]:
                if not paths:
                    return []
                done = running.each(func, paths, f"reading {what}", executor=executor)
                for failure in done.failures:  # with keep_going: reported, the rest goes on
                    if failure.path not in {f.path for f in failed.failures}:  # once per log
                        failed.failures.append(failure)
                return list(done.results)

            result = evaluate(
                test_paths,
                names,
                setup,
                calibration=cal,
                train_paths=train_paths,
                val_paths=val_paths,
                k_sigma=k_sigma,
                repeats=repeats,
                progress=bar,
                fast_cutoff_hz=settings.get("fast_cutoff_hz"),
                run=run,
                batch=max(1, getattr(executor, "workers", 1) or 1),
            )
        if result.positives == 0:
            log.warning(
                "no test sample is labelled as a collision: F1 is 0 and AUC undefined "
                "(evaluate wants logs with collisions and their %s labels)",
                setup.options.label_topic,
            )
        missed = result.missed_gates(min_f1, min_auc)
        with all_or_nothing() as written:  # the report and the JUnit file: both or neither
            written.extend(p for p in (report_path, junit_path) if p is not None)
            gates = (min_f1, min_auc)
            _write_reports(result, missed, cal, report_path, junit_path, step_summary, gates)
        for m in result.methods:
            if m.skipped is not None:
                log.warning("method %s skipped: %s", m.name, m.skipped)
        if not failed.failures:  # a log that failed is the run's answer, before any gate
            for line in missed:
                log.warning("gate missed: %s", line)
    return EvaluateRun(
        evaluation=result,
        missed=missed,
        warnings=tuple(warnings),
        failures=tuple(failed.failures),
    )


def _write_reports(
    result: Evaluation,
    missed: list[str],
    cal: Calibration | None,
    report: Path | None,
    junit: Path | None,
    step_summary: bool,
    gates: tuple[float | None, float | None],
) -> None:
    from twincd.evaluation.markdown import evaluation_markdown
    from twincd.reports import (
        append_step_summary,
        calibration_settings,
        evaluation_junit,
        evaluation_report,
    )
    from twincd.reports.documents import write_text

    settings = calibration_settings(cal) if cal is not None else []
    if report is not None:
        evaluation_report(report, result, missed, settings, gates)
        log.info("wrote %s", report)
    if junit is not None:
        write_text(junit, evaluation_junit(result, *gates))
        log.info("wrote %s", junit)
    if step_summary:
        append_step_summary(evaluation_markdown(result, missed))
