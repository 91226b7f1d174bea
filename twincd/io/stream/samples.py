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

import logging
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from twincd.errors import JointMismatchError, LogReadError, SplitJointsError, TopicError
from twincd.io.cdr import BOOL, DYNAMIC_JOINT_STATE, JOINT_STATE, CdrStats
from twincd.io.stream.batch import DEFAULT_BATCH, END, Batch, BoolBatch, JointStateBatch
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
    "OWN_PREFIX",
    "LogStream",
    "SampleBlock",
    "StreamCounts",
    "choose_topic",
    "iter_blocks",
    "warn_ignored_joints",
]

log = logging.getLogger("twincd")


OWN_PREFIX = "/twincd/"  # twincd's own channels: never taken for the robot's joint states
DYNAMIC_TOPIC = "/dynamic_joint_states"  # ros2_control's joint_state_broadcaster publishes here
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


@dataclass
class StreamCounts:
    """What happened to the JointState messages of a stream."""

    read: int = 0  # messages read on the topic
    incomplete: int = 0  # dropped: a stream joint missing, or a non-finite position
    duplicates: int = 0  # dropped: the exact stamp of an earlier sample
    late: int = 0  # dropped: older than a sample already emitted
    ragged: int = 0  # dropped: filled arrays whose length differs from the names
    clock_back: int = 0  # dropped: behind a backward jump of the clock
    jumps: int = 0  # backward jumps of the clock
    largest_jump_ns: int = 0
    samples: int = 0  # emitted
    unstamped: int = 0  # every header stamp of the topic 0: timed by the log time instead
    foreign: int = 0  # ignored: messages that carry none of the stream's joints
    foreign_names: tuple[str, ...] = ()  # the joints those messages name
    other_publisher: int = 0  # ignored: a second publisher's on the same joints (zeros)
    named_twice: int = 0  # messages naming a joint twice (its first value kept)
    twice_names: tuple[str, ...] = ()

    @property
    def dropped(self) -> int:
        return (
            self.incomplete
            + self.duplicates
            + self.late
            + self.ragged
            + self.clock_back
            + self.other_publisher
        )


def warn_ignored_joints(source: str, names: Sequence[str], used: Sequence[str], what: str) -> None:
    """One warning naming the log joints (``names``) that are not ``used``."""
    ignored = [n for n in names if n not in used]
    if ignored:
        log.warning(
            "%s: ignoring %d log joint(s) not in %s: %s",
            source,
            len(ignored),
            what,
            ", ".join(ignored),
        )


def choose_topic(topics: Mapping[str, str], wanted: str, source: str) -> str:
    """The JointState topic to read (contract: Inputs: fall back to the only JointState topic,
    or, without any, to the only DynamicJointState topic)."""
    if wanted in topics:
        if topics[wanted] not in (JOINT_STATE, DYNAMIC_JOINT_STATE):
            raise TopicError(
                f"topic {wanted} is {topics[wanted]}, not {JOINT_STATE}",
                source,
                "pick a JointState topic with the topic option",
            )
        return wanted
    candidates = sorted(
        t for t, m in topics.items() if m == JOINT_STATE and not t.startswith(OWN_PREFIX)
    ) or sorted(t for t, m in topics.items() if m == DYNAMIC_JOINT_STATE)
    if len(candidates) == 1:
        log.warning(
            "topic %s not in %s; using its only JointState topic %s", wanted, source, candidates[0]
        )
        return candidates[0]
    if not candidates:
        raise TopicError(
            f"no {JOINT_STATE} topic (wanted {wanted})",
            source,
            "record joint states or pick another topic with the topic option",
        )
    raise TopicError(
        f"topic {wanted} not found and several JointState topics exist: {', '.join(candidates)}",
        source,
        "pick one with the topic option",
    )


