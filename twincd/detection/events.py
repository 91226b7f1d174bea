"""Collision events: contiguous runs of flagged samples, for people to read."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Event:
    """One contiguous run of flagged samples (indices inclusive)."""

    first: int
    last: int
    start_ns: int
    end_ns: int
    peak_score: float
    peak_ns: int
    joint: str

    @property
    def samples(self) -> int:
        return self.last - self.first + 1

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9  # integer ns first: no float noise

    def to_dict(self) -> dict[str, object]:
        return {
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "duration_s": self.duration_s,
            "samples": self.samples,
            "peak_score": self.peak_score,
            "peak_ns": self.peak_ns,
            "joint": self.joint,
        }


def runs(flags: BoolArray) -> list[tuple[int, int]]:
    """(first, last) index pairs, inclusive, of every run of True."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate(([0], f, [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def find_events(
    flags: BoolArray,
    scores: FloatArray,
    residual_: FloatArray,
    stamp_ns: IntArray,
    joint_names: Sequence[str],
) -> list[Event]:
    """Events from a flag vector; the joint is the one with the largest share of Σ residual²."""
    events = []
    for first, last in runs(flags):
        seg = slice(first, last + 1)
        peak = first + int(np.argmax(scores[seg]))
        share = (residual_[seg] ** 2).sum(axis=0)
        events.append(
            Event(
                first=first,
                last=last,
                start_ns=int(stamp_ns[first]),
                end_ns=int(stamp_ns[last]),
                peak_score=float(scores[peak]),
                peak_ns=int(stamp_ns[peak]),
                joint=joint_names[int(np.argmax(share))],
            )
        )
    return events
