"""The one place where ``watch`` uses ``OnlineDetector``.

Results are matched to samples by stamp: a detector that holds samples back (a coarse time grid
at high rates) returns them later with their ``stamp_ns``, and ``flush`` gives what it still
holds at the end of a segment. A detector whose results carry no stamps returns one row per
pushed sample, at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from twincd.detection.events import Event
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection.online import OnlineDetector


@dataclass
class Scored:
    """Scored samples (by stamp) and the events that closed."""

    stamp_ns: IntArray
    score: FloatArray
    flag: BoolArray
    residual: FloatArray
    events: list[Event] = field(default_factory=list)

    @staticmethod
    def empty(joints: int) -> Scored:
        return Scored(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool), np.zeros((0, joints)))


class LiveDetector:
    """A restartable ``OnlineDetector``: one per segment of the stream."""

    def __init__(self, calibration: Calibration, source: str) -> None:
        self.calibration = calibration
        self.source = source
        self._detector = self._new()
        self.joint_names: list[str] = list(self._detector.joint_names)
        self.use_sim: bool = bool(self._detector.use_sim)
        self.samples = 0
        self.skipped = 0
        self.flagged = 0
        self._judged_before = 0  # judged samples of the segments that ended

    def _new(self) -> OnlineDetector:
        from twincd.detection.online import OnlineDetector

        return OnlineDetector(self.calibration, source=self.source)

    @property
    def judged(self) -> int:
        """Samples judged (past each segment's start-up span) over every segment."""
        return self._judged_before + int(self._detector.counts.judged)

    @property
    def latency_s(self) -> float:
        """The causal filter's group delay (how late a step shows in the score)."""
        return float(self._detector.latency_s)

    def push(
        self,
        stamp_ns: IntArray,
        position: FloatArray,
        velocity: FloatArray,
        effort: FloatArray,
        sim_effort: FloatArray | None,
    ) -> Scored:
        det = self._detector
        if self.use_sim and sim_effort is not None and not np.isfinite(sim_effort).any():
            # none has its twin effort: all would be skipped (and an empty push with a twin
            # effort trips the chain), so skip them here
            self.skipped += len(stamp_ns)
            joints = len(self.joint_names)
            n = len(stamp_ns)
            return Scored(
                np.asarray(stamp_ns, np.int64),
                np.full(n, np.nan),
                np.zeros(n, bool),
                np.full((n, joints), np.nan),
            )
        before = det.skipped
        out = det.push(stamp_ns, position, velocity, effort, sim_effort if self.use_sim else None)
        self.skipped += det.skipped - before
        stamps = np.asarray(getattr(out, "stamp_ns", stamp_ns), dtype=np.int64)
        scored = Scored(stamps, out.score, out.flag, out.residual, list(out.events))
        self.samples += len(stamps) - (det.skipped - before)
        self.flagged += int(np.count_nonzero(out.flag))
        return scored

    def finish(self) -> Scored:
        """End of a segment: what the detector still holds, and the event still open."""
        det = self._detector
        scored = Scored.empty(len(self.joint_names))
        flush = getattr(det, "flush", None)
        if flush is not None:
            out = flush()
            stamps = np.asarray(getattr(out, "stamp_ns", np.zeros(0, np.int64)), dtype=np.int64)
            scored = Scored(stamps, out.score, out.flag, out.residual, list(out.events))
            self.samples += len(stamps)
            self.flagged += int(np.count_nonzero(out.flag))
        scored.events += det.close()
        return scored

    def restart(self) -> Scored:
        """A new segment: finish this one, and start afresh (filter and events)."""
        done = self.finish()
        self._judged_before += int(self._detector.counts.judged)
        self._detector = self._new()
        return done
