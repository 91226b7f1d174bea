"""``threshold``: the detection threshold from the score on collision-free logs, and the false
alarms it gives on them counted as ``evaluate`` counts them."""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.commands.runs import (
    CommandRun,
    Options,
    as_path,
    split_options,
)

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from twincd.calibration import Calibration

log = logging.getLogger("twincd")


@dataclass(frozen=True, kw_only=True)
class ThresholdRun(CommandRun):
    """What ``threshold_calibration`` gives: the calibration with its threshold, and where it
    was written (None: nowhere)."""

    calibration: Calibration
    written: Path | None = None

    def to_dict(self) -> dict[str, object]:
        """``threshold --json`` (contract: ``--json`` documents) but for its errors and
        warnings: the value, the rule, the false alarms counted on the logs, and the
        ``threshold`` object of the calibration."""
        th = self.calibration.require_threshold()
        return {
            "value": th.value,
            "rule": "budget" if th.budget_per_hour is not None else "k-sigma",
            "false_alarms": th.false_alarms,
            "hours": None if th.judged_s is None else th.judged_s / 3600.0,
            "calibration": None if self.written is None else str(self.written),
            "threshold": th.to_dict(),
        }


def threshold_calibration(
    logs: Iterable[str | Path],
    calibration: Calibration | str | Path,
    *,
    k_sigma: float | None = None,
    false_alarms_per_hour: float | None = None,
    output: str | Path | None = None,
    force: bool = False,
    **options: Unpack[Options],
) -> ThresholdRun:
    """``twincd threshold``: the threshold of ``calibration`` (one, or its file) from
    collision-free ``logs`` (files, bags, folders of logs; each log once), each streamed: by
    default a false-alarm budget for the models scored by depth, μ + 4σ for the others;
    ``k_sigma`` keeps μ + kσ, ``false_alarms_per_hour`` sets the budget
    (``twincd.calibration.threshold.threshold_from_parts``). Then, in a second pass, the false
    alarms the threshold gives on these logs are counted (``detect``'s events, as ``evaluate``
    counts them) and a threshold that flags most of them is refused.

    ``options`` as ``fit_calibration``'s; how the logs are read is the calibration's by
    default, and may be given (``twincd.SetupOptions``). ``output``: where to write the
    calibration (None: nowhere; its recorded reading options are kept as they were)."""
    from twincd.calibration import Calibration
    from twincd.calibration.threshold import LogScores, check_threshold_choice, score_log
    from twincd.detection.files import threshold_logs
    from twincd.executors.local import Bound, gathered_warnings
    from twincd.executors.run import LogFailure
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs

    with gathered_warnings() as warnings:
        running, asked = split_options(options)
        check_threshold_choice(k_sigma, false_alarms_per_hour)
        cal = Calibration.given(calibration)
        target = as_path(output)
        paths = expand_logs(logs)
        if target is not None:
            check_target(target, "calibration", force=force, inputs=paths)
        setup = asked.resolve(cal).for_logs(paths)
        scoring: Bound[Path, LogScores] = Bound(score_log, cal, setup)
        done = running.each(scoring, paths, "scoring")
        counted: list[LogFailure] = []
        # the threshold, and the false alarms it gives on these logs: detect's events, counted
        # as evaluate counts them (a second pass: the events need the threshold)
        each = running.mapper(counted)
        cal = threshold_logs(done.results, cal, setup, each, k_sigma, false_alarms_per_hour)
        if target is not None:
            cal.save(target)
            log.info("wrote %s", target)
    # a log that failed in either pass is the run's failure (exit 2, --json's errors)
    failures = (*done.failures, *counted)
    return ThresholdRun(
        calibration=cal, written=target, warnings=tuple(warnings), failures=failures
    )
