"""Time-ordered sample blocks of one log's joint states, with labels and the twin's effort (the
sample layer of the block stream, on top of ``twincd.io.stream.topics``).

``iter_blocks(path, options)`` streams a log of any length at flat memory: topic batches
(``twincd.io.stream.topics``) go through a reorder buffer that sorts the newest samples by stamp and
emits the older ones in blocks. Rules (contract: Inputs):

- time is ``header.stamp``, unless every stamp of the topic is 0 (decided on the messages read
  ahead): then the log time. A stamp of 0 among others is a time like any other (simulation
  time starts there);
- the stream's joints are the ``known`` ones (a robot model's or a calibration's), else those of
  the log's own twin effort, else those of the message layout (name list) that carries the most
  joints (ties: the most messages); see ``LogStream``. Messages that carry none of them (another
  publisher on the topic, e.g. a gripper node) are ignored and counted; a message's joints
  beyond them are ignored with one warning that names them; a joint named twice in a message
  keeps its first value (counted). An arm whose joints arrive split over several layouts is
  refused (``SplitJointsError``);
- samples missing a stream joint (or with a non-finite position) are dropped first, then exact
  duplicate stamps (the first read — earliest log time — is kept);
- a sample older than one already emitted is *late*: dropped and counted. A log that fits in
  the reorder buffer is therefore sorted exactly like a whole-log sort;
- a header clock that jumps back against the log time by more than ``parts.CLOCK_JUMP_NS`` is not
  reordering: the samples behind the jump are dropped and counted until their stamps pass the
  time reached before it, so two stretches of the recording are never interleaved;
- ragged messages (filled arrays whose length differs from ``name``) are dropped and counted;
- labels (Bool) are held from each message onto the samples' log times; a sample is emitted
  only once every label message at or before its log time has been read;
- the twin's effort is joined by exact stamp (NaN where missing). Its messages are expected no
  later in log time than their samples (``simulate`` writes them at the same log time).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from twincd.errors import LogReadError
from twincd.io.cdr import CdrStats
from twincd.io.stream.batch import DEFAULT_BATCH, END, Batch, BoolBatch, JointStateBatch
from twincd.io.stream.counts import StreamCounts, report_counts
from twincd.io.stream.head import LogHead
from twincd.io.stream.parts import (
    Clock,
    Labels,
    Rows,
    Sim,
    cat,
    concat,
    empty_rows,
)
from twincd.io.stream.topics import TopicReader
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.io.options import LogOptions

__all__ = [
    "DEFAULT_BLOCK",
    "DEFAULT_REORDER",
    "LogStream",
    "SampleBlock",
    "iter_blocks",
]

DEFAULT_BLOCK = 16384
DEFAULT_REORDER = 10_000


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples of one log, in strictly increasing stamp order.

    Columns follow the stream's ``joint_names``. ``velocity`` is NaN where a message had none;
    ``effort`` is None when the log has no effort (decided from its first message), else NaN
    where a message lacked it. ``labels`` and ``sim_effort`` are None when their topic is
    absent.
    """

    stamp_ns: IntArray
    log_time_ns: IntArray
    position: FloatArray
    velocity: FloatArray
    effort: FloatArray | None
    labels: BoolArray | None
    sim_effort: FloatArray | None

    def __len__(self) -> int:
        return len(self.stamp_ns)


