"""Recordings read another way than a calibration's logs were: one arm of a bag that holds two
(``/left/joint_states``, ``/right/joint_states``, joints ``left_joint1``…), labels on another
topic. Built from an existing MCAP log's messages with rosbags' writers (``builders.write``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from support.builders import TS, Message, write

JOINT_STATE = "sensor_msgs/msg/JointState"


def messages_of(log: Path) -> list[Message]:
    """Every message of the MCAP ``log``, deserialised by rosbags (in log-time order)."""
    from mcap.reader import make_reader

    with open(log, "rb") as f:
        items = [
            Message(c.topic, s.name, m.log_time, TS.deserialize_cdr(m.data, s.name))
            for s, c, m in make_reader(f).iter_messages()
            if s is not None
        ]
    return items


def retopic(messages: Sequence[Message], topics: Mapping[str, str]) -> list[Message]:
    """The messages with their topics renamed (``topics``: old → new; others unchanged)."""
    return [replace(m, topic=topics.get(m.topic, m.topic)) for m in messages]


def prefixed(messages: Sequence[Message], prefix: str, topic: str) -> list[Message]:
    """The joint states of ``messages`` on ``topic``, each joint named ``prefix`` + its name
    (one arm of a bag of two); other messages left out."""
    out = []
    for m in messages:
        if m.msgtype == JOINT_STATE and m.topic == "/joint_states":
            names = [prefix + n for n in m.msg.name]
            out.append(replace(m, topic=topic, msg=replace(m.msg, name=names)))
    return out


def two_arm_bag(
    target: Path,
    left: Path,
    right: Path,
    form: str = "rosbag2-mcap",
    topics: Mapping[str, str] | None = None,
) -> Path:
    """A bag of two arms: ``left``'s joint states on ``/left/joint_states`` (``left_joint1``…),
    ``right``'s on ``/right/joint_states`` (``right_joint1``…), and ``left``'s other topics
    (labels, contact links, its twin's effort) as they are, or renamed by ``topics``."""
    left_msgs = messages_of(left)
    arms = prefixed(left_msgs, "left_", "/left/joint_states")
    arms += prefixed(messages_of(right), "right_", "/right/joint_states")
    rest = retopic([m for m in left_msgs if m.topic != "/joint_states"], topics or {})
    return write(target, form, sorted([*arms, *rest], key=lambda m: m.log_time))


def left_arm_alone(target: Path, left: Path, form: str = "rosbag2-mcap") -> Path:
    """``left`` written again as it is, in ``form`` (what the two-arm bag's left arm must
    read as)."""
    return write(target, form, messages_of(left))
