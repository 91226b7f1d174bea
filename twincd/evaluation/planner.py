"""How ``evaluate`` runs each method and handles its logs: the strategy a method takes
(``plan``), the sets of logs in one order whatever order they come in (``by_source``,
``sorted_paths``), the checks every strategy makes of the logs and scores (``require_labels``,
``require_scores``), the warning on logs shared between sets (``warn_on_overlap``) and the
signature of the progress they are given (the per-log mapper's is ``twincd.executors.run.Each``)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from twincd.errors import DataError
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, make_method
from twincd.prepare.prepared import PreparedLog

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.calibration.threshold import LogScores
    from twincd.evaluation.streamed import JudgedLog

T = TypeVar("T")
Progress = Callable[[Sequence[Any], str], Iterable[Any]]

log = logging.getLogger("twincd")


def plan(
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


def by_source(logs: Iterable[T]) -> list[T]:
    """Logs in one order whatever order they were given or prepared in: methods that learn
    (and sums over logs) then see the same sequence on every run."""
    return sorted(logs, key=_source)  # type: ignore[arg-type]


def sorted_paths(paths: Sequence[Path]) -> list[Path]:
    """Paths in the order of their logs' sources (``str(Path(p))``)."""
    return sorted((Path(p) for p in paths), key=str)


def require_labels(logs: Sequence[PreparedLog | JudgedLog], option: str) -> None:
    """A log without collision labels is an error (``option``: the set it was given in)."""
    for lg in logs:
        if (lg.labels is None) if isinstance(lg, PreparedLog) else not lg.labelled:
            raise DataError(
                "the log has no collision labels",
                f"{lg.source}, {option}",
                "evaluate needs ground truth: record std_msgs/Bool collision labels on the "
                "label topic",
                option="label_topic",
            )


def require_scores(source: str, name: str, scores: int, units: int, finite: bool) -> None:
    """A method giving other than one finite score per unit is a defect of the method."""
    if scores != units or not finite:
        raise DataError(
            f"method {name!r} gave {scores} scores for {units} units, or non-finite ones",
            source,
            "report this as a bug in the method",
        )


def warn_on_overlap(
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
