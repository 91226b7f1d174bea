"""Detection on a log file, streamed block by block at flat memory: the log's frames (read,
twinned and filtered by ``twincd.pipeline``, down the chain ``twincd.chain.build_chain`` builds
for the calibration, zero-phase or causal) scored, flagged and grouped into events. Only counts
and events are kept; per-sample results go to sinks."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from twincd.detection.detect import DetectionSummary, ScoringStage
from twincd.detection.events import Event
from twincd.frames import Frame, FrameSink

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
    to ``sinks``. The chain and the scoring are those of ``OnlineDetector``: with a causal
    calibration, a log pushed live in any chunking gives the same scores, flags and events."""
    summary = DetectionSummary(str(path), calibration.require_threshold().value)
    # the stream's columns follow the calibration's joints (Setup.from_calibration)
    stage = ScoringStage(calibration)
    with setup.open(path, model=stage.model) as stream:
        for frame in stream:
            stage.regressor_mask = stream.regressor_mask
            out, closed = stage.push(frame)
            _deliver(summary, sinks, out, closed)
        _deliver(summary, sinks, Frame(), stage.finish())
        summary.joint_names = stream.joint_names
    stage.counts.warn(str(path))
    return summary


def _deliver(
    summary: DetectionSummary, sinks: Sequence[FrameSink], frame: Frame, events: list[Event]
) -> None:
    summary.add(frame, events)
    for sink in sinks:
        sink.write(frame, events)
