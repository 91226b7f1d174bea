"""Contact-link ground truth (contract: Inputs ``/collision_link``): std_msgs/String, held like the
label onto the joint-state samples. A small topic (a few messages per press), so it is read with
rosbags' reader on its own rather than through the block reader of the joint states."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twincd.errors import LogReadError
from twincd.io.cdr import STRING
from twincd.io.sources import first_line, open_reader
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


def hold_links(message_ns: IntArray, links: list[str], log_time_ns: IntArray) -> tuple[str, ...]:
    """Each sample's link: the last message at or before its log time ("" before the first)."""
    return LinkMessages.of(message_ns, links).hold(log_time_ns)


def read_links(path: str | Path, topic: str, log_time_ns: IntArray) -> tuple[str, ...] | None:
    """The touched link per sample, held onto ``log_time_ns``; None: the log lacks ``topic``."""
    messages = read_link_messages(path, topic)
    return None if messages is None else messages.hold(log_time_ns)


def read_link_messages(path: str | Path, topic: str) -> LinkMessages | None:
    """The log's messages on the link ``topic``; None: the log lacks ``topic``."""
    reader = open_reader(Path(path))
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            return None
        if any(c.msgtype != STRING for c in conns):
            raise LogReadError(
                f"link topic {topic} is {conns[0].msgtype}, not {STRING}",
                str(path),
                "pick another link topic",
                option="link_topic",
            )
        stamps: list[int] = []
        links: list[str] = []
        try:
            for conn, when, raw in reader.messages(conns):
                stamps.append(int(when))
                links.append(str(reader.deserialize(raw, conn.msgtype).data))
        except Exception as exc:  # the I/O edge: a damaged topic becomes one line
            raise LogReadError(
                f"cannot read link topic {topic}: {first_line(exc)}",
                str(path),
                "check the log, or pick another link topic",
                option="link_topic",
            ) from exc
    finally:
        reader.close()
    return LinkMessages.of(np.asarray(stamps, dtype=np.int64), links)