class LogStream:
    """One log's joint states as ``SampleBlock``s (a context manager and an iterable).

    Opening reads the first messages (up to the reorder window; ``twincd.io.stream.head``) to
    fix ``joint_names`` (after the joint map): exactly ``joints`` when given (an error when the
    log lacks one, in that order); else the ``known`` joints the log has (a robot model's or a
    calibration's, named by ``known_from``, and those of the log's own twin effort; model
    joints the log lacks are the caller's business); else the joints of the log's own twin
    effort (``sim_topic``); else all the joints of the message layout that carries the most
    joints, ties going to the layout with the most messages. Then the layout with the most of
    those joints fixes the columns; other layouts that carry none are another publisher's
    (ignored, counted in one warning), and one that carries a joint it lacks means
    the arm is split over publishers (refused). Iterate once.
    """

    def __init__(
        self,
        path: str | Path,
        options: LogOptions,
        joints: Sequence[str] | None = None,
        block_size: int = DEFAULT_BLOCK,
        strict: bool = True,
        reorder: int = DEFAULT_REORDER,
        *,
        batch_size: int = DEFAULT_BATCH,
        known: Sequence[str] | None = None,
        known_from: str = "the robot model",
    ) -> None:
        if block_size < 1 or reorder < 0:
            raise ValueError("block_size must be ≥ 1 and reorder ≥ 0")
        self.path = Path(path)
        self.source = str(self.path)
        self.block_size = block_size
        self.reorder = reorder
        self.counts = StreamCounts()
        self._reader = TopicReader(self.path, strict=strict, batch_size=batch_size)
        exact = joints is not None
        try:
            head = LogHead(
                self._reader,
                options,
                joints if exact else known,
                exact,
                "the calibration" if exact else known_from,
                reorder,
            )
        except BaseException:
            self._reader.close()
            raise
        self._open(head)

    def _open(self, head: LogHead) -> None:
        """The topics and joints ``head`` fixed, and the state before the first sample."""
        self.topic, self.label_topic, self.sim_topic = head.topic, head.label_topic, head.sim_topic
        self.has_labels, self.has_sim = head.has_labels, head.has_sim
        self.has_effort, self.no_effort_why = head.has_effort, head.no_effort_why
        self.joint_names = head.joint_names
        self._items, self._head = head.items, head.batches
        self._log_timed, self._sim_log_timed = head.log_timed, head.sim_log_timed
        self._cols = head.columns  # per stream joint, its column in a layout
        self._period_ns = head.period_ns
        self._last_measuring = -np.inf  # the stamp of the last sample emitted that measures
        width = len(self.joint_names)
        self._pending = empty_rows(width, self.has_effort)
        self._labels = Labels() if self.has_labels else None
        self._sim = Sim(width) if self.has_sim else None
        self._seq = 0
        self._clock = Clock()
        self._sim_clock = Clock()
        self._last: int | None = None  # stamp of the last emitted sample
        self._first: int | None = None  # stamp of the first
        self._out: list[Rows] = []
        self._out_n = 0
        self._labels_out: list[BoolArray] = []
        self._sim_out: list[FloatArray] = []
        self._used = False

    # ------------------------------------------------------------ protocol

    def __enter__(self) -> LogStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._reader.close()

    @property
    def stats(self) -> CdrStats:
        """Messages decoded on the fast path and through rosbags."""
        return self._reader.stats

    @property
    def damage(self) -> str | None:
        """With strict=False, what was damaged and how much was read; else None."""
        return self._reader.damage

    def __iter__(self) -> Iterator[SampleBlock]:
        if self._used:
            raise RuntimeError("a LogStream can be iterated once")
        self._used = True
        return self._blocks()

    # ------------------------------------------------------------ work

    def _blocks(self) -> Iterator[SampleBlock]:
        head, self._head = self._head, []
        for topic, batch, mark in head:
            yield from self._take(topic, batch, mark)
        for topic, batch in self._items:
            yield from self._take(topic, batch, self._reader.watermark_ns)
        yield from self._emit(END, final=True)
        if self.counts.samples == 0:
            raise LogReadError(
                "no sample carries every joint",
                f"{self.source}, {self.topic}",
                "pick another topic with the topic option, or check the joint map",
            )
        self._report()

    def _take(self, topic: str, batch: Batch, mark: int) -> Iterator[SampleBlock]:
        if topic == self.topic and isinstance(batch, JointStateBatch):
            self._add_samples(batch)
        if topic == self.label_topic and self._labels is not None and isinstance(batch, BoolBatch):
            self._labels.add(batch)
        if topic == self.sim_topic and self._sim is not None and isinstance(batch, JointStateBatch):
            self._add_sim(batch)
        yield from self._emit(mark, final=False)

    def _note_layout(self, batch: JointStateBatch, cols: NDArray[np.intp]) -> bool:
        """Count what a batch's layout brings that the stream does not use; False when the
        batch carries none of the stream's joints (another publisher's: ignored)."""
        twice = [n for n, c in Counter(batch.names).items() if c > 1]
        if twice:
            self.counts.named_twice += len(batch)
            self.counts.twice_names = tuple(dict.fromkeys((*self.counts.twice_names, *twice)))
        if (cols >= 0).any():
            return True
        self.counts.foreign += len(batch)
        self.counts.foreign_names = tuple(dict.fromkeys((*self.counts.foreign_names, *batch.names)))
        return False

    def _ragged(self, batch: JointStateBatch) -> bool:
        """Filled arrays must match ``name``: a batch (one layout) that does not is dropped."""
        k = len(batch.names)
        kp, kv, ke = batch.position.shape[1], batch.velocity.shape[1], batch.effort.shape[1]
        if kp == k and kv in (0, k) and ke in (0, k):
            return False
        self.counts.ragged += len(batch)
        return True

    def _add_samples(self, batch: JointStateBatch) -> None:
        n = len(batch)
        self.counts.read += n
        if self._ragged(batch):
            return
        cols = self._cols(batch.names)
        if not self._note_layout(batch, cols):
            return
        if (cols < 0).any():
            self.counts.incomplete += n
            return
        same = len(cols) == len(batch.names) and bool((cols == np.arange(len(cols))).all())

        def pick(values: FloatArray) -> FloatArray:
            return values if same else values[:, cols]  # a copy only when columns move

        position = pick(batch.position)
        ok: BoolArray = np.asarray(np.isfinite(position).all(axis=1))
        nan = np.full((n, len(cols)), np.nan)
        velocity = pick(batch.velocity) if batch.velocity.shape[1] else nan
        effort = None
        if self.has_effort:
            effort = pick(batch.effort) if batch.effort.shape[1] else nan
        stamp = batch.log_time_ns if self._log_timed else batch.stamp_ns
        self.counts.unstamped += n if self._log_timed else 0
        seq = np.arange(self._seq, self._seq + n, dtype=np.int64)
        self._seq += n
        rows = Rows(stamp, batch.log_time_ns, seq, position, velocity, effort)
        self.counts.incomplete += int((~ok).sum())
        kept = np.flatnonzero(ok)
        behind = self._clock.behind(stamp[kept], batch.log_time_ns[kept])
        ok[kept[behind]] = False
        self.counts.clock_back += int(behind.sum())
        self.counts.jumps, self.counts.largest_jump_ns = self._clock.jumps, self._clock.largest_ns
        if self._last is not None:
            self.counts.duplicates += int((ok & (stamp == self._last)).sum())
            self.counts.late += int((ok & (stamp < self._last)).sum())
            ok &= stamp > self._last
        if not ok.all():
            rows = rows.select(np.flatnonzero(ok))
        rows, dropped = rows.sorted_unique()
        self.counts.duplicates += dropped
        pending = self._pending
        if len(pending) == 0:
            self._pending = rows
        elif len(rows) and rows.stamp[0] > pending.stamp[-1]:
            self._pending = Rows.join(pending, rows)  # the usual case: no sort needed
        elif len(rows):
            self._pending, dropped = Rows.join(pending, rows).sorted_unique()
            self.counts.duplicates += dropped

    def _add_sim(self, batch: JointStateBatch) -> None:
        assert self._sim is not None
        cols = self._cols(batch.names)
        width = batch.effort.shape[1]
        effort = np.full((len(batch), len(cols)), np.nan)
        have = (cols >= 0) & (cols < width)  # like zip(name, effort): extra names get nothing
        effort[:, have] = batch.effort[:, cols[have]]
        stamp = batch.log_time_ns if self._sim_log_timed else batch.stamp_ns
        # as their samples: never over earlier ones
        ahead = ~self._sim_clock.behind(stamp, batch.log_time_ns)
        stamp, effort = stamp[ahead], effort[ahead]
        if self._last is not None:  # their samples are gone already
            keep = stamp > self._last
            stamp, effort = stamp[keep], effort[keep]
        self._sim.add(stamp, effort)

    def _emit(self, mark: int, final: bool) -> Iterator[SampleBlock]:
        pending = self._pending
        k = len(pending) if final else max(0, len(pending) - self.reorder)
        if not final and k and (self._labels is not None or self._sim is not None):
            # labels and the twin's effort must have been read up to the samples' log time
            waiting = np.flatnonzero(pending.log_time[:k] >= mark)
            if len(waiting):
                k = int(waiting[0])
        other = self._other_publisher(pending, k, final)
        if k:
            done, self._pending = pending.select(slice(0, k)), pending.select(slice(k, None))
            self._last = int(done.stamp[-1])
            self._first = int(done.stamp[0]) if self._first is None else self._first
            if other.any():
                self.counts.other_publisher += int(other.sum())
                done = done.select(np.flatnonzero(~other))
                k = len(done)
            if self._labels is not None:
                self._labels_out.append(self._labels.hold(done.log_time))
            if self._sim is not None:
                self._sim_out.append(self._sim.take(done.stamp))
                self._sim.drop_through(self._last)
            self._out.append(done)
            self._out_n += k
        if self._labels is not None:
            rest = self._pending.log_time
            needed = min(mark, int(rest.min())) if len(rest) else mark
            self._labels.settle(mark, needed)
        while self._out_n >= self.block_size or (final and self._out_n):
            yield self._block(min(self.block_size, self._out_n))

    def _other_publisher(self, rows: Rows, k: int, final: bool) -> BoolArray:
        """Which of the first ``k`` pending rows are a second publisher's on the same joints.

        Bags carry no publisher id, so the rule is the stamp lattice with the content: a sample
        whose efforts are all exactly 0 (a fake driver, a placeholder node) that falls between
        two samples measuring effort less than 1.5 periods apart was squeezed in beside the
        live stream, not in its place (after the stream's last live sample: less than half a
        period after it). A driver whose motors are off publishes zeros in place of its
        samples, a period apart: those are kept. Decided on the pending rows (the reorder
        window is the look ahead), vectorised."""
        effort = rows.effort
        none = np.zeros(k, dtype=bool)
        if self._period_ns is None or effort is None or not k:
            return none
        # a sample all of whose efforts are 0 has its first one 0: most blocks have none
        if (effort[:k, 0] == 0).any():
            finite = np.isfinite(effort).all(axis=1)
            zero = finite & (effort == 0).all(axis=1)
            measuring = finite & ~zero
            stamp = rows.stamp.astype(np.float64)
            prev = np.maximum.accumulate(np.where(measuring, stamp, -np.inf))
            prev = np.maximum(prev, self._last_measuring)
            after = np.where(measuring, stamp, np.inf)[::-1]
            following = np.minimum.accumulate(after)[::-1]
            squeezed = zero & (following - prev <= 1.5 * self._period_ns)
            if final:  # after the last live sample: squeezed in when well before its next one
                late = np.isinf(following) & (stamp - prev < 0.5 * self._period_ns)
                squeezed |= zero & late
            none = squeezed[:k]
        # the last sample emitted that measures effort: the last one, as a rule
        last = effort[k - 1]
        if np.isfinite(last).all() and last.any():
            self._last_measuring = float(rows.stamp[k - 1])
        else:
            measures = np.flatnonzero(np.isfinite(effort[:k]).all(axis=1) & effort[:k].any(axis=1))
            if len(measures):
                self._last_measuring = float(rows.stamp[measures[-1]])
        return none

    def _span_s(self) -> float:
        """Seconds from the first sample emitted to the last."""
        first = self._first if self._first is not None else self._last
        return 0.0 if first is None or self._last is None else (self._last - first) * 1e-9

    def _block(self, n: int) -> SampleBlock:
        rows = self._out[0] if len(self._out) == 1 else concat(self._out)
        labels = cat(self._labels_out)
        sim = cat(self._sim_out)
        head, rest = rows.select(slice(0, n)), rows.select(slice(n, None))
        self._out = [rest] if len(rest) else []
        self._out_n = len(rest)
        self._labels_out = [] if labels is None or not len(rest) else [labels[n:]]
        self._sim_out = [] if sim is None or not len(rest) else [sim[n:]]
        self.counts.samples += n
        return SampleBlock(
            stamp_ns=head.stamp,
            log_time_ns=head.log_time,
            position=head.position,
            velocity=head.velocity,
            effort=head.effort,
            labels=None if labels is None else labels[:n],
            sim_effort=None if sim is None else sim[:n],
        )

    def _report(self) -> None:
        report_counts(
            self.counts, self.source, self.topic, self.reorder, self._span_s(), self.damage
        )


# Open a log for streaming; iterate the result for ``SampleBlock``s (see ``LogStream``).
iter_blocks = LogStream
