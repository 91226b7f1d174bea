"""The momentum observer against physics, and the naive baselines.

Logs are built from arrays: a smooth analytic trajectory (builders.trajectory), the motor torque
from the nominal model's inverse dynamics minus a known external torque, so the observer's
exact answer is known. The helpers here are shared by the other baseline test modules.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import pytest
from support.builders import trajectory

from twincd.evaluation.baselines.mob import NaiveMob, check_mob, mob_tau_ext, momentum_observer
from twincd.evaluation.methods import MethodSkipped, make_method
from twincd.io.logs import JointStates
from twincd.prepare.prepared import PreparedLog
from twincd.signal.filters import LowPass
from twincd.twin.dynamics import inverse_dynamics
from twincd.twin.robot import RobotModel, load_robot

T0_NS = 1_700_000_000_000_000_000


@lru_cache(maxsize=1)
def xarm() -> RobotModel:
    return load_robot("xarm7")


def motor_torque(
    robot: RobotModel, t_s: np.ndarray, tau_ext: np.ndarray, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, τ_m) with M q̈ + C q̇ + g = τ_m + τ_ext exactly."""
    q, qd, qdd = trajectory(t_s, robot.dof, seed)
    return q, qd, inverse_dynamics(robot, q, qd, qdd) - tau_ext


def make_log(
    t_s: np.ndarray,
    position: np.ndarray,
    velocity: np.ndarray,
    effort: np.ndarray,
    labels: np.ndarray | None = None,
    robot: RobotModel | None = None,
    names: Sequence[str] | None = None,
    source: str = "synthetic",
) -> PreparedLog:
    """A PreparedLog straight from arrays (efforts filtered with the default low-pass)."""
    names = tuple(names or (robot or xarm()).joint_names)
    stamp = T0_NS + np.round(t_s * 1e9).astype(np.int64)
    states = JointStates(
        source=source,
        topic="/joint_states",
        joint_names=names,
        stamp_ns=stamp,
        log_time_ns=stamp,
        position=position,
        velocity=velocity,
        effort=effort,
        labels=labels,
    )
    lp = LowPass()
    return PreparedLog(
        states=states,
        sim_effort=effort.copy(),
        effort_f=lp.apply(states.t_s, effort),
        sim_effort_f=lp.apply(states.t_s, effort),
        robot=robot,
        simulated=False,
    )


