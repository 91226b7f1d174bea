"""Collision events: contiguous runs of flagged samples, for people to read."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

if TYPE_CHECKING:
    from twincd.detection.isolation import LinkIsolator


@dataclass(frozen=True)
class Event:
    """One contiguous run of flagged samples (indices inclusive)."""

    first: int
    last: int
    start_ns: int
    end_ns: int
    peak_score: float
    peak_ns: int
    joint: str  # the joint with the largest share of the event's Σ residual²
    link: str | None = None  # the link most likely touched, when it can be told

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
            "link": self.link,
        }


def runs(flags: BoolArray) -> list[tuple[int, int]]:
    """(first, last) index pairs, inclusive, of every run of True."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate(([0], f, [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


class EventTracker:
    """Events from flags that arrive block by block: an event still flagged at the end of a
    block stays open and continues into the next, so block boundaries never split one.

    State is one open event (a few numbers, a per-joint sum and maximum), whatever the log
    length.
    """

    def __init__(self, joint_names: Sequence[str], isolator: LinkIsolator | None = None) -> None:
        self.joint_names = tuple(joint_names)
        self.isolator = isolator
        self._offset = 0  # global index of the next sample
        self._open: dict[str, Any] | None = None

    def push(
        self, flags: BoolArray, scores: FloatArray, residual_: FloatArray, stamp_ns: IntArray
    ) -> list[Event]:
        """The events that closed within this block (an event ending at its last sample closes
        only when the next sample arrives unflagged, or at ``finish``)."""
        n = len(flags)
        closed: list[Event] = []
        if n and self._open is not None and not flags[0]:
            closed.append(self._close())
        for first, last in runs(flags):
            seg = slice(first, last + 1)
            peak = first + int(np.argmax(scores[seg]))
            part = {
                "first": self._offset + first,
                "last": self._offset + last,
                "start_ns": int(stamp_ns[first]),
                "end_ns": int(stamp_ns[last]),
                "peak_score": float(scores[peak]),
                "peak_ns": int(stamp_ns[peak]),
                "share": (residual_[seg] ** 2).sum(axis=0),
                "absmax": np.abs(residual_[seg]).max(axis=0),
            }
            if first == 0 and self._open is not None:  # the open event goes on
                self._extend(part)
            else:
                self._open = part
            if last < n - 1:
                closed.append(self._close())
        self._offset += n
        return closed

    def finish(self) -> list[Event]:
        """Close the event still open at the end of the log, if any."""
        return [self._close()] if self._open is not None else []

    def _extend(self, part: dict[str, Any]) -> None:
        assert self._open is not None
        ev = self._open
        ev["last"], ev["end_ns"] = part["last"], part["end_ns"]
        ev["share"] = ev["share"] + part["share"]
        ev["absmax"] = np.maximum(ev["absmax"], part["absmax"])
        if part["peak_score"] > ev["peak_score"]:  # the first peak wins ties, as argmax does
            ev["peak_score"], ev["peak_ns"] = part["peak_score"], part["peak_ns"]

    def _close(self) -> Event:
        assert self._open is not None
        ev, self._open = self._open, None
        link = None if self.isolator is None else self.isolator.link(ev["absmax"])
        return Event(
            first=ev["first"],
            last=ev["last"],
            start_ns=ev["start_ns"],
            end_ns=ev["end_ns"],
            peak_score=ev["peak_score"],
            peak_ns=ev["peak_ns"],
            joint=self.joint_names[int(np.argmax(ev["share"]))],
            link=link,
        )


def find_events(
    flags: BoolArray,
    scores: FloatArray,
    residual_: FloatArray,
    stamp_ns: IntArray,
    joint_names: Sequence[str],
    isolator: LinkIsolator | None = None,
) -> list[Event]:
    """Events of a whole flag vector; the joint is the one with the largest share of Σ residual²."""
    tracker = EventTracker(joint_names, isolator)
    return tracker.push(flags, scores, residual_, stamp_ns) + tracker.finish()
