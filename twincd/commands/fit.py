"""``fit``: the calibration of the best model the logs allow (or the one asked for), with the
filter that model fits best with, written with its report (both or neither)."""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from twincd.commands.runs import (
    CommandRun,
    Options,
    as_path,
    check_reports,
    split_options,
)

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration

log = logging.getLogger("twincd")


@dataclass(frozen=True, kw_only=True)
class FitRun(CommandRun):
    """What ``fit_calibration`` gives: the calibration, with the run's warnings and failures."""

    calibration: Calibration


def fit_calibration(
    logs: Iterable[str | Path],
    *,
    model: str | None = None,
    output: str | Path | None = None,
    report: str | Path | None = None,
    force: bool = False,
    **options: Unpack[Options],
) -> FitRun:
    """``twincd fit``: fit ``model`` (None: the best the logs allow) over ``logs`` (files, bags,
    folders of logs; each log once), log by log (memory flat in the number of logs and
    samples).

    ``options``: the reading settings (``Settings``: ``robot``, ``topic``, ``cutoff_hz``, …)
    and how to run the logs (``RunOptions``: ``jobs``, ``scheduler``, ``keep_going``, …).
    Unless a filter is given, the identified models (and the best model) filter without
    overshoot at 1.5 Hz (``twincd.commands.settings.fit_setup``). ``output``: the calibration JSON
    to write; ``report``: a Markdown or HTML report, written first (both or neither). Neither may
    replace a file that is not twincd's own of its kind unless ``force``."""
    from twincd.calibration import fit_log, merge_fits
    from twincd.calibration.crossfit import crossfit_calibration
    from twincd.calibration.fitting import scored_by_depth
    from twincd.calibration.models import fit_features
    from twincd.commands.settings import fit_setup
    from twincd.executors.local import Bound, gathered_warnings
    from twincd.executors.run import all_or_nothing
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs

    with gathered_warnings() as warnings:
        running, asked = split_options(options)
        paths = expand_logs(logs)
        target = as_path(output)
        if target is not None:
            check_target(target, "calibration", force=force, inputs=paths)
        report_path, _ = check_reports(report, None, force=force, inputs=paths)
        setup, model = fit_setup(asked, model)
        setup = setup.for_logs(paths)  # a named option no log has: refused before any work
        figure = report_path is not None and report_path.suffix.lower() == ".html"
        crossfit = scored_by_depth(model)  # its noise from a second pass (below)
        features = replace(fit_features(model), speed_stats=not crossfit)
        single = crossfit and len(paths) == 1  # cross-fitted by time folds
        work: Bound[Path, Any] = Bound(fit_log, setup, (), features, single)
        if figure:
            from twincd.reports.traces import fit_log_with_pairs

            work = Bound(fit_log_with_pairs, setup, features, single)
        done = running.each(work, paths, "fitting")
        parts = [part for part, _ in done.results] if figure else done.results
        cal = merge_fits(parts, setup, model)
        failures = list(done.failures)
        if crossfit:
            cal = crossfit_calibration(cal, parts, setup, running.mapper(failures))
        with all_or_nothing() as written:  # the report, then the calibration: both or neither
            if report_path is not None:
                from twincd.reports import ThinnedPairs, fit_report

                pairs = ThinnedPairs.merge([p for _, p in done.results]) if figure else None
                written.append(report_path)
                source = cal.source if target is None else str(target)
                fit_report(report_path, replace(cal, source=source), pairs)
            if target is not None:
                cal.save(target)
        if report_path is not None:
            log.info("wrote %s", report_path)
        if target is not None:
            log.info(
                "wrote %s (%d samples from %d log(s))",
                target,
                cal.fit.samples,
                len(cal.fit.logs),
            )
    return FitRun(calibration=cal, warnings=tuple(warnings), failures=tuple(failures))
