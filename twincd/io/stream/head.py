"""A log opened for the sample stream (``twincd.io.stream.samples.LogStream``): its topics
chosen, and its first messages read ahead (up to the reorder window), which fix the stream's
joints, its time base, whether it has effort and the period of the samples that measure it."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np

from twincd.errors import LogReadError, TopicError
from twincd.io.cdr import BOOL, DYNAMIC_JOINT_STATE, JOINT_STATE
from twincd.io.stream.batch import Batch, JointStateBatch
from twincd.io.stream.choice import DYNAMIC_TOPIC, Columns, choose_joints, choose_topic
from twincd.io.stream.topics import TopicReader

if TYPE_CHECKING:
    from twincd.io.options import LogOptions

log = logging.getLogger("twincd")


class LogHead:
    """What opening a log fixes for its ``LogStream`` (its docstring says how), and the
    batches read ahead to fix it: ``batches``, each with the reader's watermark of the moment,
    then ``items``, the topic batches after them.

    ``known``: the joints wanted (exactly those when ``exact``; None: the log's), named by
    ``known_from``; ``reorder``: the joint-state samples to read ahead."""

    def __init__(
        self,
        reader: TopicReader,
        options: LogOptions,
        known: Sequence[str] | None,
        exact: bool,
        known_from: str,
        reorder: int,
    ) -> None:
        from twincd.io.named import require_named, require_named_joints

        self._reader = reader
        self.source = reader.source
        self.known_from = known_from
        self._rename = options.rename  # log joint names → the model's
        require_named(options, reader.topics, self.source)  # a named topic the log lacks: refused
        self._choose_topics(options)
        self.items: Iterator[tuple[str, Batch]] = reader.batches(self._wanted())
        self.batches = self._read_ahead(reorder)
        first = self._first_joint_states()
        raw = {n for _, b, _ in self.batches if isinstance(b, JointStateBatch) for n in b.names}
        require_named_joints(options, raw, f"{self.source}, {self.topic}")
        self.joint_names = self._choose_joints(first, known, exact)
        self.columns = Columns(self.joint_names, self._rename, f"{self.source}, {self.topic}")
        # header stamps, unless every stamp of the topic is 0 (decided on the first messages):
        # then the log time; a stamp of 0 among others is a time like any other (simulation
        # time starts there)
        self.log_timed = not any(b.stamp_ns.any() for b in first)
        sims = self._joint_states(self.sim_topic)
        self.sim_log_timed = bool(sims) and not any(b.stamp_ns.any() for b in sims)
        # a log has effort when most of its first messages carry it (one empty message does
        # not decide); samples without it are dropped as bad samples later
        with_effort = sum(len(b) for b in first if b.effort.shape[1] > 0)
        self.has_effort = 2 * with_effort > sum(len(b) for b in first)
        self.period_ns = self._measuring_period(first) if self.has_effort else None

    def _choose_topics(self, options: LogOptions) -> None:
        """The joint-state topic, whether the label and twin effort topics are there, and the
        DynamicJointState topic that may stand in for effort."""
        topics = self._reader.topics
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

    def _wanted(self) -> list[str]:
        """The topics to decode."""
        wanted = [self.topic] + ([self._dynamic] if self._dynamic else [])
        wanted += [self.label_topic] if self.has_labels else []
        wanted += [self.sim_topic] if self.has_sim else []
        return wanted

    def _read_ahead(self, reorder: int) -> list[tuple[str, Batch, int]]:
        """The batches up to the reorder window's joint-state samples, each with the reader's
        watermark of the moment."""
        head: list[tuple[str, Batch, int]] = []
        seen = 0
        for topic, batch in self.items:
            head.append((topic, batch, self._reader.watermark_ns))
            if topic == self.topic:
                seen += len(batch)
                if seen >= max(reorder, 1):
                    break
        return head

    def _joint_states(self, topic: str) -> list[JointStateBatch]:
        """The JointState batches of ``topic`` read ahead."""
        return [b for t, b, _ in self.batches if t == topic and isinstance(b, JointStateBatch)]

    def _first_joint_states(self) -> list[JointStateBatch]:
        """The stream topic's batches read ahead (a ``LogReadError`` when there are none)."""
        first = self._joint_states(self.topic)
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
        return first

    def _effort_source(self, first: list[JointStateBatch], dynamic: str) -> list[JointStateBatch]:
        """The JointState messages read ahead, or, when none carries effort, those of the
        DynamicJointState topic ``dynamic`` (which becomes the stream's topic); the topic not
        read is no longer decoded."""
        if any(b.effort.shape[1] for b in first):
            self._reader.ignore(dynamic)
            return first
        other = self._joint_states(dynamic)
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

    def _choose_joints(
        self, first: list[JointStateBatch], known: Sequence[str] | None, exact: bool
    ) -> tuple[str, ...]:
        """The stream's joints (``choose_joints``) among the layouts of ``first``: the
        ``known`` ones, with those of the log's own twin effort unless ``exact``; without any,
        the twin effort's, else the layout's that carries the most joints."""
        layouts: dict[tuple[str, ...], int] = {}
        for b in first:
            key = self._mapped(b.names)
            layouts[key] = layouts.get(key, 0) + len(b)
        if known is None:
            known = self._sim_names() or max(layouts, key=lambda k: (len(set(k)), layouts[k]))
            self.known_from = "the log's twin effort" if self._sim_names() else "the topic"
        elif not exact:  # joints with the log's own twin effort are never ignored
            known = tuple(dict.fromkeys((*known, *self._sim_names())))
        return choose_joints(layouts, tuple(known), exact, self.known_from, self.source, self.topic)

    def _measuring_period(self, first: list[JointStateBatch]) -> float | None:
        """The nominal period (ns) of the messages read ahead that measure effort on the
        stream's joints (``LogStream._other_publisher``'s lattice), or None when too few do."""
        stamps = []
        for b in first:
            cols = self.columns(b.names)
            if (cols < 0).any() or b.effort.shape[1] != len(b.names):
                continue
            effort = b.effort[:, cols]
            measuring = np.isfinite(effort).all(axis=1) & (effort != 0).any(axis=1)
            stamps.append((b.log_time_ns if self.log_timed else b.stamp_ns)[measuring])
        steps = np.diff(np.unique(np.concatenate(stamps))) if stamps else np.zeros(0)
        return float(np.median(steps)) if len(steps) else None

    def _mapped(self, names: Sequence[str]) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self._rename(n) for n in names))

    def _sim_names(self) -> tuple[str, ...]:
        """The joints of the log's own twin effort in the messages read ahead."""
        return self._mapped(
            [
                n
                for topic, batch, _ in self.batches
                if topic == self.sim_topic and self.has_sim and isinstance(batch, JointStateBatch)
                for n in batch.names
            ]
        )
