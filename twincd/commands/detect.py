"""``detect``: each log streamed down its calibration's chain, its per-sample output written
where the work runs, then the reports (all or nothing)."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.commands.runs import (
    CommandRun,
    Options,
    as_path,
    check_reports,
    input_files,
    split_options,
)
from twincd.errors import UsageError

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration
    from twincd.detection import DetectionSummary
    from twincd.prepare.frames import FrameSink
    from twincd.prepare.setup import Setup

log = logging.getLogger("twincd")


@dataclass(frozen=True, kw_only=True)
class DetectRun(CommandRun):
    """What ``detect_files`` gives: each log's summary (counts and events), in the order given,
    at the calibration's ``threshold``."""

    logs: list[DetectionSummary] = field(default_factory=list)
    threshold: float

    @property
    def collision(self) -> bool:
        return any(s.events for s in self.logs)

    @property
    def exit_code(self) -> int:
        """2 when a log failed (3 for a defect), else 1 when a collision was found, else 0."""
        return super().exit_code or int(self.collision)

    def to_dict(self) -> dict[str, object]:
        """``detect --json`` (contract: ``--json`` documents) but for its errors and
        warnings."""
        return {
            "collision": self.collision,
            "threshold": self.threshold,
            "logs": [s.to_dict() for s in self.logs],
        }


def detect_files(
    logs: Iterable[str | Path],
    calibration: Calibration | str | Path,
    *,
    output: str | Path | None = None,
    report: str | Path | None = None,
    junit: str | Path | None = None,
    step_summary: bool = True,
    force: bool = False,
    **options: Unpack[Options],
) -> DetectRun:
    """``twincd detect``: collisions in ``logs`` (files, bags, folders of logs; each log once),
    each streamed block by block down ``calibration``'s chain (one, or its file) at flat
    memory, on ``jobs`` local processes or the Dask cluster at ``scheduler``.

    ``options`` as ``fit_calibration``'s; how the logs are read is the calibration's by
    default, and may be given (``twincd.SetupOptions``: a filter that contradicts it is an
    error).
    ``output``: per-sample output (.mcap: the input plus twincd's channels, .csv, .jsonl) for
    one log, or a folder of ``<log>.detect.mcap`` files; ``report`` (.md or .html) and
    ``junit``: written after every log (all or nothing); ``step_summary``: the Markdown
    summary appended to ``$GITHUB_STEP_SUMMARY`` when it is set."""
    from twincd.calibration import Calibration
    from twincd.detection.outputs import detect_targets
    from twincd.executors.local import Bound, gathered_warnings
    from twincd.executors.run import all_or_nothing
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs

    with gathered_warnings() as warnings:
        running, asked = split_options(options)
        cal = Calibration.given(calibration)
        threshold = cal.require_threshold().value
        paths = expand_logs(logs)
        setup = asked.resolve(cal).for_logs(paths)
        targets = detect_targets(paths, as_path(output))
        inputs = [*paths, *input_files([calibration])]
        for target in targets:
            if target is not None:
                kind = "detect" if target.suffix.lower() == ".mcap" else "table"
                check_target(target, kind, force=force, inputs=inputs)
        report_path, junit_path = check_reports(report, junit, force=force, inputs=inputs)
        trace = report_path is not None and report_path.suffix.lower() == ".html"
        items = list(zip(paths, targets, strict=True))
        with all_or_nothing() as written:
            # one log at a time: only the small summaries are kept, so memory stays flat
            written.extend(target for target in targets if target is not None)
            work: Bound[tuple[Path, Path | None], DetectionSummary] = Bound(
                detect_and_write, cal, setup, trace
            )
            done = running.each(work, items, "detecting")
            written.extend(p for p in (report_path, junit_path) if p is not None)
            _write_reports(done.results, cal, report_path, junit_path, step_summary)
        where = {str(path): target for path, target in items}
        for result in done.results:  # the per-sample outputs written, as other commands say
            if where.get(result.source) is not None:
                log.info("wrote %s (%d samples)", where[result.source], result.samples)
    return DetectRun(
        logs=done.results,
        threshold=threshold,
        warnings=tuple(warnings),
        failures=tuple(done.failures),
    )


class DetectOptions(Options, total=False):
    """The keyword arguments of ``detect_files``."""

    output: str | Path | None
    report: str | Path | None
    junit: str | Path | None
    step_summary: bool
    force: bool


def detect_file(
    log: str | Path, calibration: Calibration | str | Path, **options: Unpack[DetectOptions]
) -> DetectionSummary:
    """``twincd detect`` on one log (``detect_files``, whose keyword arguments it takes): its
    summary (counts and events), whose ``warnings`` are the run's. A folder of several logs is
    an error."""
    from twincd.io.logs import expand_logs

    paths = expand_logs([log])
    if len(paths) != 1:
        raise UsageError(
            f"one log expected, {len(paths)} found",
            str(log),
            "give one log file or bag (detect_files takes several)",
        )
    run = detect_files(paths, calibration, **options)
    summary = run.logs[0]
    summary.warnings = list(run.warnings)
    return summary


def _write_reports(
    results: Sequence[DetectionSummary],
    cal: Calibration,
    report: Path | None,
    junit: Path | None,
    step_summary: bool,
) -> None:
    from twincd.reports import (
        append_step_summary,
        calibration_settings,
        detection_junit,
        detection_markdown,
        detection_report,
    )
    from twincd.reports.documents import write_text

    settings = calibration_settings(cal)
    if report is not None:
        detection_report(report, results, settings)
        log.info("wrote %s", report)
    if junit is not None:
        write_text(junit, detection_junit(results))
        log.info("wrote %s", junit)
    if step_summary:
        append_step_summary(detection_markdown(results, settings))


def detect_and_write(
    item: tuple[Path, Path | None],
    calibration: Calibration,
    setup: Setup,
    trace: bool = False,
) -> DetectionSummary:
    """The per-log step of ``detect``: stream one log, writing its per-sample output (if any)
    where the work runs; only the summary travels back (with ``trace``, also the bounded
    figure data of a report)."""
    from twincd.detection.files import detect_streamed
    from twincd.detection.outputs import open_sink
    from twincd.reports.traces import DetectionTrace

    path, target = item
    with contextlib.ExitStack() as outputs:
        sinks: list[FrameSink] = []
        if target is not None:
            sink = open_sink(path, target, calibration.joint_names, partial=not setup.strict)
            sinks.append(outputs.enter_context(sink))
        figure_data = None
        if trace:
            threshold = calibration.require_threshold().value
            figure_data = DetectionTrace(calibration.joint_names, threshold)
            sinks.append(figure_data)
        summary = detect_streamed(path, calibration, setup, sinks)
        summary.trace = figure_data
        return summary
