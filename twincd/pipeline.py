"""From a log on disk to the arrays every method works on: read, twin (or the log's own
``/twincd/sim_effort``), low-pass filter. Pure per-log work; nothing is shared between logs but
the read-only robot model cache.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from twincd.errors import DataError, JointMismatchError
from twincd.io.logs import JointStates, LogOptions, read_log
from twincd.signal.filters import LowPass
from twincd.twin.dynamics import Differentiator, simulate_effort
from twincd.twin.robot import RobotModel, load_robot

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class PreparedLog:
    """One log ready for scoring: raw and filtered efforts in ``joint_names`` order.

    ``effort_f`` is the paper's τ̃ and ``sim_effort_f`` its τ̂̃. ``robot`` is None when the
    twin's effort came from the log itself and no model was asked for.
    """

    states: JointStates  # restricted to joint_names
    sim_effort: FloatArray
    effort_f: FloatArray
    sim_effort_f: FloatArray
    robot: RobotModel | None
    simulated: bool  # False: the log carried /twincd/sim_effort
    # the filter behind effort_f: methods that filter other inputs do it alike
    lowpass: LowPass = field(default_factory=LowPass)

    @property
    def source(self) -> str:
        return self.states.source

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.states.joint_names

    @property
    def labels(self) -> BoolArray | None:
        return self.states.labels

    @property
    def effort(self) -> FloatArray:
        assert self.states.effort is not None  # prepare() refuses logs without effort
        return self.states.effort

    def __len__(self) -> int:
        return len(self.states)


@lru_cache(maxsize=32)
def robot_for(robot: str, joints: tuple[str, ...]) -> RobotModel:
    """The robot model reduced to ``joints`` (cached: loading a URDF costs milliseconds)."""
    return load_robot(robot, keep=joints)


def twin_effort(
    states: JointStates,
    robot: str | None,
    differentiator: Differentiator | None = None,
    force_simulate: bool = False,
    fallback_robot: str | None = None,
) -> tuple[JointStates, FloatArray, RobotModel | None, bool]:
    """(states in twin joint order, τ̂, robot or None, simulated?) for one log.

    Uses the log's ``/twincd/sim_effort`` when present (unless ``force_simulate``), else
    simulates with ``robot`` (or ``fallback_robot`` when no robot was asked for: a default
    model is only needed, and only loaded, for logs without a simulated effort).
    """
    if states.sim_effort is not None and not force_simulate:
        have: BoolArray = np.asarray(np.isfinite(states.sim_effort).all(axis=0))
        names = tuple(n for n, ok in zip(states.joint_names, have.tolist(), strict=True) if ok)
        if names:
            sel = states.select(names)
            model = robot_for(robot, names) if robot else None
            assert sel.sim_effort is not None
            return sel, sel.sim_effort, model, False
    robot = robot or fallback_robot
    if robot is None:
        raise JointMismatchError(
            "the log has no simulated effort and no robot model was given",
            states.source,
            "pass --robot or run `twincd simulate` first",
        )
    model = robot_for(robot, states.joint_names)
    sel = states.select(model.joint_names)
    return sel, simulate_effort(model, sel, differentiator), model, True


def prepare(
    path: str | Path,
    options: LogOptions,
    robot: str | None,
    lowpass: LowPass,
    joint_names: Sequence[str] | None = None,
    fallback_robot: str | None = None,
) -> PreparedLog:
    """Read, twin and filter one log; ``joint_names`` pins the column order (a calibration's).

    ``fallback_robot`` simulates logs without ``/twincd/sim_effort`` when ``robot`` is None.
    """
    states = read_log(path, options)
    if states.effort is None:
        raise DataError(
            "the log has no measured effort",
            f"{states.source}, {states.topic}",
            "record JointState.effort; twincd compares it with the twin",
        )
    sel, sim, model, simulated = twin_effort(states, robot, fallback_robot=fallback_robot)
    if joint_names is not None:
        missing = [n for n in joint_names if n not in sel.joint_names]
        if missing:
            raise JointMismatchError(
                f"the log lacks calibrated joint(s) {', '.join(missing)}",
                states.source,
                "use a calibration made for this robot, or --joint-map",
            )
        cols = [sel.joint_names.index(n) for n in joint_names]
        sel = sel.select(joint_names)
        sim = sim[:, cols]
    assert sel.effort is not None
    t_s = sel.t_s
    return PreparedLog(
        states=sel,
        sim_effort=sim,
        effort_f=lowpass.apply(t_s, sel.effort, sel.source),
        sim_effort_f=lowpass.apply(t_s, sim, sel.source),
        robot=model,
        simulated=simulated,
        lowpass=lowpass,
    )
