"""The batch types of the block stream: decoded messages of one topic, a bounded number at a
time, as ``TopicReader`` yields them, and the raw (undecoded) messages its backends give.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from twincd.io.cdr import BOOL, DYNAMIC_JOINT_STATE, JOINT_STATE, STRING
from twincd.types import BoolArray, ByteArray, FloatArray, IntArray

__all__ = [
    "DEFAULT_BATCH",
    "END",
    "INTERFACES",
    "STRING",
    "SUPPORTED",
    "Batch",
    "BoolBatch",
    "Damage",
    "JointStateBatch",
    "RawTopic",
    "StringBatch",
    "dynamic_batches",
    "message_batches",
]

SUPPORTED = (JOINT_STATE, DYNAMIC_JOINT_STATE, BOOL, STRING)
# the state interfaces of a DynamicJointState that a JointState carries
INTERFACES = ("position", "velocity", "effort")
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


def dynamic_batches(log_time_ns: IntArray, msgs: Sequence[Any]) -> list[JointStateBatch]:
    """ros2_control's ``DynamicJointState`` messages (decoded) as JointState batches, one per
    layout (joint names and their interfaces): each joint's ``position``, ``velocity`` and
    ``effort`` interfaces, NaN where a joint lacks one (a sample without a position is then
    dropped as incomplete), an empty array where no joint has it."""
    layouts: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(msgs):
        interfaces = tuple(tuple(v.interface_names) for v in m.interface_values)
        layouts.setdefault((tuple(m.joint_names), interfaces), []).append(i)
    out = []
    for (names, interfaces), rows in layouts.items():
        n, k = len(rows), len(names)
        columns = []
        for kind in INTERFACES:
            where = [(j, ifs.index(kind)) for j, ifs in enumerate(interfaces[:k]) if kind in ifs]
            if not where and kind != "position":
                columns.append(np.zeros((n, 0)))
                continue
            values = np.full((n, k), np.nan)
            for j, at in where:
                values[:, j] = [_value(msgs[r].interface_values[j].values, at) for r in rows]
            columns.append(values)
        stamps = np.array(
            [msgs[r].header.stamp.sec * 1_000_000_000 + msgs[r].header.stamp.nanosec for r in rows],
            dtype=np.int64,
        )
        out.append(JointStateBatch(names, log_time_ns[rows], stamps, *columns))
    return out


def message_batches(msgtype: str, log_time_ns: IntArray, msgs: Sequence[Any]) -> list[Batch]:
    """Decoded messages of one topic of type ``msgtype`` (a ``Bool``, ``DynamicJointState`` or
    ``String`` type of ``SUPPORTED``) as batches: how both readers turn the messages rosbags
    deserialised into the stream's batches."""
    if msgtype == BOOL:
        return [BoolBatch(log_time_ns, np.array([bool(m.data) for m in msgs], dtype=bool))]
    if msgtype == DYNAMIC_JOINT_STATE:
        return list(dynamic_batches(log_time_ns, msgs))
    return [StringBatch(log_time_ns, [str(m.data) for m in msgs])]


def _value(values: Any, at: int) -> float:
    return float(values[at]) if at < len(values) else float("nan")
