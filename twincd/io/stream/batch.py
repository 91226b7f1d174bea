"""The batch types of the block stream: decoded messages of one topic, a bounded number at a
time, as ``TopicReader`` yields them, and the raw (undecoded) messages its backends give.
"""

from __future__ import annotations

from dataclasses import dataclass

from twincd.io.cdr import BOOL, JOINT_STATE, STRING
from twincd.types import BoolArray, ByteArray, FloatArray, IntArray

__all__ = [
    "DEFAULT_BATCH",
    "END",
    "STRING",
    "SUPPORTED",
    "Batch",
    "BoolBatch",
    "Damage",
    "JointStateBatch",
    "RawTopic",
    "StringBatch",
]

SUPPORTED = (JOINT_STATE, BOOL, STRING)
DEFAULT_BATCH = 16384  # messages decoded at once: 4× smaller peak memory than 65 536, as fast
END = 2**63 - 1  # the watermark once everything has been read


@dataclass(frozen=True)
class JointStateBatch:
    """JointState messages that share one name list (and array widths).

    ``stamp_ns`` is the raw header stamp (0 where the publisher left it empty). A ragged
    message (a filled array whose length differs from ``names``) keeps its own widths.
    """

    names: tuple[str, ...]
    log_time_ns: IntArray
    stamp_ns: IntArray
    position: FloatArray  # (n, k)
    velocity: FloatArray  # (n, k), or (n, 0) for messages without velocity
    effort: FloatArray  # (n, k), or (n, 0)

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclass(frozen=True)
class BoolBatch:
    """std_msgs/msg/Bool messages."""

    log_time_ns: IntArray
    value: BoolArray

    def __len__(self) -> int:
        return len(self.log_time_ns)


@dataclass(frozen=True)
class StringBatch:
    """std_msgs/msg/String messages (rare: decoded by rosbags)."""

    log_time_ns: IntArray
    values: list[str]

    def __len__(self) -> int:
        return len(self.log_time_ns)


Batch = JointStateBatch | BoolBatch | StringBatch


@dataclass(frozen=True)
class RawTopic:
    """Undecoded CDR messages of one topic, all of one payload length."""

    topic: str
    log_time_ns: IntArray
    payloads: ByteArray


class Damage(Exception):
    """Reading stopped at a damaged part of the log (``where`` says what and where)."""
