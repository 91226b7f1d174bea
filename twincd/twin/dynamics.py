"""The digital twin: the effort each joint should need for the logged motion.

τ̂ = M(q) q̈ + C(q, q̇) q̇ + g(q), computed by Pinocchio's RNEA over a whole block of samples at
once (``rneaInParallel``: C++ threads, the GIL released). q̈ comes from the logged velocity
through the real-time Savitzky–Golay differentiator (twincd.signal.derivatives), which restarts
across gaps, so jitter and dropouts do not become effort spikes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from twincd.io.logs import JointStates
from twincd.signal.derivatives import (
    DEFAULT_GAP_FACTOR,
    DEFAULT_POLYORDER,
    DEFAULT_WINDOW,
    differentiate,
)
from twincd.twin.openmp import load_pinocchio
from twincd.twin.robot import RobotModel
from twincd.types import BoolArray, FloatArray

# whether an OpenMP team of more than one thread has run in this process: a process forked after
# that hangs at its own first parallel region, so a pool must then start its workers afresh
_team_started = False


def openmp_team_started() -> bool:
    """True once the batched RNEA has run on more than one thread in this process."""
    return _team_started


def default_threads() -> int:
    """The cores this process may use (Linux affinity, else the CPU count), or
    ``TWINCD_TWIN_THREADS`` (a worker of a process pool is given one)."""
    pinned = os.environ.get("TWINCD_TWIN_THREADS", "")
    if pinned.isdigit() and int(pinned) > 0:
        return int(pinned)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class Differentiator:
    """Settings of the acceleration estimate (samples, polynomial degree, gap threshold)."""

    window: int = DEFAULT_WINDOW
    polyorder: int = DEFAULT_POLYORDER
    gap_factor: float = DEFAULT_GAP_FACTOR

    def __call__(self, t_s: FloatArray, values: FloatArray) -> FloatArray:
        return differentiate(t_s, values, self.window, self.polyorder, self.gap_factor)


def inverse_dynamics(
    robot: RobotModel,
    position: FloatArray,
    velocity: FloatArray,
    acceleration: FloatArray,
    threads: int | None = None,
) -> FloatArray:
    """RNEA for every sample; arrays are (N, dof) in the robot's joint order.

    One ``pin.rneaInParallel`` call per block instead of a Python loop of ``pin.rnea``: on
    xArm 7 it is 2× faster on one thread and 4× on two (identical torques), and it releases
    the GIL so reading and writing can overlap with it.
    """
    pin = load_pinocchio()

    n = len(position)
    if n == 0:
        return np.zeros((0, robot.dof))
    threads = threads or default_threads()
    # Pinocchio takes one column per sample: the transpose of a C-ordered (N, dof) array is
    # that, without a copy, when q and v hold the joint values as they are
    if robot.plain_layout:
        q, v, a = (
            np.ascontiguousarray(x, dtype=np.float64).T for x in (position, velocity, acceleration)
        )
    else:
        q = np.asfortranarray(robot.configuration(position).T)
        v = np.asfortranarray(robot.velocity_vector(velocity).T)
        a = np.asfortranarray(robot.velocity_vector(acceleration).T)
    tau = np.empty((robot.model.nv, n), order="F")
    if threads > 1:
        global _team_started
        _team_started = True
    pin.rneaInParallel(threads, robot.pool(threads), q, v, a, tau)
    out: FloatArray = tau.T if robot.plain_layout else robot.joint_values(tau.T)
    return out


def gravity(robot: RobotModel, position: FloatArray) -> FloatArray:
    """g(q) per sample, from Pinocchio's computeGeneralizedGravity (an identity for tests)."""
    pin = load_pinocchio()

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


