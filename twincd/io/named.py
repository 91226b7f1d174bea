"""Options a user named are honoured or refused, never silently replaced by a default (contract:
Inputs, Exit codes and streams).

A named topic (joint states, labels, the twin's effort, contact links) or joint-map entry that
a log lacks is an error when that log is read (``require_named``, called by the block stream,
so every command and the library refuse it alike). Over a run of several logs, ``settle_named``
decides first: an option that matches nothing in any of the run's logs is an error; one that
matches in some is honoured there and said, in one warning, not to match in the others, which
are then read as if it had not been named (the default topic, no labels, the twin computed).
A default that matches nothing (a default label topic in unlabelled logs) is no error.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from twincd.errors import TopicError, TwincdError, UsageError
from twincd.io.cdr import BOOL, JOINT_STATE, STRING
from twincd.io.options import LogOptions

__all__ = ["require_named", "require_named_joints", "settle_named"]

log = logging.getLogger("twincd")

# joint-state messages looked at for joint names (as ``LogStream`` looks ahead for layouts)
HEAD_MESSAGES = 10_000

# option → (what it is called, the message type it wants, what a log without it does instead)
_TOPICS = {
    "topic": ("joint-state topic", JOINT_STATE, "those use their only JointState topic"),
    "label_topic": ("label topic", BOOL, "those are read without labels"),
    "sim_topic": ("simulated effort topic", JOINT_STATE, "those get the twin's effort computed"),
    "link_topic": ("link topic", STRING, "those are judged without contact links"),
}


def _of_type(topics: Mapping[str, str], msgtype: str) -> str:
    found = sorted(t for t, m in topics.items() if m == msgtype)
    return ", ".join(found[:6]) + (", …" if len(found) > 6 else "") if found else "none"


def require_named(options: LogOptions, topics: Mapping[str, str], source: str) -> None:
    """A ``TopicError`` for the first named topic that ``topics`` (a log's) lacks (the link
    topic aside: only ``evaluate`` reads it, over its test logs, ``settle_named``)."""
    for option, (what, msgtype, _) in _TOPICS.items():
        if option == "link_topic" or not options.names(option):
            continue
        wanted = str(getattr(options, option))
        if wanted not in topics:
            raise TopicError(
                f"{what} {wanted} is not in the log",
                source,
                f"check its spelling (the log's {msgtype} topics: {_of_type(topics, msgtype)}), "
                "or leave it out",
                option=option,
            )


def _unmatched_joints(options: LogOptions, names: set[str]) -> list[tuple[str, str]]:
    """The named joint renamings (``joint_map:OLD`` entries, the ``joint_prefix``) that match
    none of ``names``: (option, how it reads)."""
    out = [
        (f"joint_map:{old}", f"joint map entry {old}={new}")
        for old, new in (options.joint_map or {}).items()
        if options.names(f"joint_map:{old}") and old not in names
    ]
    prefix = options.joint_prefix
    if options.names("joint_prefix") and not any(n.startswith(prefix) for n in names):
        out.append(("joint_prefix", f"joint prefix {prefix}"))
    return out


def require_named_joints(options: LogOptions, joints: Iterable[str], source: str) -> None:
    """A ``UsageError`` when a named joint-map entry, or the named joint prefix, matches none
    of the log's ``joints``."""
    names = set(joints)
    missing = _unmatched_joints(options, names)
    if missing:
        option = missing[0][0].partition(":")[0]
        raise UsageError(
            f"{', '.join(what for _, what in missing)} matches no joint of the log",
            f"{source}: log joints {', '.join(sorted(names)[:10])}",
            "check its spelling, or leave it out",
            option=option,
        )


@dataclass
class _Found:
    """What one log offers the named options: its topics and (when asked) its joint names."""

    topics: dict[str, str]
    joints: set[str] = field(default_factory=set)


def _look(path: Path, options: LogOptions, joints: bool) -> _Found:
    # the leaf modules: twincd.io.stream's sample stream checks named options through this one
    from twincd.io.stream.batch import JointStateBatch
    from twincd.io.stream.topics import TopicReader

    with TopicReader(path, strict=False) as reader:
        found = _Found(dict(reader.topics))
        if not joints:
            return found
        states = [t for t, m in found.topics.items() if m == JOINT_STATE]
        wanted = [options.topic] if options.topic in states else states
        if options.sim_topic in states:
            wanted.append(options.sim_topic)
        seen = 0
        for _, batch in reader.batches(wanted):
            if isinstance(batch, JointStateBatch):
                found.joints.update(batch.names)
                seen += len(batch)
                if seen >= HEAD_MESSAGES * len(wanted):
                    break
    return found


def settle_named(
    paths: Sequence[Path], options: LogOptions, topics: Sequence[str] | None = None
) -> LogOptions:
    """The options to read ``paths`` (one run's logs) with: a named option that matches none
    of them is a ``TopicError`` or ``UsageError``; one that some lack is said in one warning
    and no longer counted as named (those logs are read as if it had not been given).
    ``topics``: the topic options to check (None: every one, the link topic too).

    Logs that cannot be opened are left to their own run to report."""
    checks = [o for o in _TOPICS if options.names(o) and (topics is None or o in topics)]
    renaming = ("joint_map:", "joint_prefix")
    renamings = [] if topics is not None else [o for o in options.named if o.startswith(renaming)]
    if not checks and not renamings:
        return options
    found: dict[Path, _Found] = {}
    for path in paths:
        try:
            found[Path(path)] = _look(Path(path), options, bool(renamings))
        except TwincdError:
            continue
    if not found:
        return options
    relaxed: list[str] = []
    for option in checks:
        what, msgtype, instead = _TOPICS[option]
        wanted = str(getattr(options, option))
        lacking = [p for p, f in found.items() if wanted not in f.topics]
        if len(lacking) == len(found):
            everywhere: dict[str, str] = {}
            for f in found.values():
                everywhere.update(f.topics)
            raise TopicError(
                f"{what} {wanted} is in none of the logs",
                _where(list(found)),
                f"check its spelling (their {msgtype} topics: {_of_type(everywhere, msgtype)}), "
                "or leave it out",
                option=option,
            )
        if lacking:
            log.warning(
                "%s %s is not in %d of the %d logs (%s); %s",
                what,
                wanted,
                len(lacking),
                len(found),
                _names(lacking),
                instead,
            )
            relaxed.append(option)
    unmatched = {p: dict(_unmatched_joints(options, f.joints)) for p, f in found.items()}
    for option in sorted(renamings):
        lacking = [p for p in found if option in unmatched[p]]
        what = unmatched[lacking[0]][option] if lacking else option
        if len(lacking) == len(found):
            joints: set[str] = set()
            for f in found.values():
                joints |= f.joints
            raise UsageError(
                f"{what} matches no joint of the logs",
                f"{_where(list(found))}: log joints {', '.join(sorted(joints)[:10])}",
                "check its spelling, or leave it out",
                option=option.partition(":")[0],
            )
        if lacking:
            log.warning(
                "%s matches no joint of %d of the %d logs (%s)",
                what,
                len(lacking),
                len(found),
                _names(lacking),
            )
            relaxed.append(option)
    return options.unnamed(*relaxed)


def _names(paths: Sequence[Path]) -> str:
    return ", ".join(str(p) for p in paths[:4]) + (", …" if len(paths) > 4 else "")


def _where(paths: Sequence[Path]) -> str:
    return str(paths[0]) if len(paths) == 1 else f"{len(paths)} logs: {_names(paths)}"
