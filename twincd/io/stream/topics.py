"""Topic batches: every log form read as decoded arrays, a bounded batch at a time (the message
layer of the block stream; ``twincd.io.stream.samples`` turns these into time-ordered samples).

``TopicReader(path).batches(topics)`` yields ``(topic, batch)`` pairs in (approximately) log-time
order, each batch a few tens of thousands of messages at most, never the whole log:

- bare MCAP files and the MCAP storage files of rosbag2 folders: whole chunks, decoded with
  numpy (``twincd.io.mcap`` and the decoders of ``twincd.io.cdr``);
- rosbag2 sqlite3: bulk SQL in timestamp order, decoded the same way;
- ROS 1 bags, compressed rosbag2 bags and anything else: rosbags' AnyReader, per message.

``watermark_ns`` says how far the log has been read: every wanted message with a log time
below it has been yielded. Joining topics by log time (labels) waits for it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from twincd.errors import LogReadError, TopicError, TwincdError
from twincd.io.cdr import (
    BOOL,
    JOINT_STATE,
    CdrStats,
    decode_bools,
    decode_joint_states,
    typestore,
)
from twincd.io.sources import first_line
from twincd.io.stream.backends import McapBackend, open_backend
from twincd.io.stream.batch import (
    DEFAULT_BATCH,
    END,
    SUPPORTED,
    Batch,
    BoolBatch,
    Damage,
    JointStateBatch,
    RawTopic,
    message_batches,
)
from twincd.types import ByteArray, IntArray

__all__ = ["TopicReader"]


class TopicReader:
    """Decoded batches of the topics of one log (a context manager).

    ``strict``: a truncated or corrupt log raises ``LogReadError``; otherwise reading stops at
    the damage and ``damage`` says what was read.
    """

    def __init__(self, path: str | Path, strict: bool = True, batch_size: int = DEFAULT_BATCH):
        self.path = Path(path)
        self.source = str(self.path)
        self.strict = strict
        self.batch_size = batch_size
        self.stats = CdrStats()
        self.watermark_ns = -(2**63)
        self.messages = 0  # yielded so far
        self.last_log_time_ns: int | None = None
        self.ignored: set[str] = set()  # wanted topics no longer decoded (``ignore``)
        self._damage: str | None = None
        self._backend = open_backend(self.path, self.source, self.stats)
        self.topics: dict[str, str] = dict(self._backend.topics)
        if self._backend.damage is not None:
            if not self.topics:  # nothing intact to read: an error, strict or not
                damage, self.strict = self._backend.damage, True
                self._damaged(damage)
            self._damaged(self._backend.damage)

    def __enter__(self) -> TopicReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._backend.close()

    @property
    def damage(self) -> str | None:
        """With strict=False: what is damaged and how much was read before it; else None."""
        if self._damage is None:
            return None
        upto = (
            f" up to log time {self.last_log_time_ns}" if self.last_log_time_ns is not None else ""
        )
        read = f"read {self.messages} message(s) of the wanted topics{upto}"
        fix = "; `mcap recover` can repair it" if isinstance(self._backend, McapBackend) else ""
        return f"log is damaged: {self._damage}; {read}{fix}"

    def _damaged(self, where: str) -> None:
        if self.strict:
            self.close()
            raise LogReadError(f"cannot read damaged log: {where}", self.source, self._backend.hint)
        self._damage = self._damage or where

    def batches(self, topics: Sequence[str]) -> Iterator[tuple[str, Batch]]:
        """``(topic, batch)`` of the given topics in about log-time order; topics the log
        lacks are skipped. Each batch holds messages of one topic (and one JointState layout).
        """
        wanted = [t for t in dict.fromkeys(topics) if t in self.topics]
        for t in wanted:
            if self.topics[t] not in SUPPORTED:
                raise TopicError(
                    f"topic {t} is {self.topics[t]}, which twincd does not read",
                    self.source,
                    f"give a topic of type {', '.join(SUPPORTED)}",
                )
        pending: dict[tuple[str, int], list[RawTopic]] = {}
        count = 0
        try:
            for item in self._backend.items(wanted, self.batch_size):
                if isinstance(item, int):
                    if count >= self.batch_size:
                        yield from self._flush(pending)
                        count = 0
                    if count == 0:  # everything before the mark has been yielded
                        self.watermark_ns = item
                elif isinstance(item, RawTopic):
                    if item.topic in self.ignored:
                        continue
                    pending.setdefault((item.topic, item.payloads.shape[1]), []).append(item)
                    count += len(item.log_time_ns)
                    if count >= 4 * self.batch_size:  # a huge chunk: bound memory anyway
                        yield from self._flush(pending)
                        count = 0
                elif item[0] not in self.ignored:
                    yield self._note(*item)
        except Damage as exc:
            yield from self._flush(pending)
            self._damaged(str(exc))
            self.watermark_ns = END
            return
        yield from self._flush(pending)
        self.watermark_ns = END

    def ignore(self, topic: str) -> None:
        """Stop decoding ``topic`` in the batches still to come (a topic read ahead and then
        not needed)."""
        self.ignored.add(topic)

    def _note(self, topic: str, batch: Batch) -> tuple[str, Batch]:
        self.messages += len(batch)
        if len(batch):
            last = int(batch.log_time_ns.max())
            self.last_log_time_ns = max(last, self.last_log_time_ns or last)
        return topic, batch

    def _flush(self, pending: dict[tuple[str, int], list[RawTopic]]) -> Iterator[tuple[str, Batch]]:
        out: list[tuple[str, Batch]] = []
        for key in list(pending):
            raws = pending.pop(key)  # let the pieces go before decoding: a lower peak
            log_time = np.concatenate([r.log_time_ns for r in raws])
            payloads = np.concatenate([r.payloads for r in raws])
            del raws
            out.extend((key[0], b) for b in self._decode(key[0], log_time, payloads))
        out.sort(key=lambda tb: int(tb[1].log_time_ns[0]))
        for topic, batch in out:
            yield self._note(topic, batch)

    def _decode(self, topic: str, log_time: IntArray, payloads: ByteArray) -> list[Batch]:
        msgtype = self.topics[topic]
        try:
            if msgtype == JOINT_STATE:
                return [
                    JointStateBatch(
                        g.names, log_time[g.rows], g.stamp_ns, g.position, g.velocity, g.effort
                    )
                    for g in decode_joint_states(payloads, self.stats)
                ]
            if msgtype == BOOL:
                return [BoolBatch(log_time, decode_bools(payloads, self.stats))]
            # rare (String), or nested (DynamicJointState): decoded by rosbags
            msgs = [typestore().deserialize_cdr(row.tobytes(), msgtype) for row in payloads]
            self.stats.add(fallback=len(msgs))
            return message_batches(msgtype, log_time, msgs)
        except TwincdError:
            raise
        except Exception as exc:  # a payload even rosbags cannot decode
            raise LogReadError(
                f"cannot decode a {msgtype} message: {first_line(exc)}",
                f"{self.source}, {topic} near log time {int(log_time[0])}",
                "the log is corrupt; re-record it",
            ) from exc
