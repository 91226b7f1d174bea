"""``fit`` over many logs: each log streamed block by block into mergeable statistics."""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from twincd.calibration.affine import AffineCalibration, AffineStats, clean_rows
from twincd.calibration.file import Calibration, calibration_from_fit
from twincd.errors import DataError
from twincd.pipeline import PreparedStream, Setup

log = logging.getLogger("twincd")


@dataclass(frozen=True)
class LogFit:
    """What one log contributes to a fit: small, picklable, mergeable (the per-log step)."""

    source: str
    stats: AffineStats
    joint_names: tuple[str, ...]
    period_s: float
    simulated: bool
    robot: tuple[str, str] | None  # (name, URDF sha256) when a model was used
    seconds: float  # time spent in the regression sums, as the paper times training
    labelled: bool = True  # the log has collision labels (else every sample is taken as clean)


def fit_log(path: str | Path, setup: Setup) -> LogFit:
    """Stream one log through read → twin → filter into affine statistics."""
    stats: AffineStats | None = None
    seconds = 0.0
    labelled = False
    with setup.open(path) as stream:
        for frame in stream:
            labelled |= "labels" in frame
            start = time.perf_counter()
            part = AffineStats.from_arrays(
                frame["sim_effort_f"],
                frame["effort_f"],
                clean_rows(frame.get("labels"), frame.n, frame.get("edge")),
            )
            stats = part if stats is None else stats + part
            seconds += time.perf_counter() - start
        assert stats is not None  # the stream raises on logs without samples
        return LogFit(
            source=stream.source,
            stats=stats,
            joint_names=stream.joint_names,
            period_s=stream.period_s,
            simulated=stream.simulated,
            robot=_robot_of(stream),
            seconds=seconds,
            labelled=labelled,
        )


def _robot_of(stream: PreparedStream) -> tuple[str, str] | None:
    if stream.robot is None:
        return None
    return stream.robot.name, stream.robot.urdf_sha256


def merge_fits(parts: Iterable[LogFit], setup: Setup) -> Calibration:
    """The calibration from per-log statistics, merged in any order (exact merges)."""
    parts = sorted(parts, key=lambda p: p.source)  # any completion order gives one answer
    if not parts:
        raise DataError("no logs to fit", "fit", "give at least one collision-free log")
    names = parts[0].joint_names
    for p in parts[1:]:
        if p.joint_names != names:
            raise DataError(
                "logs with different joints cannot be fitted together",
                f"{p.source}: {', '.join(p.joint_names)} vs {', '.join(names)}",
                "fit logs of one robot, or give a joint map",
            )
    total = parts[0].stats
    for p in parts[1:]:
        total = total + p.stats
    start = time.perf_counter()
    estimator = AffineCalibration(names).fit_stats(total)
    estimator.fit_s_ = sum(p.seconds for p in parts) + time.perf_counter() - start
    _warn_about_fit(estimator, [p.source for p in parts if not p.labelled])
    robots = sorted({p.robot for p in parts if p.robot is not None})
    name, sha = robots[0] if robots else (setup.robot, None)
    return calibration_from_fit(
        estimator,
        setup.lowpass,
        setup.options,
        name,
        sha,
        any(p.simulated for p in parts),
        [p.source for p in parts],
        period_s=statistics.median(p.period_s for p in parts),
    )


# below this on every joint, the twin explains next to none of the measured effort
LOW_R2 = 0.1


def _warn_about_fit(estimator: AffineCalibration, unlabelled: list[str]) -> None:
    """Fits that are likely wrong say so (one line each): a negative gain, a twin that explains
    nothing (a wrong robot model or joint map), logs without labels whose collisions, if any,
    were fitted as if normal."""
    names = estimator.joint_names or ()
    negative = [n for n, a in zip(names, estimator.a_, strict=True) if a < 0]
    if negative:
        log.warning(
            "fit: negative a on %s: the twin's effort runs against the measured one; check the "
            "robot model, the joint map and the effort sign",
            ", ".join(negative),
        )
    r2 = estimator.r2_
    if len(r2) and bool(np.all(np.nan_to_num(r2, nan=0.0) < LOW_R2)):
        log.warning(
            "fit: R² below %g on every joint (best %.3f): the twin explains almost none of the "
            "measured effort; check the robot model and the joint map",
            LOW_R2,
            float(np.nanmax(r2)) if np.isfinite(r2).any() else 0.0,
        )
    if unlabelled:
        log.warning(
            "fit: %d log(s) have no collision labels (%s): every sample was taken as "
            "collision-free; fit on logs known to be free of collisions",
            len(unlabelled),
            unlabelled[0] + (", ..." if len(unlabelled) > 1 else ""),
        )


def fit_calibration(paths: Iterable[str | Path], setup: Setup) -> Calibration:
    """Fit a, b over ``paths`` log by log (memory flat in the number of logs and samples)."""
    return merge_fits([fit_log(path, setup) for path in paths], setup)