def torque_regressor(
    robot: RobotModel, position: FloatArray, velocity: FloatArray, acceleration: FloatArray
) -> FloatArray:
    """Y(q, q̇, q̈) per sample, (N, dof, 10·links): τ̂ = Y θ is linear in the links' inertial
    parameters θ (Pinocchio's ``computeJointTorqueRegressor``; θ of a link is its mass, first
    moment and inertia, ``Inertia.toDynamicParameters``), so a fit of θ to measured effort
    identifies the plant's rigid-body parameters where the URDF's are wrong.

    Pinocchio has no batched regressor: one call per sample (≈ 11 µs on xArm 7), which only the
    ``identified`` calibration models pay.
    """
    pin = load_pinocchio()

    model = robot.model
    data = model.createData()
    params = 10 * (model.njoints - 1)
    if robot.plain_layout:  # the joint values are Pinocchio's vectors as they are
        q, v, a = (
            np.ascontiguousarray(x, dtype=np.float64) for x in (position, velocity, acceleration)
        )
    else:
        q = robot.configuration(position)
        v = robot.velocity_vector(velocity)
        a = robot.velocity_vector(acceleration)
    out = np.empty((len(q), model.nv, params))
    for i in range(len(q)):
        out[i] = pin.computeJointTorqueRegressor(model, data, q[i], v[i], a[i])
    if robot.plain_layout:
        return out
    rows = [j.idx_v for j in robot.joints]
    picked: FloatArray = out[:, rows, :]
    return picked


def regressor_mask(robot: RobotModel) -> NDArray[np.bool_]:
    """(dof, 10·links): the entries of ``torque_regressor`` that are not zero by the robot's
    structure (a link's parameters never act on the joints beyond it, and some act on no
    revolute joint). Found from random states, where no structural zero is missed and a
    non-structural entry is never exactly 0; only these are filtered (half of xArm 7's)."""
    cached: NDArray[np.bool_] | None = robot.__dict__.get("_regressor_mask")
    if cached is None:
        rng = np.random.default_rng(0)
        shape = (64, robot.dof)
        y = torque_regressor(
            robot, rng.uniform(-3, 3, shape), rng.normal(size=shape), rng.normal(size=shape)
        )
        cached = np.any(y != 0.0, axis=0)
        robot.__dict__["_regressor_mask"] = cached
    return cached


def inertial_parameters(robot: RobotModel) -> FloatArray:
    """θ of the URDF, (10·links,): with ``torque_regressor``, Y θ = RNEA (an identity for tests)."""
    model = robot.model
    return np.concatenate(
        [np.asarray(model.inertias[i].toDynamicParameters()) for i in range(1, model.njoints)]
    )


def regressor_effort(y: FloatArray, theta: FloatArray, regressor_mask: BoolArray) -> FloatArray:
    """Y_j θ_j per joint, (N, D), from the masked regressor (N, kept). Summed entry by entry in
    one fixed order, not by einsum or BLAS (whose kernels change with the block's length and
    strides): each sample's sum is the same whatever the block's length (live detection pushes
    one sample at a time, a file thousands), so batch and live agree to the bit."""
    out = np.zeros((len(y), len(theta)))
    end = 0
    for j, kept in enumerate(regressor_mask):
        start, end = end, end + int(np.count_nonzero(kept))
        for column, weight in zip(range(start, end), theta[j, kept], strict=True):
            out[:, j] += y[:, column] * weight
    return out


def inertial_effort(y: FloatArray, theta: FloatArray) -> FloatArray:
    """Y_j θ_j per joint, (N, D), from the whole regressor (N, D, P) and the weights (D, P)
    (zero where the regressor is structurally zero). numpy's einsum on C-ordered arrays sums
    each row's products along its last axis in an order fixed by the row's length alone (not
    BLAS: tests/test_grid.py checks live, one sample at a time, against whole blocks), 10×
    faster than ``regressor_effort``."""
    rows = np.ascontiguousarray(y, dtype=np.float64)
    out: FloatArray = np.einsum("ndp,dp->nd", rows, np.ascontiguousarray(theta, dtype=np.float64))
    return out