def at_rest_at_ends(
    t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, ramp: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The motion scaled by a smooth envelope e(t) that is 0 at both ends (a robot at rest when
    the log starts and stops, as real logs are): e q with its exact derivatives."""
    end = t[-1]
    x = np.clip(np.minimum(t, end - t) / ramp, 0.0, 1.0)
    sign = np.where(t < end / 2, 1.0, -1.0) / ramp
    e = x**3 * (10 - 15 * x + 6 * x**2)  # quintic smoothstep: q̈ stays continuous
    de = 30 * x**2 * (1 - x) ** 2 * sign
    dde = 60 * x * (1 - x) * (1 - 2 * x) * sign**2
    e, de, dde = e[:, None], de[:, None], dde[:, None]
    return e * q, de * q + e * qd, dde * q + 2 * de * qd + e * qdd


def pushed_log(
    seed: int, seconds: float = 12.0, pushes: int = 0, noise: float = 0.02
) -> PreparedLog:
    """A 100 Hz log of the nominal xArm 7 with Coulomb-like friction (a model error the
    observer sees) and ``pushes`` smooth external-torque pulses of 1 s, labelled."""
    robot = xarm()
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * 100)) * 0.01
    labels = np.zeros(len(t), dtype=bool)
    tau_ext = np.zeros((len(t), robot.dof))
    slots = np.linspace(1.0, seconds - 1.0, pushes + 1)
    for k in range(pushes):
        start = rng.uniform(slots[k], slots[k + 1] - 1.0)
        inside = (t >= start) & (t < start + 1.0)
        shape = np.sin(np.pi * (t[inside] - start)) ** 2
        direction = rng.normal(size=robot.dof) * np.array([4, 4, 3, 3, 1.5, 1, 0.3])
        tau_ext[inside] = shape[:, None] * direction[None]
        labels |= inside
    q, qd, qdd = at_rest_at_ends(t, *trajectory(t, robot.dof, seed))
    tau_m = inverse_dynamics(robot, q, qd, qdd) - tau_ext
    tau_m = tau_m + 0.3 * np.tanh(qd / 0.05) + rng.normal(0, noise, tau_m.shape)
    return make_log(t, q, qd, tau_m, labels, robot, source=f"pushed_{seed}")


# ------------------------------------------------------------------ the observer, physics


def test_no_push_gives_near_zero() -> None:
    robot = xarm()
    t = np.arange(1500) * 0.01
    q, qd, tau_m = motor_torque(robot, t, np.zeros((len(t), robot.dof)))
    tau = momentum_observer(robot, t, q, qd, tau_m)
    assert tau.shape == (len(t), robot.dof)
    assert np.abs(tau).max() < 0.02  # N·m; trapezoidal error only


@pytest.mark.parametrize("gain", [100.0, 20.0])
@pytest.mark.parametrize("irregular", [False, True])
def test_constant_push_first_order_response(gain: float, irregular: bool) -> None:
    robot = xarm()
    rng = np.random.default_rng(3)
    if irregular:
        dt = rng.uniform(0.004, 0.016, 1499)  # jitter
        dt[700] = 0.12  # and a dropout
        t = np.concatenate([[0.0], np.cumsum(dt)])
    else:
        t = np.arange(1500) * 0.01
    on = 400
    t_on = t[on]
    tau_c = np.array([2.0, -3.0, 1.5, -1.0, 0.5, 0.8, -0.2])
    tau_ext = np.where((t >= t_on)[:, None], tau_c[None], 0.0)
    q, qd, tau_m = motor_torque(robot, t, tau_ext, seed=1)
    tau = momentum_observer(robot, t, q, qd, tau_m, gain=gain)
    # the trapezoid sees the step as a ramp over the sample interval before t_on: half of it
    # enters there; from t_on on, the estimate follows ṙ = K (τ_ext − r) exactly
    h_on = t[on] - t[on - 1]
    r_on = 0.5 * tau_c * (1.0 - np.exp(-gain * h_on))
    s = t[on:] - t_on
    decay = np.exp(-gain * s)[:, None]
    expected = tau_c[None] * (1.0 - decay) + r_on[None] * decay
    assert np.abs(tau[: on - 1]).max() < 0.02
    assert np.abs(tau[on:] - expected).max() < 0.005 * np.abs(tau_c).max() + 0.02
    # after five time constants (1/K) the push is recovered to within 1 %
    k = int(np.searchsorted(t, t_on + 5.0 / gain))
    np.testing.assert_allclose(tau[k], tau_c, atol=0.01 * np.abs(tau_c).max() + 0.02)


def test_duplicate_stamps_leave_estimate_unchanged() -> None:
    robot = xarm()
    t = np.arange(300) * 0.01
    t[150] = t[149]  # duplicate stamp
    tau_c = np.full(robot.dof, 0.5)
    q, qd, tau_m = motor_torque(robot, t, np.tile(tau_c, (len(t), 1)))
    tau = momentum_observer(robot, t, q, qd, tau_m)
    assert np.isfinite(tau).all()
    np.testing.assert_array_equal(tau[150], tau[149])
    np.testing.assert_allclose(tau[-1], tau_c, atol=0.02)


# ------------------------------------------------------------------ method plumbing


def test_log_column_order_does_not_matter() -> None:
    log = pushed_log(0, seconds=4.0, pushes=1)
    perm = [6, 2, 0, 5, 1, 4, 3]
    names = [log.joint_names[i] for i in perm]
    shuffled = make_log(
        log.states.t_s,
        log.states.position[:, perm],
        log.states.velocity[:, perm],
        log.effort[:, perm],
        log.labels,
        log.robot,
        names=names,
    )
    a = mob_tau_ext(log)
    b = mob_tau_ext(shuffled)
    np.testing.assert_allclose(b, a[:, perm], atol=1e-9)
    np.testing.assert_allclose(NaiveMob().score(shuffled), NaiveMob().score(log), atol=1e-9)


def test_skipped_without_matching_robot() -> None:
    log = pushed_log(0, seconds=2.0)
    no_robot = make_log(
        log.states.t_s, log.states.position, log.states.velocity, log.effort, robot=None
    )
    with pytest.raises(MethodSkipped, match="robot model"):
        check_mob([log, no_robot])
    other = make_log(
        log.states.t_s,
        log.states.position,
        log.states.velocity,
        log.effort,
        robot=log.robot,
        names=[f"j{i}" for i in range(7)],
    )
    with pytest.raises(MethodSkipped, match="joints"):
        make_method("naive-mob").check([other])
    make_method("naive-mob").check([log])  # fine


def test_naive_mob_scores_pushes_higher() -> None:
    log = pushed_log(1, seconds=12.0, pushes=3)
    method = make_method("naive-mob")
    assert isinstance(method, NaiveMob) and not method.learns
    score = method.fit([]).score(log)
    assert score.shape == (len(log),)
    assert log.labels is not None
    assert np.median(score[log.labels]) > 5 * np.median(score[~log.labels])


def test_naive_diff_is_affine_score_with_unit_gain() -> None:
    log = pushed_log(2, seconds=3.0)
    shifted = make_log(
        log.states.t_s, log.states.position, log.states.velocity, log.effort, robot=log.robot
    )
    method = make_method("naive-diff")
    assert not method.learns
    object.__setattr__(shifted, "sim_effort_f", shifted.sim_effort_f + 0.5)
    score = method.fit([]).score(shifted)
    np.testing.assert_allclose(score, 0.25 * 7)


def test_all_seven_registered_lazily() -> None:
    import subprocess
    import sys

    code = (
        "import sys, twincd.evaluation.methods as m; names = m.available(); "
        "assert all(n in names for n in ('naive-diff','naive-mob','point-ocsvm','point-ae',"
        "'lstm-mob','window-ocsvm','window-ae')), names; "
        "assert 'torch' not in sys.modules and 'sklearn' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_observer_output_is_filtered_like_the_logs_efforts() -> None:
    import dataclasses

    from twincd.signal.filters import LowPass

    log = pushed_log(3, seconds=2.0)
    sharp = dataclasses.replace(log, lowpass=LowPass(cutoff_hz=5.0))
    np.testing.assert_array_equal(mob_tau_ext(sharp), mob_tau_ext(log, lowpass=LowPass(5.0)))
    assert not np.allclose(mob_tau_ext(sharp), mob_tau_ext(log))
