"""Contact-link ground truth (contract: Inputs ``/collision_link``): std_msgs/String, held like the
label onto the joint-state samples. A small topic (a few messages per press), read by the same
topic reader as the joint states (``twincd.io.stream.TopicReader``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from twincd.errors import LogReadError
from twincd.io.cdr import STRING
from twincd.types import IntArray


@dataclass(frozen=True)
class LinkMessages:
    """A log's link messages in time order, to hold onto samples block by block."""

    times_ns: IntArray  # log time of each message, ascending
    values: tuple[str, ...]

    @classmethod
    def of(cls, message_ns: IntArray, links: list[str]) -> LinkMessages:
        order = np.argsort(np.asarray(message_ns, dtype=np.int64), kind="stable")
        times = np.asarray(message_ns, dtype=np.int64)[order]
        return cls(times, tuple(links[i] for i in order))

    def held(self, log_time_ns: IntArray) -> NDArray[np.intp]:
        """Each sample's message: the index of the last one at or before its log time (−1
        before the first)."""
        at: NDArray[np.intp] = (
            np.searchsorted(self.times_ns, np.asarray(log_time_ns, dtype=np.int64), side="right")
            - 1
        )
        return at

    def hold(self, log_time_ns: IntArray) -> tuple[str, ...]:
        """Each sample's link ("" before the first message)."""
        return tuple(self.values[i] if i >= 0 else "" for i in self.held(log_time_ns).tolist())


def read_links(
    path: str | Path, topic: str, log_time_ns: IntArray, strict: bool = False
) -> tuple[str, ...] | None:
    """The touched link per sample, held onto ``log_time_ns``; None: the log lacks ``topic``."""
    messages = read_link_messages(path, topic, strict)
    return None if messages is None else messages.hold(log_time_ns)


def read_link_messages(path: str | Path, topic: str, strict: bool = False) -> LinkMessages | None:
    """The log's messages on the link ``topic``; None: the log lacks ``topic``.

    Read by the block stream's topic reader, the one every command reads a log with (a log
    that reads for ``detect`` reads here alike); ``strict``: a damaged log is an error, else
    read up to the damage as the joint states were."""
    from twincd.io.stream import StringBatch

    batches = read_small_topic(path, topic, STRING, "link", strict)
    if batches is None:
        return None
    stamps: list[IntArray] = []
    links: list[str] = []
    for batch in batches:
        if isinstance(batch, StringBatch):
            stamps.append(batch.log_time_ns)
            links.extend(batch.values)
    times = np.concatenate(stamps) if stamps else np.zeros(0, dtype=np.int64)
    return LinkMessages.of(times, links)


def read_small_topic(
    path: str | Path, topic: str, msgtype: str, what: str, strict: bool = False
) -> list[Any] | None:
    """Every batch of a small ``topic`` of type ``msgtype`` (a few messages per push: links,
    labels), read by the topic reader every command reads a log with; None: the log lacks
    ``topic``; another type is an error naming the ``what`` topic (``--{what}-topic``)."""
    from twincd.io.stream import TopicReader

    with TopicReader(Path(path), strict=strict) as reader:
        found = reader.topics.get(topic)
        if found is None:
            return None
        if found != msgtype:
            raise LogReadError(
                f"{what} topic {topic} is {found}, not {msgtype}",
                str(path),
                f"pick another {what} topic",
                option=f"{what}_topic",
            )
        return [batch for _, batch in reader.batches([topic])]
