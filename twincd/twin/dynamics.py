"""The digital twin: the effort each joint should need for the logged motion.

τ̂ = M(q) q̈ + C(q, q̇) q̇ + g(q), computed by Pinocchio's RNEA per sample. q̈ comes from the
logged velocity through the real-time Savitzky–Golay differentiator (twincd.signal.derivatives),
which
restarts across gaps, so jitter and dropouts do not become effort spikes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from twincd.io.logs import JointStates
from twincd.signal.derivatives import (
    DEFAULT_GAP_FACTOR,
    DEFAULT_POLYORDER,
    DEFAULT_WINDOW,
    differentiate,
)
from twincd.twin.robot import RobotModel

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Differentiator:
    """Settings of the acceleration estimate (samples, polynomial degree, gap threshold)."""

    window: int = DEFAULT_WINDOW
    polyorder: int = DEFAULT_POLYORDER
    gap_factor: float = DEFAULT_GAP_FACTOR

    def __call__(self, t_s: FloatArray, values: FloatArray) -> FloatArray:
        return differentiate(t_s, values, self.window, self.polyorder, self.gap_factor)


def inverse_dynamics(
    robot: RobotModel, position: FloatArray, velocity: FloatArray, acceleration: FloatArray
) -> FloatArray:
    """Per-sample RNEA; arrays are (N, dof) in the robot's joint order."""
    q = robot.configuration(position)
    v = robot.velocity_vector(velocity)
    a = robot.velocity_vector(acceleration)
    model = robot.model
    data = model.createData()
    tau = np.empty((len(q), model.nv))
    rnea = pin.rnea
    for i in range(len(q)):
        tau[i] = rnea(model, data, q[i], v[i], a[i])
    return robot.joint_values(tau)


def gravity(robot: RobotModel, position: FloatArray) -> FloatArray:
    """g(q) per sample, from Pinocchio's computeGeneralizedGravity."""
    q = robot.configuration(position)
    data = robot.model.createData()
    out = np.array([pin.computeGeneralizedGravity(robot.model, data, qi) for qi in q])
    return robot.joint_values(out)


def simulate_effort(
    robot: RobotModel, states: JointStates, differentiator: Differentiator | None = None
) -> FloatArray:
    """τ̂ for every sample of ``states`` (N, robot.dof), columns in the robot's joint order."""
    differentiator = differentiator or Differentiator()
    sel = states.select(robot.joint_names)
    acceleration = differentiator(sel.t_s, sel.velocity)
    return inverse_dynamics(robot, sel.position, sel.velocity, acceleration)
