"""Live joint-state samples: decoded, matched by name, reordered within a bounded window, and
cut into segments where the source's clock jumps back.

- Time is ``header.stamp``, the message's log time where the stamp is 0 (as for a log).
- Joints are matched by name to the calibration's (after the joint map or prefix); a message's
  other joints are ignored; a message that lacks a calibrated joint is not usable (counted).
- Reordering: a sample is held until the newest stamp is ``window_ns`` past it (default 20 ms,
  ``REORDER_WINDOW_NS``), or it arrived ``window_ns`` ago (the source paused or ended: no newer
  sample comes), or ``max_rows`` samples are held (1000); then samples leave in stamp order.
  A sample whose twin effort comes on its own topic (a calibration that uses the log's) also
  waits for it, up to ``JOIN_WAIT_NS`` (100 ms) more. A sample older than one
  already released is late: dropped and counted; an exact duplicate stamp is dropped (the
  first kept), as a log reader does.
- A clock that jumps back (a restarted source, a replay that loops): a stamp that falls behind
  the source's log time by ``CLOCK_JUMP_NS`` (5 s) more than before, and is not after the newest
  stamp, starts a new segment, judged from scratch, instead of being dropped as late.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from twincd.io.cdr import decode_joint_states
from twincd.io.stream.parts import CLOCK_JUMP_NS
from twincd.types import FloatArray

__all__ = ["REORDER_MAX", "REORDER_WINDOW_NS", "JointDecoder", "Reorder", "Sample", "Segments"]

REORDER_WINDOW_NS = 20_000_000
REORDER_MAX = 1000
JOIN_WAIT_NS = 100_000_000


@dataclass(frozen=True)
class Sample:
    """One joint-state sample in the calibration's joint order."""

    stamp_ns: int
    log_time_ns: int
    received_ns: int
    position: FloatArray
    velocity: FloatArray  # NaN where the message has none
    effort: FloatArray


@dataclass
class DecodeCounts:
    messages: int = 0
    usable: int = 0
    other_joints: int = 0  # messages that carry none of the calibrated joints
    partial: int = 0  # messages that carry some, not all
    ragged: int = 0  # filled arrays of another length than ``name``
    undecodable: int = 0


@dataclass
class JointDecoder:
    """CDR JointState payloads → samples in ``joints`` order (``rename``: a log joint's name
    as the calibration knows it, ``twincd.io.options.LogOptions.rename``)."""

    joints: Sequence[str]
    rename: Callable[[str], str] | None = None
    counts: DecodeCounts = field(default_factory=DecodeCounts)

    def decode(self, data: bytes, log_time_ns: int, received_ns: int) -> Sample | None:
        self.counts.messages += 1
        try:
            groups = decode_joint_states(np.frombuffer(data, dtype=np.uint8)[None, :])
        except Exception:  # a payload that is no JointState at all
            self.counts.undecodable += 1
            return None
        if not groups:
            self.counts.undecodable += 1
            return None
        g = groups[0]
        names = list(g.names) if self.rename is None else [self.rename(n) for n in g.names]
        where = {n: i for i, n in reversed(list(enumerate(names)))}  # first of a doubled name
        idx = [where.get(j, -1) for j in self.joints]
        if all(i < 0 for i in idx):
            self.counts.other_joints += 1
            return None
        if any(i < 0 for i in idx):
            self.counts.partial += 1
            return None
        k = len(names)
        pos, vel, eff = g.position[0], g.velocity[0], g.effort[0]
        if len(pos) != k or len(eff) != k or len(vel) not in (0, k):
            self.counts.ragged += 1
            return None
        cols = np.asarray(idx)
        stamp = int(g.stamp_ns[0]) or int(log_time_ns)
        velocity = vel[cols] if len(vel) else np.full(len(cols), np.nan)
        self.counts.usable += 1
        return Sample(stamp, int(log_time_ns), int(received_ns), pos[cols], velocity, eff[cols])


class Reorder:
    """Samples held by stamp and released in order (see the module's docstring)."""

    def __init__(self, window_ns: int = REORDER_WINDOW_NS, max_rows: int = REORDER_MAX) -> None:
        self.window_ns = int(window_ns)
        self.max_rows = int(max_rows)
        self._heap: list[tuple[int, int, Sample]] = []
        self._held: set[int] = set()
        self._seq = 0
        self.released: int | None = None  # the last stamp released
        self.newest: int | None = None
        self.late = 0
        self.duplicates = 0

    def __len__(self) -> int:
        return len(self._heap)

    def add(self, sample: Sample) -> None:
        stamp = sample.stamp_ns
        if self.released is not None and stamp <= self.released:
            if stamp == self.released:
                self.duplicates += 1
            else:
                self.late += 1
            return
        if stamp in self._held:
            self.duplicates += 1
            return
        self._seq += 1
        heapq.heappush(self._heap, (stamp, self._seq, sample))
        self._held.add(stamp)
        self.newest = stamp if self.newest is None else max(self.newest, stamp)

    def ready(
        self, complete: Callable[[int], bool] | None = None, now_ns: int | None = None
    ) -> list[Sample]:
        """The samples that may leave now, in stamp order. ``complete(stamp)``: whether what
        joins the sample (the twin's effort of a log that carries it) has come; a sample waits
        for it up to ``JOIN_WAIT_NS`` past the window. ``now_ns`` (the clock of the samples'
        ``received_ns``): a sample that arrived the window (and the wait) ago leaves too."""
        out: list[Sample] = []
        if self.newest is None:
            return out
        limit = self.newest - self.window_ns
        while self._heap:
            stamp, _, sample = self._heap[0]
            held = -1 if now_ns is None else now_ns - sample.received_ns - self.window_ns
            due = (stamp <= limit or held >= 0) and (
                complete is None
                or complete(stamp)
                or stamp <= limit - JOIN_WAIT_NS
                or held >= JOIN_WAIT_NS
            )
            if not (due or len(self._heap) > self.max_rows):
                break
            out.append(self._pop())
        return out

    def drain(self) -> list[Sample]:
        """Every held sample, in stamp order (the end of a segment or of the session)."""
        out = [self._pop() for _ in range(len(self._heap))]
        return out

    def _pop(self) -> Sample:
        stamp, _, sample = heapq.heappop(self._heap)
        self._held.discard(stamp)
        self.released = stamp
        return sample

    def reset(self) -> None:
        self._heap.clear()
        self._held.clear()
        self.released = self.newest = None


class Segments:
    """Backward jumps of the source's clock (see ``CLOCK_JUMP_NS``): ``jumped(sample)`` is
    True for the first sample of a new segment."""

    def __init__(self) -> None:
        self.offset: int | None = None  # the largest stamp − log time so far in this segment
        self.newest: int | None = None
        self.count = 1

    def jumped(self, sample: Sample) -> bool:
        offset = sample.stamp_ns - sample.log_time_ns
        jump = (
            self.offset is not None
            and self.newest is not None
            and offset < self.offset - CLOCK_JUMP_NS
            and sample.stamp_ns <= self.newest
        )
        if jump:
            self.count += 1
            self.offset, self.newest = offset, sample.stamp_ns
            return True
        self.offset = offset if self.offset is None else max(self.offset, offset)
        self.newest = sample.stamp_ns if self.newest is None else max(self.newest, sample.stamp_ns)
        return False
