"""Detection on one log: score, flag where score ≥ μ + kσ, events."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twincd.calibration import Calibration
from twincd.detection.events import Event, find_events
from twincd.detection.score import residual
from twincd.pipeline import PreparedLog

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class LogDetection:
    """Per-sample scores, flags and residuals of one log, and its events."""

    log: PreparedLog
    residual: FloatArray
    scores: FloatArray
    flags: BoolArray
    threshold: float
    events: list[Event]

    @property
    def source(self) -> str:
        return self.log.source

    def to_dict(self) -> dict[str, object]:
        return {
            "path": self.source,
            "samples": len(self.scores),
            "collision_samples": int(self.flags.sum()),
            "events": [e.to_dict() for e in self.events],
        }


def detect(log: PreparedLog, calibration: Calibration) -> LogDetection:
    """Score and flag every sample of ``log`` with a calibration that has a threshold."""
    threshold = calibration.require_threshold().value
    r = residual(log.effort_f, log.sim_effort_f, calibration.a, calibration.b)
    scores: FloatArray = np.einsum("ij,ij->i", r, r)
    flags = scores >= threshold
    events = find_events(flags, scores, r, log.states.stamp_ns, log.joint_names)
    return LogDetection(log, r, scores, flags, threshold, events)
