"""What a sample stream reads (``twincd.io.stream.samples``): its joint-state topic, its joints
among the message layouts read ahead, and each stream joint's column in a layout."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from twincd.errors import JointMismatchError, SplitJointsError, TopicError
from twincd.io.cdr import DYNAMIC_JOINT_STATE, JOINT_STATE

log = logging.getLogger("twincd")

OWN_PREFIX = "/twincd/"  # twincd's own channels: never taken for the robot's joint states
DYNAMIC_TOPIC = "/dynamic_joint_states"  # ros2_control's joint_state_broadcaster publishes here


def warn_ignored_joints(source: str, names: Sequence[str], used: Sequence[str], what: str) -> None:
    """One warning naming the log joints (``names``) that are not ``used``."""
    ignored = [n for n in names if n not in used]
    if ignored:
        log.warning(
            "%s: ignoring %d log joint(s) not in %s: %s",
            source,
            len(ignored),
            what,
            ", ".join(ignored),
        )


def choose_topic(topics: Mapping[str, str], wanted: str, source: str) -> str:
    """The JointState topic to read (contract: Inputs: fall back to the only JointState topic,
    or, without any, to the only DynamicJointState topic)."""
    if wanted in topics:
        if topics[wanted] not in (JOINT_STATE, DYNAMIC_JOINT_STATE):
            raise TopicError(
                f"topic {wanted} is {topics[wanted]}, not {JOINT_STATE}",
                source,
                "pick a JointState topic with the topic option",
            )
        return wanted
    candidates = sorted(
        t for t, m in topics.items() if m == JOINT_STATE and not t.startswith(OWN_PREFIX)
    ) or sorted(t for t, m in topics.items() if m == DYNAMIC_JOINT_STATE)
    if len(candidates) == 1:
        log.warning(
            "topic %s not in %s; using its only JointState topic %s", wanted, source, candidates[0]
        )
        return candidates[0]
    if not candidates:
        raise TopicError(
            f"no {JOINT_STATE} topic (wanted {wanted})",
            source,
            "record joint states or pick another topic with the topic option",
        )
    raise TopicError(
        f"topic {wanted} not found and several JointState topics exist: {', '.join(candidates)}",
        source,
        "pick one with the topic option",
    )


def choose_joints(
    layouts: dict[tuple[str, ...], int],
    known: tuple[str, ...],
    exact: bool,
    known_from: str,
    source: str,
    topic: str,
) -> tuple[str, ...]:
    """The stream's joints from the layouts read ahead (their joint names after the joint map,
    each with its message count): see ``LogStream``. ``known``: the joints wanted, exactly
    those when ``exact``; ``known_from``: what named them."""
    where = f"{source}, {topic}"
    wanted = set(known)
    relevant = {k: c for k, c in layouts.items() if wanted & set(k)}
    if not relevant:
        calibrated = known_from == "the calibration"
        raise JointMismatchError(
            f"the log lacks calibrated joint(s) {', '.join(known)}"
            if calibrated
            else f"no joint of the log is in {known_from}",
            f"{where}: log joints {', '.join(sorted({n for k in layouts for n in k})[:8])}; "
            f"wanted {', '.join(known[:8])}",
            "check the robot model, the topic and the joint map",
            option="robot,topic,joint_map",
        )
    best = max(relevant, key=lambda k: (len(wanted & set(k)), relevant[k]))
    covered = wanted & set(best)
    split = [k for k in relevant if (wanted & set(k)) - covered]
    if split:
        parts = " | ".join(", ".join(n for n in k if n in wanted) for k in (best, *split))
        raise SplitJointsError(
            "the arm's joints arrive split over several messages per sample "
            f"({parts}); twincd does not join them",
            where,
            "record the arm's joints in one JointState message (one publisher), or pick a "
            "topic that carries them all with the topic option",
        )
    warn_ignored_joints(source, best, tuple(wanted), known_from)
    if exact:
        missing = [j for j in known if j not in covered]
        if missing:
            raise JointMismatchError(
                f"joints {', '.join(missing)} are not in the log",
                where,
                "check the robot model, the topic and the joint map",
            )
        return known
    return tuple(n for n in best if n in wanted)


class Columns:
    """Per stream joint, its column in the messages of a layout (a call per layout's names;
    remembered)."""

    def __init__(self, joint_names: Sequence[str], rename: Callable[[str], str], where: str):
        self.joint_names = tuple(joint_names)
        self._rename = rename  # log joint names → the model's
        self._where = where  # the log and topic, for messages
        self._known: dict[tuple[str, ...], NDArray[np.intp]] = {}

    def __call__(self, names: tuple[str, ...]) -> NDArray[np.intp]:
        """Per stream joint, its column in messages named ``names`` (-1: absent; a name given
        twice: its first column)."""
        cols = self._known.get(names)
        if cols is None:
            where: dict[str, int] = {}
            for i, n in enumerate(names):
                mapped = self._rename(n)
                if mapped in where and names[where[mapped]] != n:
                    clash = names[where[mapped]]
                    raise JointMismatchError(
                        f"after the joint map, log joints {clash} and {n} are both {mapped}",
                        self._where,
                        "map every log joint to a name of its own",
                        option="joint_map",
                    )
                where.setdefault(mapped, i)
            cols = np.array([where.get(j, -1) for j in self.joint_names], dtype=np.intp)
            self._known[names] = cols
        return cols
