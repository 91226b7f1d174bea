"""The twin against physics identities (Pinocchio's own functions and a closed form)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from support.builders import trajectory

from twincd.io.logs import JointStates
from twincd.signal.derivatives import differentiate
from twincd.signal.filters import LowPass
from twincd.twin.dynamics import Differentiator, gravity, inverse_dynamics, simulate_effort
from twincd.twin.robot import load_robot

TWO_LINK = """<robot name="two_link">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="10"/></joint>
  <link name="l1"><inertial><origin xyz="{lc1} 0 0"/><mass value="{m1}"/>
    <inertia ixx="0.01" iyy="{i1}" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="{l1} 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="100" velocity="10"/></joint>
  <link name="l2"><inertial><origin xyz="{lc2} 0 0"/><mass value="{m2}"/>
    <inertia ixx="0.01" iyy="{i2}" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
</robot>
"""


def states_from(t_s, q, qd, effort=None) -> JointStates:
    stamp = (t_s * 1e9).round().astype(np.int64)
    names = tuple(f"joint{i + 1}" for i in range(q.shape[1]))
    return JointStates("test", "/joint_states", names, stamp, stamp, q, qd, effort)


def test_static_twin_equals_generalized_gravity():
    robot = load_robot("xarm7")
    q, _, _ = trajectory(np.linspace(0, 5, 50))
    zeros = np.zeros_like(q)
    expected = np.array(
        [pin.computeGeneralizedGravity(robot.model, robot.model.createData(), qi) for qi in q]
    )
    np.testing.assert_allclose(inverse_dynamics(robot, q, zeros, zeros), expected, atol=1e-12)
    np.testing.assert_allclose(gravity(robot, q), expected, atol=1e-12)


def test_two_link_arm_matches_the_closed_form(tmp_path):
    p = {"m1": 2.0, "m2": 1.5, "l1": 0.5, "lc1": 0.25, "lc2": 0.2, "i1": 0.05, "i2": 0.03}
    urdf = tmp_path / "two_link.urdf"
    urdf.write_text(TWO_LINK.format(**p))
    robot = load_robot(str(urdf))
    assert robot.joint_names == ("j1", "j2")
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-2, 2, (20, 2)) for _ in range(3))
    m1, m2, l1, lc1, lc2, i1, i2 = (p[k] for k in ("m1", "m2", "l1", "lc1", "lc2", "i1", "i2"))
    g = 9.81
    c2, q12 = np.cos(q[:, 1]), q[:, 0] + q[:, 1]
    m11 = i1 + i2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2)
    m12 = i2 + m2 * (lc2**2 + l1 * lc2 * c2)
    m22 = i2 + m2 * lc2**2
    h = -m2 * l1 * lc2 * np.sin(q[:, 1])
    # rotation about +y lowers the arm for positive angles: z = -sin(angle)
    g1 = -(m1 * lc1 + m2 * l1) * g * np.cos(q[:, 0]) - m2 * lc2 * g * np.cos(q12)
    g2 = -m2 * lc2 * g * np.cos(q12)
    tau1 = m11 * qdd[:, 0] + m12 * qdd[:, 1] + h * (2 * qd[:, 0] * qd[:, 1] + qd[:, 1] ** 2) + g1
    tau2 = m12 * qdd[:, 0] + m22 * qdd[:, 1] - h * qd[:, 0] ** 2 + g2
    np.testing.assert_allclose(
        inverse_dynamics(robot, q, qd, qdd), np.c_[tau1, tau2], rtol=1e-9, atol=1e-9
    )


def test_twin_reproduces_a_nominal_log_within_one_percent():
    robot = load_robot("xarm7")
    t = np.arange(0, 20, 0.01)
    q, qd, qdd = trajectory(t, seed=3)
    effort = inverse_dynamics(robot, q, qd, qdd)  # exact q̈: the log's "measured" effort
    tau_hat = simulate_effort(robot, states_from(t, q, qd, effort))
    lp = LowPass()
    err = np.abs(lp.apply(t, tau_hat) - lp.apply(t, effort)).max(axis=0)
    span = np.ptp(effort, axis=0)
    assert np.all(err < 0.01 * span), err / span


def test_jitter_and_gaps_do_not_make_spikes():
    rng = np.random.default_rng(4)
    period = 0.01
    t = np.cumsum(period * (1 + rng.uniform(-0.15, 0.15, 3000)))
    t = np.where(t > 12.0, t + 0.5, t)  # a half-second dropout
    t -= t[0]
    _, qd, qdd = trajectory(t, seed=5)
    est = Differentiator()(t, qd)
    # away from the gap edges the estimate is exact up to the polynomial's truncation
    assert np.abs(est - qdd).max() < 0.05 * np.abs(qdd).max()


def test_differentiator_is_exact_for_cubics_on_irregular_times():
    rng = np.random.default_rng(6)
    t = np.cumsum(rng.uniform(0.005, 0.015, 200))
    y = 1 + 2 * t - 3 * t**2 + 0.5 * t**3
    np.testing.assert_allclose(differentiate(t, y), 2 - 6 * t + 1.5 * t**2, atol=1e-8)


def test_differentiator_rejects_a_degenerate_window():
    with pytest.raises(ValueError):
        differentiate(np.arange(5.0), np.arange(5.0), window=1)


def test_batched_rnea_equals_a_loop_of_pinocchio_rnea() -> None:
    import pinocchio as pin

    robot = load_robot("xarm7")
    rng = np.random.default_rng(3)
    q, qd, qdd = (rng.uniform(-1, 1, (257, robot.dof)) for _ in range(3))
    data = robot.model.createData()
    loop = np.array([pin.rnea(robot.model, data, *row) for row in zip(q, qd, qdd)])
    for threads in (1, 2):
        np.testing.assert_array_equal(inverse_dynamics(robot, q, qd, qdd, threads), loop)
