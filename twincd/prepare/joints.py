"""The order of a log's joints: the robot model's, then any it lacks in natural order
(``joint_order``), never the order of a log's messages; and the joints a run's logs agree on
(``agreed_joints``), so every log of a robot, read in any order and on any worker, gives the
same columns.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, Protocol

from twincd.errors import JointMismatchError

if TYPE_CHECKING:
    from twincd.twin.robot import RobotModel


def _natural_key(name: str) -> list[Any]:
    """``joint2`` before ``joint10``."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def joint_order(names: Iterable[str], robot: RobotModel | None) -> tuple[str, ...]:
    """The order of a log's joints: the robot model's, then any the model lacks by name
    (natural order) — never the order of a log's messages, so every log of a robot, read in
    any order and on any worker, gives the same columns."""
    names = list(names)
    first = [n for n in robot.joint_names if n in names] if robot is not None else []
    return (*first, *sorted((n for n in names if n not in first), key=_natural_key))


class HasJoints(Protocol):
    """What ``agreed_joints`` reads of a log (a ``PreparedLog``, a ``PreparedStream``)."""

    @property
    def source(self) -> str: ...
    @property
    def joint_names(self) -> tuple[str, ...]: ...


def agreed_joints(logs: Iterable[HasJoints]) -> tuple[str, ...]:
    """The joints (in order) every log has; logs with other joints are an error. The order
    comes from the robot model or the calibration, so it does not depend on which log came
    first."""
    by_source = sorted(logs, key=lambda lg: lg.source)
    orders = sorted({lg.joint_names for lg in by_source})
    if len(orders) > 1:
        odd = next(lg for lg in by_source if lg.joint_names != orders[0])
        raise JointMismatchError(
            "logs with different joints cannot be used together",
            f"{odd.source}: {', '.join(odd.joint_names)} vs {', '.join(orders[0])}",
            "give logs of one robot, or a joint map",
            option="joint_map",
        )
    return orders[0] if orders else ()
