"""Detection on a log file, streamed block by block: the zero-phase chain with lookahead, or,
for a causal calibration, the log's blocks pushed into an ``OnlineDetector`` — so batch and live
detection are one code path. Only counts and events are kept; per-sample results go to sinks."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.detect import DetectionSummary, ScoringStage
from twincd.detection.events import Event
from twincd.detection.online import OnlineDetector
from twincd.errors import DataError
from twincd.frames import Frame, FrameSink
from twincd.pipeline import require_enough_samples, warn_velocity_from_position
from twincd.signal.checks import SignalChecks

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.pipeline import Setup


def detect_file(
    path: str | Path,
    calibration: Calibration,
    setup: Setup,
    sinks: Sequence[FrameSink] = (),
) -> DetectionSummary:
    """Detect collisions in one log streamed block by block; every frame of results also goes
    to ``sinks``. A causal calibration runs through ``OnlineDetector``, so batch and live
    detection are one code path; a zero-phase one through the same stages with lookahead."""
    summary = DetectionSummary(str(path), calibration.require_threshold().value)
    if calibration.lowpass.causal:
        return detect_file_online(path, calibration, setup, summary, sinks)
    # the stream's columns follow the calibration's joints (Setup.from_calibration)
    stage = ScoringStage(calibration)
    with setup.open(path) as stream:
        for frame in stream:
            stage.regressor_mask = stream.regressor_mask
            out, closed = stage.push(frame)
            _deliver(summary, sinks, out, closed)
        _deliver(summary, sinks, Frame(), stage.finish())
        summary.joint_names = stream.joint_names
    stage.counts.warn(str(path))
    return summary


def detect_file_online(
    path: str | Path,
    calibration: Calibration,
    setup: Setup,
    summary: DetectionSummary,
    sinks: Sequence[FrameSink] = (),
) -> DetectionSummary:
    """``detect`` with a causal calibration: the log's blocks pushed into an OnlineDetector."""
    from twincd.io.stream import iter_blocks

    with iter_blocks(
        path,
        setup.options,
        joints=calibration.joint_names,
        block_size=setup.block_size_for(calibration.regressor),
        strict=setup.strict,
    ) as blocks:
        detector: OnlineDetector | None = None
        checks = SignalChecks(calibration.joint_names, {})
        for block in blocks:
            first = detector is None
            if detector is None:
                if block.effort is None:
                    raise DataError(
                        "the log has no measured effort",
                        f"{path}, {blocks.topic}",
                        "record JointState.effort; twincd compares it with the twin",
                    )
                has_sim = block.sim_effort is not None and bool(np.isfinite(block.sim_effort).all())
                detector = OnlineDetector(
                    calibration,
                    period_s=setup.period_s,
                    sim_effort=has_sim,
                    threads=setup.twin_threads or 1,
                    allow_urdf_change=setup.allow_urdf_change,
                    source=str(path),
                )
                limits = detector.robot.position_limits if detector.robot is not None else {}
                checks = SignalChecks(calibration.joint_names, limits)
            checks.push(block.position, block.effort)
            result = detector.push(
                block.stamp_ns,
                block.position,
                block.velocity,
                block.effort,
                block.sim_effort if detector.use_sim else None,
            )
            frame = detector.last_frame.with_columns(
                log_time_ns=block.log_time_ns[np.isfinite(result.score)]
            )
            _deliver(summary, sinks, frame, result.events)
            if first and detector.velocity_from_position:
                warn_velocity_from_position(str(path), block.velocity, calibration.joint_names)
        if detector is None:
            raise DataError("the log has no joint-state samples", str(path), "record joint states")
        _deliver(summary, sinks, Frame(), detector.close())
        summary.joint_names = calibration.joint_names
        require_enough_samples(summary.samples, str(path))
        checks.warn(str(path))
        detector.counts.warn(str(path))
        if detector.skipped:
            summary.warnings.append(
                f"{path}: skipped {detector.skipped} sample(s) with non-finite values"
            )
    return summary


def _deliver(
    summary: DetectionSummary, sinks: Sequence[FrameSink], frame: Frame, events: list[Event]
) -> None:
    summary.add(frame, events)
    for sink in sinks:
        sink.write(frame, events)