class LogStream:
    """One log's joint states as ``SampleBlock``s (a context manager and an iterable).

    Opening reads the first messages (up to the reorder window) to fix ``joint_names`` (after
    the joint map): exactly ``joints`` when given (an error when the log lacks one, in that
    order); else the ``known`` joints the log has (a robot model's or a calibration's, named by
    ``known_from``, and those of the log's own twin effort; model joints the log lacks are the
    caller's business); else the joints of
    the log's own twin effort (``sim_topic``); else all the joints of the message layout that
    carries the most joints, ties going to the layout with the most messages. Then the layout
    with the most of those joints fixes the columns; other layouts that carry none are another
    publisher's (ignored, counted in one warning), and one that carries a joint it lacks means
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
        self._rename = options.rename  # log joint names → the model's
        self._reader = TopicReader(self.path, strict=strict, batch_size=batch_size)
        self._known_from = "the calibration" if joints is not None else known_from
        try:
            self._open(options, joints if joints is not None else known, joints is not None)
        except BaseException:
            self._reader.close()
            raise

    def _open(self, options: LogOptions, known: Sequence[str] | None, exact: bool) -> None:
        from twincd.io.named import require_named, require_named_joints

        topics = self._reader.topics
        require_named(options, topics, self.source)  # a named topic the log lacks: refused
        self.topic = choose_topic(topics, options.topic, self.source)
        self.label_topic = options.label_topic
        self.has_labels = self.label_topic in topics
        if self.has_labels and topics[self.label_topic] != BOOL:
            raise TopicError(
                f"label topic {self.label_topic} is {topics[self.label_topic]}, not {BOOL}",
                self.source,
                "pick another label topic",
            )
        self.sim_topic = options.sim_topic
        self.has_sim = topics.get(self.sim_topic) == JOINT_STATE
        # ros2_control's DynamicJointState: read when no JointState carries effort
        self.no_effort_why: str | None = None  # why it cannot stand in, when it cannot
        dynamic = [t for t, m in topics.items() if m == DYNAMIC_JOINT_STATE]
        if topics[self.topic] == DYNAMIC_JOINT_STATE or not dynamic:
            self._dynamic: str | None = None
        else:
            self._dynamic = DYNAMIC_TOPIC if DYNAMIC_TOPIC in dynamic else sorted(dynamic)[0]
        wanted = [self.topic] + ([self._dynamic] if self._dynamic else [])
        wanted += [self.label_topic] if self.has_labels else []
        wanted += [self.sim_topic] if self.has_sim else []
        self._items = self._reader.batches(wanted)
        # read ahead to learn the joints; the watermark of the moment goes with each batch
        self._head: list[tuple[str, Batch, int]] = []
        seen = 0
        for topic, batch in self._items:
            self._head.append((topic, batch, self._reader.watermark_ns))
            if topic == self.topic:
                seen += len(batch)
                if seen >= max(self.reorder, 1):
                    break
        first = self._read_ahead(self.topic)
        if self._dynamic is not None:
            first = self._effort_source(first, self._dynamic)
        if not first:
            damage = self._reader.damage
            if damage is not None:  # the damage came before any joint state
                raise LogReadError(
                    damage, self.source, "repair it with `mcap recover` if it is MCAP"
                )
            raise LogReadError(
                f"topic {self.topic} has no messages", self.source, "record joint states"
            )
        raw = {n for t, b, _ in self._head if isinstance(b, JointStateBatch) for n in b.names}
        require_named_joints(options, raw, f"{self.source}, {self.topic}")
        layouts: dict[tuple[str, ...], int] = {}
        for b in first:
            key = self._mapped(b.names)
            layouts[key] = layouts.get(key, 0) + len(b)
        if known is None:
            known = self._sim_names() or max(layouts, key=lambda k: (len(set(k)), layouts[k]))
            self._known_from = "the log's twin effort" if self._sim_names() else "the topic"
        elif not exact:  # joints with the log's own twin effort are never ignored
            known = tuple(dict.fromkeys((*known, *self._sim_names())))
        self.joint_names = self._choose_joints(layouts, tuple(known), exact)
        # header stamps, unless every stamp of the topic is 0 (decided on the first messages):
        # then the log time; a stamp of 0 among others is a time like any other (simulation
        # time starts there)
        self._log_timed = not any(b.stamp_ns.any() for b in first)
        sims = [
            b for t, b, _ in self._head if t == self.sim_topic and isinstance(b, JointStateBatch)
        ]
        self._sim_log_timed = bool(sims) and not any(b.stamp_ns.any() for b in sims)
        # a log has effort when most of its first messages carry it (one empty message does
        # not decide); samples without it are dropped as bad samples later
        with_effort = sum(len(b) for b in first if b.effort.shape[1] > 0)
        self.has_effort = 2 * with_effort > sum(len(b) for b in first)
        self._columns: dict[tuple[str, ...], NDArray[np.intp]] = {}
        self._period_ns = self._measuring_period(first) if self.has_effort else None
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

    def _read_ahead(self, topic: str) -> list[JointStateBatch]:
        return [b for t, b, _ in self._head if t == topic and isinstance(b, JointStateBatch)]

    def _effort_source(self, first: list[JointStateBatch], dynamic: str) -> list[JointStateBatch]:
        """The JointState messages read ahead, or, when none carries effort, those of the
        DynamicJointState topic ``dynamic`` (which becomes the stream's topic); the topic not
        read is no longer decoded."""
        if any(b.effort.shape[1] for b in first):
            self._reader.ignore(dynamic)
            return first
        other = self._read_ahead(dynamic)
        names = {n for b in first for n in self._mapped(b.names)}
        shared = [b for b in other if names & set(self._mapped(b.names)) or not names]
        if not any(b.effort.shape[1] for b in shared):
            what = "no effort interface" if shared else "none of its joints"
            self.no_effort_why = f"{dynamic} ({DYNAMIC_JOINT_STATE}) carries {what}"
            self._reader.ignore(dynamic)
            return first
        log.warning(
            "%s: %s carries no effort; reading the joint states from %s (%s) instead",
            self.source,
            self.topic,
            dynamic,
            DYNAMIC_JOINT_STATE,
        )
        self._reader.ignore(self.topic)
        self.topic = dynamic
        return other

    def _measuring_period(self, first: list[JointStateBatch]) -> float | None:
        """The nominal period (ns) of the messages read ahead that measure effort on the
        stream's joints (``_other_publisher``'s lattice), or None when too few do."""
        stamps = []
        for b in first:
            cols = self._cols(b.names)
            if (cols < 0).any() or b.effort.shape[1] != len(b.names):
                continue
            effort = b.effort[:, cols]
            measuring = np.isfinite(effort).all(axis=1) & (effort != 0).any(axis=1)
            stamps.append((b.log_time_ns if self._log_timed else b.stamp_ns)[measuring])
        steps = np.diff(np.unique(np.concatenate(stamps))) if stamps else np.zeros(0)
        return float(np.median(steps)) if len(steps) else None

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

    def _mapped(self, names: Sequence[str]) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self._rename(n) for n in names))

    def _sim_names(self) -> tuple[str, ...]:
        """The joints of the log's own twin effort in the messages read ahead."""
        return self._mapped(
            [
                n
                for topic, batch, _ in self._head
                if topic == self.sim_topic and self.has_sim and isinstance(batch, JointStateBatch)
                for n in batch.names
            ]
        )

    def _choose_joints(
        self, layouts: dict[tuple[str, ...], int], known: tuple[str, ...], exact: bool
    ) -> tuple[str, ...]:
        """The stream's joints from the layouts read ahead (see the class docstring)."""
        where = f"{self.source}, {self.topic}"
        wanted = set(known)
        relevant = {k: c for k, c in layouts.items() if wanted & set(k)}
        if not relevant:
            calibrated = self._known_from == "the calibration"
            raise JointMismatchError(
                f"the log lacks calibrated joint(s) {', '.join(known)}"
                if calibrated
                else f"no joint of the log is in {self._known_from}",
                f"{where}: log joints {', '.join(sorted({n for k in layouts for n in k})[:8])}; "
                f"wanted {', '.join(known[:8])}",
                "check the robot model, the topic and the joint map",
                option="robot,topic,joint_map",
            )
        best = max(relevant, key=lambda k: (len(wanted & set(k)), relevant[k]))
        covered = wanted & set(best)
        split = [k for k in relevant if (wanted & set(k)) - covered]
        if split:
            parts = " | ".join(", ".join(n for n in k if n in wanted) for k in (best, *split))
            raise SplitJointsError(
                "the arm's joints arrive split over several messages per sample "
                f"({parts}); twincd does not join them",
                where,
                "record the arm's joints in one JointState message (one publisher), or pick a "
                "topic that carries them all with the topic option",
            )
        warn_ignored_joints(self.source, best, tuple(wanted), self._known_from)
        if exact:
            missing = [j for j in known if j not in covered]
            if missing:
                raise JointMismatchError(
                    f"joints {', '.join(missing)} are not in the log",
                    where,
                    "check the robot model, the topic and the joint map",
                )
            return known
        return tuple(n for n in best if n in wanted)

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

    def _cols(self, names: tuple[str, ...]) -> NDArray[np.intp]:
        """Per stream joint, its column in messages named ``names`` (-1: absent; a name given
        twice: its first column)."""
        cols = self._columns.get(names)
        if cols is None:
            where: dict[str, int] = {}
            for i, n in enumerate(names):
                mapped = self._rename(n)
                if mapped in where and names[where[mapped]] != n:
                    clash = names[where[mapped]]
                    raise JointMismatchError(
                        f"after the joint map, log joints {clash} and {n} are both {mapped}",
                        f"{self.source}, {self.topic}",
                        "map every log joint to a name of its own",
                        option="joint_map",
                    )
                where.setdefault(mapped, i)
            cols = np.array([where.get(j, -1) for j in self.joint_names], dtype=np.intp)
            self._columns[names] = cols
        return cols

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
        c = self.counts
        if c.ragged:
            log.warning(
                "%s: dropping %d ragged message(s) (filled arrays that do not match the names)",
                self.source,
                c.ragged,
            )
        if c.jumps:
            log.warning(
                "%s: the clock jumps back %d time(s) (by up to %.3g s); dropping the %d sample(s) "
                "stamped before the time already reached",
                self.source,
                c.jumps,
                c.largest_jump_ns * 1e-9,
                c.clock_back,
            )
        if c.unstamped:
            log.warning(
                "%s: the samples on %s carry no header stamp (every one is 0); the %d sample(s) "
                "are timed by their log time instead",
                self.source,
                self.topic,
                c.unstamped,
            )
        if c.duplicates:
            log.warning(
                "%s: dropping %d sample(s) whose stamp repeats an earlier one",
                self.source,
                c.duplicates,
            )
        if c.foreign:
            log.warning(
                "%s: ignoring %d message(s) on %s that carry none of its joints (another "
                "publisher's: %s)",
                self.source,
                c.foreign,
                self.topic,
                ", ".join(c.foreign_names[:8]),
            )
        if c.other_publisher:
            log.warning(
                "%s: ignoring %d message(s) on %s from a second publisher of the same joints "
                "(every effort exactly 0, between samples of the live one less than 1.5 periods "
                "apart; ≈ %.3g Hz)",
                self.source,
                c.other_publisher,
                self.topic,
                c.other_publisher / max(self._span_s(), 1e-9),
            )
        if c.named_twice:
            log.warning(
                "%s: %d message(s) name joint(s) %s twice; keeping the first value of each",
                self.source,
                c.named_twice,
                ", ".join(c.twice_names),
            )
        if c.incomplete:
            log.warning(
                "%s: dropping %d sample(s) that do not carry every joint", self.source, c.incomplete
            )
        if c.late:
            log.warning(
                "%s: dropping %d sample(s) stamped earlier than samples already read "
                "(more than %d samples out of order)",
                self.source,
                c.late,
                self.reorder,
            )
        if self.damage is not None:
            log.warning("%s: %s", self.source, self.damage)


def iter_blocks(
    path: str | Path,
    options: LogOptions,
    joints: Sequence[str] | None = None,
    block_size: int = DEFAULT_BLOCK,
    strict: bool = True,
    reorder: int = DEFAULT_REORDER,
    known: Sequence[str] | None = None,
    known_from: str = "the robot model",
) -> LogStream:
    """Open a log for streaming; iterate the result for ``SampleBlock``s (see ``LogStream``)."""
    return LogStream(
        path, options, joints, block_size, strict, reorder, known=known, known_from=known_from
    )
