"""The parts of a sample stream: pending sample rows, labels held onto samples, the twin's effort
joined by stamp, and the detection of backward jumps of the header clock (used by
``twincd.io.stream.samples.LogStream``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from twincd.io.stream.batch import BoolBatch
from twincd.types import BoolArray, FloatArray, IntArray

__all__ = ["CLOCK_JUMP_NS", "Clock", "Labels", "Rows", "Sim", "cat", "concat", "empty_rows"]

CLOCK_JUMP_NS = 5_000_000_000  # stamps this much further behind the log time: the clock jumped back
_T = TypeVar("_T", bound=np.generic)


@dataclass
class Rows:
    """Samples, sorted by (stamp, log time, read order) and free of duplicate stamps."""

    stamp: IntArray
    log_time: IntArray
    seq: IntArray
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray | None

    def __len__(self) -> int:
        return len(self.stamp)

    def select(self, idx: NDArray[np.intp] | slice) -> Rows:
        eff = None if self.effort is None else self.effort[idx]
        return Rows(
            self.stamp[idx],
            self.log_time[idx],
            self.seq[idx],
            self.position[idx],
            self.velocity[idx],
            eff,
        )

    @staticmethod
    def join(a: Rows, b: Rows) -> Rows:
        eff = None if a.effort is None or b.effort is None else np.concatenate([a.effort, b.effort])
        return Rows(
            np.concatenate([a.stamp, b.stamp]),
            np.concatenate([a.log_time, b.log_time]),
            np.concatenate([a.seq, b.seq]),
            np.concatenate([a.position, b.position]),
            np.concatenate([a.velocity, b.velocity]),
            eff,
        )

    def sorted_unique(self) -> tuple[Rows, int]:
        """These rows sorted, exact duplicate stamps dropped (first kept); (rows, dropped)."""
        if len(self.stamp) < 2 or bool((self.stamp[1:] > self.stamp[:-1]).all()):
            return self, 0  # already in order: the usual case
        order = np.lexsort((self.seq, self.log_time, self.stamp))
        stamp = self.stamp[order]
        keep = np.ones(len(order), dtype=bool)
        keep[1:] = stamp[1:] != stamp[:-1]
        return self.select(order[keep]), int((~keep).sum())


def empty_rows(width: int, effort: bool) -> Rows:
    none = np.zeros(0, np.int64)
    return Rows(
        none,
        none,
        none,
        np.zeros((0, width)),
        np.zeros((0, width)),
        np.zeros((0, width)) if effort else None,
    )


class Labels:
    """Label messages as (log time, value), kept to the transitions once final."""

    def __init__(self) -> None:
        self.t = np.zeros(0, np.int64)
        self.v = np.zeros(0, bool)

    def add(self, batch: BoolBatch) -> None:
        t = np.concatenate([self.t, batch.log_time_ns])
        v = np.concatenate([self.v, batch.value])
        order = np.argsort(t, kind="stable")  # equal times: the later read wins the hold
        self.t, self.v = t[order], v[order]

    def hold(self, times: IntArray) -> BoolArray:
        """Each time takes the value of the latest message at or before it (False before any)."""
        idx = np.searchsorted(self.t, times, side="right") - 1
        held = np.zeros(len(times), dtype=bool)
        ok = idx >= 0
        held[ok] = self.v[idx[ok]]
        return held

    def settle(self, mark: int, needed_from: int) -> None:
        """Keep only transitions among messages before ``mark`` (no more can come there), and
        drop those that no sample at or after ``needed_from`` can see."""
        final = int(np.searchsorted(self.t, mark, side="left"))
        keep = np.ones(len(self.t), dtype=bool)
        if final > 1:  # v[: final - 1] would wrap around at final = 0
            keep[1:final] = self.v[1:final] != self.v[: final - 1]
        self.t, self.v = self.t[keep], self.v[keep]
        first = int(np.searchsorted(self.t, needed_from, side="right")) - 1
        if first > 0:
            self.t, self.v = self.t[first:], self.v[first:]


class Sim:
    """The twin's effort by stamp, waiting for the samples it belongs to."""

    def __init__(self, width: int) -> None:
        self.stamp = np.zeros(0, np.int64)
        self.effort = np.zeros((0, width))

    def add(self, stamp: IntArray, effort: FloatArray) -> None:
        stamp = np.concatenate([self.stamp, stamp])
        effort = np.concatenate([self.effort, effort])
        order = np.argsort(stamp, kind="stable")
        stamp, effort = stamp[order], effort[order]
        same = np.flatnonzero(stamp[1:] == stamp[:-1]) + 1
        for i in same.tolist():  # rare: a later message on the same stamp fills in or wins
            effort[i] = np.where(np.isnan(effort[i]), effort[i - 1], effort[i])
        last = np.ones(len(stamp), dtype=bool)
        last[:-1] = stamp[1:] != stamp[:-1]
        self.stamp, self.effort = stamp[last], effort[last]

    def take(self, stamps: IntArray) -> FloatArray:
        out = np.full((len(stamps), self.effort.shape[1]), np.nan)
        if len(self.stamp):
            idx = np.minimum(np.searchsorted(self.stamp, stamps), len(self.stamp) - 1)
            ok = self.stamp[idx] == stamps
            out[ok] = self.effort[idx[ok]]
        return out

    def drop_through(self, stamp: int) -> None:
        first = int(np.searchsorted(self.stamp, stamp, side="right"))
        self.stamp, self.effort = self.stamp[first:], self.effort[first:]


