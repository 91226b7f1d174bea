"""How to read a log: topics and the joint map (recorded in the calibration by ``fit``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from twincd.defaults import DEFAULT_LABEL_TOPIC, DEFAULT_SIM_TOPIC, DEFAULT_TOPIC
from twincd.errors import UsageError

__all__ = [
    "DEFAULT_LABEL_TOPIC",
    "DEFAULT_SIM_TOPIC",
    "DEFAULT_TOPIC",
    "LogOptions",
    "parse_joint_map",
]


@dataclass(frozen=True)
class LogOptions:
    """How to read joint states from a log; recorded in the calibration by ``fit``."""

    topic: str = DEFAULT_TOPIC
    label_topic: str = DEFAULT_LABEL_TOPIC
    sim_topic: str = DEFAULT_SIM_TOPIC
    joint_map: Mapping[str, str] | None = None


def parse_joint_map(text: str | None) -> dict[str, str]:
    """``old=new,old2=new2`` to a dict; empty or None gives {}."""
    if not text:
        return {}
    mapping: dict[str, str] = {}
    for item in text.split(","):
        old, sep, new = item.partition("=")
        if not sep or not old.strip() or not new.strip():
            raise UsageError(
                f"bad joint map entry {item!r}", "the joint map", "write it as old=new,old2=new2"
            )
        mapping[old.strip()] = new.strip()
    return mapping
