"""twincd's output channels, declared once (contract: Outputs): each per-sample channel's topic,
message type, the frame columns it carries, its MCAP encoder and its table columns; the events'
channel. ``detect``'s sinks (MCAP, CSV, JSON lines: ``twincd.detection.outputs``) and ``watch
-o``'s recorder (``twincd.live.record``) all iterate over them, so a new channel is one entry of
``SAMPLE_CHANNELS``.

A scored frame (``SCORED_COLUMNS``) holds per sample its header stamp and log time, the
joints' position and velocity, the residual per joint, the score and the flag."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.io.cdr import BOOL, FLOAT64, JOINT_STATE, STRING

if TYPE_CHECKING:
    from twincd.detection.events import Event
    from twincd.prepare.frames import Frame

__all__ = [
    "COLLISION_TOPIC",
    "EVENT_TOPIC",
    "RESIDUAL_TOPIC",
    "SAMPLE_CHANNELS",
    "SCORED_COLUMNS",
    "SCORE_TOPIC",
    "TABLE_CHANNELS",
    "SampleChannel",
    "event_payloads",
    "table_columns",
    "table_header",
]

RESIDUAL_TOPIC = "/twincd/residual"
SCORE_TOPIC = "/twincd/score"
COLLISION_TOPIC = "/twincd/collision"
EVENT_TOPIC = "/twincd/event"

# what a scored frame holds for the sinks
SCORED_COLUMNS = ("stamp_ns", "log_time_ns", "position", "velocity", "residual", "score", "flag")


@dataclass(frozen=True)
class SampleChannel:
    """One message per scored sample on ``topic`` (``msgtype``), stamped with the sample's log
    time: ``encode`` gives its CDR payloads from a scored frame and the joint names;
    ``columns`` its table columns' names (from the joint names), ``values`` their values (one
    array per column); tables order the channels by ``table_rank``."""

    topic: str
    msgtype: str
    encode: Callable[[Frame, Sequence[str]], Any]
    columns: Callable[[Sequence[str]], list[str]]
    values: Callable[[Frame], list[np.ndarray]]
    table_rank: int


def _residual(frame: Frame, joints: Sequence[str]) -> Any:
    from twincd.io.cdr import joint_state_block

    # a JointState whose effort is the residual, with the sample's header stamp and state
    return joint_state_block(
        frame["stamp_ns"], joints, frame["position"], frame["velocity"], frame["residual"]
    )


def _score(frame: Frame, joints: Sequence[str]) -> Any:
    from twincd.io.cdr import float64_block

    return float64_block(frame["score"])  # no header: its log time ties it to the sample


def _flag(frame: Frame, joints: Sequence[str]) -> Any:
    from twincd.io.cdr import bool_block

    return bool_block(frame["flag"])


SAMPLE_CHANNELS: tuple[SampleChannel, ...] = (
    SampleChannel(
        RESIDUAL_TOPIC,
        JOINT_STATE,
        _residual,
        lambda joints: [f"residual_{n}" for n in joints],
        lambda frame: list(np.asarray(frame["residual"]).T),
        2,
    ),
    SampleChannel(SCORE_TOPIC, FLOAT64, _score, lambda _: ["score"], lambda f: [f["score"]], 0),
    SampleChannel(COLLISION_TOPIC, BOOL, _flag, lambda _: ["collision"], lambda f: [f["flag"]], 1),
)
TABLE_CHANNELS = tuple(sorted(SAMPLE_CHANNELS, key=lambda c: c.table_rank))


def table_header(joints: Sequence[str]) -> list[str]:
    """A table's columns: the header stamp, then each channel's (``stamp_ns,score,collision,
    residual_<joint>…``)."""
    return ["stamp_ns", *(name for c in TABLE_CHANNELS for name in c.columns(joints))]


def table_columns(frame: Frame) -> list[np.ndarray]:
    """The values of ``table_header``'s columns for a scored frame, one array per column."""
    return [np.asarray(frame["stamp_ns"]), *(v for c in TABLE_CHANNELS for v in c.values(frame))]


def event_payloads(events: Sequence[Event]) -> list[bytes]:
    """``EVENT_TOPIC``'s messages: one ``std_msgs/String`` of each event's JSON, published when
    the event ends."""
    from twincd.io.cdr import serialize, typestore

    string = typestore().types[STRING]
    return [serialize(string(data=json.dumps(e.to_dict())), STRING) for e in events]