class Clock:
    """Backward jumps of a stream's header clock (see ``CLOCK_JUMP_NS``).

    A jump shows as the stamp falling behind the log time (the recorder's clock) by
    ``CLOCK_JUMP_NS`` more than it did before; reordering and jitter leave that offset alone.
    Samples after a jump are behind while their stamps have not passed the latest stamp read
    before it."""

    def __init__(self) -> None:
        low = np.iinfo(np.int64).min + CLOCK_JUMP_NS
        self.offset = low  # the largest stamp − log time read so far
        self.latest = low  # the latest stamp read so far
        self.was_behind = False  # the last sample read was behind a jump
        self.jumps = 0
        self.largest_ns = 0

    def behind(self, stamp: IntArray, log_time: IntArray) -> BoolArray:
        """Per sample: behind a backward jump of the clock."""
        if not len(stamp):
            return np.zeros(0, dtype=bool)
        offset = stamp - log_time
        prior_offset = np.maximum.accumulate(np.concatenate(([self.offset], offset[:-1])))
        prior_stamp = np.maximum.accumulate(np.concatenate(([self.latest], stamp[:-1])))
        behind = (offset < prior_offset - CLOCK_JUMP_NS) & (stamp <= prior_stamp)
        starts = behind & ~np.concatenate(([self.was_behind], behind[:-1]))
        if starts.any():
            self.jumps += int(starts.sum())
            gap = prior_offset[starts] - offset[starts]
            self.largest_ns = max(self.largest_ns, int(gap.max()))
        ahead = ~behind
        if ahead.any():
            self.offset = max(self.offset, int(offset[ahead].max()))
        self.latest = max(self.latest, int(stamp.max()))
        self.was_behind = bool(behind[-1])
        return behind


# ---------------------------------------------------------------- the stream


def cat(parts: list[NDArray[_T]]) -> NDArray[_T] | None:
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def concat(parts: list[Rows]) -> Rows:
    effort = [p.effort for p in parts if p.effort is not None]
    return Rows(
        np.concatenate([p.stamp for p in parts]),
        np.concatenate([p.log_time for p in parts]),
        np.concatenate([p.seq for p in parts]),
        np.concatenate([p.position for p in parts]),
        np.concatenate([p.velocity for p in parts]),
        np.concatenate(effort) if len(effort) == len(parts) else None,
    )
