"""How to read a log: topics and the joint names (recorded in the calibration by ``fit`` as
the defaults of later runs, which may read their logs otherwise)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from twincd.defaults import (
    DEFAULT_LABEL_TOPIC,
    DEFAULT_LINK_TOPIC,
    DEFAULT_SIM_TOPIC,
    DEFAULT_TOPIC,
)
from twincd.errors import UsageError

__all__ = [
    "DEFAULT_LABEL_TOPIC",
    "DEFAULT_LINK_TOPIC",
    "DEFAULT_SIM_TOPIC",
    "DEFAULT_TOPIC",
    "LogOptions",
    "named_options",
    "parse_joint_map",
]


@dataclass(frozen=True)
class LogOptions:
    """How to read joint states from a log; recorded in the calibration by ``fit``.

    Log joints are renamed before they are matched to the model's (``rename``): by
    ``joint_map`` (old → new), else by taking ``joint_prefix`` off a name that starts with it
    (``left_`` reads ``left_joint1`` as ``joint1``: one arm of a bag that holds two).

    ``named``: the options the user named (``topic``, ``label_topic``, ``sim_topic``,
    ``link_topic``, ``joint_prefix``, and ``joint_map:OLD`` per joint-map entry), as opposed
    to defaulted: a log that lacks a named one is refused (``twincd.io.named``), never read
    with a default in its place. Not part of the options' identity, nor recorded.
    """

    topic: str = DEFAULT_TOPIC
    label_topic: str = DEFAULT_LABEL_TOPIC
    sim_topic: str = DEFAULT_SIM_TOPIC
    joint_map: Mapping[str, str] | None = None
    named: frozenset[str] = field(default=frozenset(), compare=False)
    link_topic: str = DEFAULT_LINK_TOPIC
    joint_prefix: str = ""

    def names(self, option: str) -> bool:
        """Whether ``option`` (``topic``, ``joint_map:OLD``, …) was named by the user."""
        return option in self.named

    def unnamed(self, *options: str) -> LogOptions:
        """The same options with ``options`` no longer counted as named."""
        from dataclasses import replace

        return replace(self, named=self.named - set(options))

    def rename(self, name: str) -> str:
        """A log joint's name as the model knows it (see the class docstring)."""
        mapped = (self.joint_map or {}).get(name)
        if mapped is not None:
            return mapped
        prefix = self.joint_prefix
        return name[len(prefix) :] if prefix and name.startswith(prefix) else name


def named_options(
    topic: str | None = None,
    label_topic: str | None = None,
    sim_topic: str | None = None,
    joint_map: Mapping[str, str] | None = None,
    link_topic: str | None = None,
    joint_prefix: str | None = None,
) -> frozenset[str]:
    """``LogOptions.named`` for the options given (None: not given)."""
    given = {
        "topic": topic,
        "label_topic": label_topic,
        "sim_topic": sim_topic,
        "link_topic": link_topic,
        "joint_prefix": joint_prefix or None,
    }
    entries = {f"joint_map:{old}" for old in joint_map or {}}
    return frozenset({k for k, v in given.items() if v is not None} | entries)


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
