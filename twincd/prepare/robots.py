"""The robot models the chain twins with: the joints a model drives, the model reduced to a
log's joints (cached), the default model's refusal of another arm's log, the check that a
calibration's twin runs on the dynamics it was fitted with, and the bound on absurd samples
from a model's limits (``twincd.signal.bounds``).

Batch (``twincd.prepare.stream``), live (``twincd.detection.OnlineDetector``) and ``inspect``
take their robot models from here, so each judges a log's robot alike.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from functools import lru_cache
from typing import TYPE_CHECKING

from twincd.errors import CalibrationError, UsageError

if TYPE_CHECKING:
    from twincd.signal.bounds import SampleBounds
    from twincd.twin.robot import RobotModel

log = logging.getLogger("twincd")


@lru_cache(maxsize=32)
def model_joints(robot: str) -> tuple[str, ...]:
    """The joints a robot model drives (a gripper's are not the twin's)."""
    from twincd.twin.robot import load_robot

    return load_robot(robot).joint_names


def require_default_robot(joints: Sequence[str], source: str) -> None:
    """The default robot model stands in for a robot nobody named only on a log of its joints
    (extra joints, a gripper's, are ignored as for any model): a log that lacks one of them is
    another arm, and a reduced model is for a robot the user named (contract: Robot models).
    A ``UsageError`` that says to name it."""
    from twincd.defaults import DEFAULT_ROBOT

    model = model_joints(DEFAULT_ROBOT)
    missing = [j for j in model if j not in joints]
    if missing:
        shown = ", ".join(list(joints)[:10]) or "none"
        raise UsageError(
            f"no robot model was given and the log's joints are not those of the default "
            f"{DEFAULT_ROBOT} (it lacks {', '.join(missing)})",
            f"{source}: log joints {shown}",
            "name the robot the log was recorded on (an example-robot-data name or a URDF)",
            option="robot",
        )


def robot_for(robot: str, joints: tuple[str, ...]) -> RobotModel:
    """The robot model reduced to ``joints`` (cached: loading a URDF costs milliseconds; a
    URDF edited since is loaded again)."""
    from twincd.twin.robot import file_version, resolve_urdf

    return _robot_for(robot, joints, file_version(resolve_urdf(robot)))


@lru_cache(maxsize=32)
def _robot_for(robot: str, joints: tuple[str, ...], version: tuple[int, int]) -> RobotModel:
    from twincd.twin.robot import load_robot

    return load_robot(robot, keep=joints)


def sample_bounds(
    robot: RobotModel | None, joints: Sequence[str], drives_off: bool = True
) -> SampleBounds:
    """The causal bound on a stream's absurd samples (``twincd.signal.bounds``) from the robot
    model's limits (none without a model), and its samples with the drives off (unless not
    ``drives_off``: a command that compares no effort): the one rule batch, causal, live and
    ``inspect`` apply."""
    from twincd.signal.bounds import SampleBounds

    if robot is None:
        return SampleBounds(joints, {}, drives_off=drives_off)
    return SampleBounds(
        joints,
        robot.position_limits,
        robot.velocity_limits,
        robot.effort_limits,
        drives_off=drives_off,
    )


def check_robot(
    robot: RobotModel,
    dynamics: str | None,
    urdf_sha256: str | None,
    allow: bool,
    source: str,
) -> None:
    """The robot model a calibration's twin runs on must be the one it was fitted with, judged
    by content: its dynamics (``dynamics``: ``RobotModel.dynamics_sha256``), whatever the
    URDF's path or the rest of the file. A calibration that records only the URDF file's
    sha256 (``urdf_sha256``: written before twincd hashed the dynamics) is checked by the
    file's bytes; one that records neither (fitted on a log's own twin effort) is not checked.
    A difference is refused, or with ``allow`` said once for the log."""
    if dynamics:
        if robot.dynamics_sha256 == dynamics:
            return
        what = (
            f"the robot model {robot.name} has other dynamics than the calibration was fitted "
            f"with (dynamics sha256 {robot.dynamics_sha256[:12]}…, the calibration's "
            f"{dynamics[:12]}…: another URDF, or one whose joints, inertias, kinematics or "
            "limits changed)"
        )
    elif urdf_sha256 and robot.urdf_sha256 != urdf_sha256:
        what = (
            f"the URDF {robot.urdf_path} changed since the calibration was fitted "
            f"(sha256 {robot.urdf_sha256[:12]}…, the calibration's {urdf_sha256[:12]}…)"
        )
    else:
        return
    if allow:
        log.warning("%s: %s; using it as allowed", source, what)
        return
    raise CalibrationError(
        what,
        source,
        "give the robot's URDF the calibration was fitted with, re-fit the calibration, or "
        "allow the change if it does not affect dynamics",
        option="robot,allow_urdf_change",
    )
