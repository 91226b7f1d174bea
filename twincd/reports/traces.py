"""What the figures draw, collected while a log streams, at bounded memory whatever its length:
the measured effort, what the calibration's model predicts of it and the score as min/max
envelopes (``Envelope``), and
for ``fit`` an evenly thinned sample of (twin, measured) pairs. Both are small and picklable,
so they come back from worker processes with the log's summary."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from twincd.reports.envelope import Envelope
from twincd.types import FloatArray

if TYPE_CHECKING:
    from pathlib import Path

    from twincd.calibration.fitting import LogFit
    from twincd.detection.events import Event
    from twincd.prepare.frames import Frame
    from twincd.prepare.setup import Setup
    from twincd.signal.features import ModelFeatures


# one column per pixel of a 1000-pixel-wide figure; min and max keep every spike
DEFAULT_COLUMNS = 1000
DEFAULT_POINTS = 2000


class DetectionTrace:
    """A ``FrameSink`` keeping, per column of the figure, the min and max of each joint's
    measured effort τ̃, the twin as the calibration's model predicts it (the frames'
    ``predicted``, ``ResidualModel.predict``), the score and the labels (when present)."""

    def __init__(
        self, joint_names: Sequence[str], threshold: float, columns: int = DEFAULT_COLUMNS
    ) -> None:
        self.joint_names = tuple(joint_names)
        self.threshold = float(threshold)
        d = len(self.joint_names)
        # channels: measured (d), twin (d), score, label
        self.envelope = Envelope(2 * d + 2, columns)
        self.first_ns: int | None = None
        self.has_labels = False

    def write(self, frame: Frame, events: list[Event]) -> None:
        if not frame.n:
            return
        stamps = np.asarray(frame["stamp_ns"], dtype=np.int64)
        if self.first_ns is None:
            self.first_ns = int(stamps[0])
        labels = frame.get("labels")
        if labels is not None:
            self.has_labels = True
        label = np.full(frame.n, np.nan) if labels is None else np.asarray(labels, dtype=np.float64)
        values = np.column_stack([frame["effort_f"], frame["predicted"], frame["score"], label])
        self.envelope.push(stamps, values)

    def seconds(self) -> FloatArray:
        """Each column's start, in seconds from the first sample."""
        seconds = (self.envelope.t - (self.first_ns or 0)).astype(np.float64) * 1e-9
        return seconds

    def line(self, channel: int) -> tuple[FloatArray, FloatArray]:
        x, y = self.envelope.line(channel)
        return (x - (self.first_ns or 0)) * 1e-9, y

    def measured(self, joint: int) -> tuple[FloatArray, FloatArray]:
        return self.line(joint)

    def twin(self, joint: int) -> tuple[FloatArray, FloatArray]:
        return self.line(len(self.joint_names) + joint)

    def score(self) -> tuple[FloatArray, FloatArray]:
        return self.line(2 * len(self.joint_names))

    def label_spans(self) -> list[tuple[float, float]]:
        """(start, end) seconds of the columns holding a labelled sample."""
        if not self.has_labels:
            return []
        high = self.envelope.high[:, -1]
        flagged = np.nan_to_num(high, nan=0.0) > 0.5
        t = self.seconds()
        if not len(t):
            return []
        step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        ends = np.append(t[1:], t[-1] + step)
        from twincd.detection.events import runs

        return [(float(t[i]), float(ends[j])) for i, j in runs(flagged)]


class ThinnedPairs:
    """Every ``step``-th clean sample of (twin τ̂̃, measured τ̃) per joint, never more than
    ``2·points`` kept: when full, every other one is dropped and the step doubles."""

    def __init__(self, joints: int = 0, points: int = DEFAULT_POINTS) -> None:
        self.points = points
        self.step = 1
        self.seen = 0
        self.twin = np.zeros((0, joints))
        self.measured = np.zeros((0, joints))

    def write(self, frame: Frame, events: list[Event]) -> None:
        if not frame.n:
            return
        from twincd.calibration.affine import fit_rows

        clean = fit_rows(frame.get("labels"), frame.n, frame.get("edge_factor"))  # fit's
        twin = np.asarray(frame["sim_effort_f"])[clean]
        measured = np.asarray(frame["effort_f"])[clean]
        if not self.seen:
            self.twin = self.measured = np.zeros((0, twin.shape[1]))
        index = self.seen + np.arange(len(twin))
        keep = index % self.step == 0
        self.seen += len(twin)
        self.twin = np.concatenate([self.twin, twin[keep]])
        self.measured = np.concatenate([self.measured, measured[keep]])
        while len(self.twin) > 2 * self.points:
            self.twin, self.measured = self.twin[::2], self.measured[::2]
            self.step *= 2

    @classmethod
    def merge(cls, parts: Sequence[ThinnedPairs]) -> ThinnedPairs:
        """The pairs of several logs together, thinned to one bound."""
        out = cls(points=max((p.points for p in parts), default=DEFAULT_POINTS))
        kept = [p for p in parts if p.seen]
        if kept:
            out.twin = np.concatenate([p.twin for p in kept])
            out.measured = np.concatenate([p.measured for p in kept])
            out.seen = sum(p.seen for p in kept)
            step = max(1, -(-len(out.twin) // (2 * out.points)))
            out.twin, out.measured = out.twin[::step], out.measured[::step]
        return out


def fit_log_with_pairs(
    path: str | Path,
    setup: Setup,
    features: ModelFeatures | None = None,
    time_folds: bool = False,
) -> tuple[LogFit, ThinnedPairs]:
    """``fit``'s per-log step, also keeping the thinned pairs a report's figure draws."""
    from twincd.calibration.fitting import fit_log

    pairs = ThinnedPairs()
    return fit_log(path, setup, [pairs], features, time_folds), pairs
