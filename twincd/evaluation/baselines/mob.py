"""The momentum observer (De Luca & Mattone 2003/2005; Haddadin et al. 2017) and the paper's
"Naive MOB" baseline (IV-B 2): score(t) = ‖τ_ext(t)‖².

With the generalized momentum p = M(q) q̇ the robot obeys ṗ = τ_m + τ_ext + C(q, q̇)ᵀ q̇ − g(q)
(using Ṁ = C + Cᵀ), so the residual

    r(t) = K (p(t) − p(0) − ∫₀ᵗ (τ_m + Cᵀ q̇ − g + r) ds)

obeys ṙ = K (τ_ext − r): a first-order low-pass estimate of τ_ext. M, C and g come from
Pinocchio (``crba``, ``computeCoriolisMatrix``, ``computeGeneralizedGravity``). As the paper
does, the measured effort stands for the motor torque τ_m, so what the observer reports is every
torque the rigid-body model does not explain (friction and model errors included).

Discretisation, exact for any step: over a step of real length h the mean of τ_ext is
y = (Δp − h · β̄) / h with β = τ_m + Cᵀ q̇ − g (trapezoidal mean), and the residual is advanced
by the exact solution of ṙ = K (y − r) for y held over the step:

    r ← e^{−K h} r + (1 − e^{−K h}) y

so a constant external torque is approached as 1 − e^{−K t} whatever the sampling, jittered or
with gaps. Steps of zero length (duplicate stamps) leave r unchanged. r(0) = 0.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from twincd.errors import DataError, NotFittedError
from twincd.evaluation.baselines.windows import (
    WINDOW_SIZE,
    MinMaxScaler,
    subsample,
    window_labels,
    window_starts,
    windows,
)
from twincd.evaluation.methods import MethodSkipped, ScoringMethod
from twincd.prepare.prepared import PreparedLog
from twincd.signal.filters import LowPass
from twincd.twin.robot import RobotModel
from twincd.types import BoolArray, FloatArray

DEFAULT_GAIN = 100.0  # paper IV-A: "we fixed the observer gain to 100.0"


def momentum_observer(
    robot: RobotModel,
    t_s: FloatArray,
    position: FloatArray,
    velocity: FloatArray,
    effort: FloatArray,
    gain: float = DEFAULT_GAIN,
) -> FloatArray:
    """τ_ext estimated by the momentum observer, (N, dof) in ``robot.joint_names`` order.

    ``position``, ``velocity`` and ``effort`` (the motor torque τ_m) are (N, dof) in the robot's
    joint order; ``t_s`` are the sample times in seconds (any spacing).
    """
    t = np.asarray(t_s, dtype=np.float64)
    n = len(t)
    if gain <= 0:
        raise ValueError("the observer gain must be > 0")
    model = robot.model
    data = model.createData()
    q = robot.configuration(np.asarray(position, dtype=np.float64))
    v = robot.velocity_vector(np.asarray(velocity, dtype=np.float64))
    tau_m = robot.velocity_vector(np.asarray(effort, dtype=np.float64))
    nv = model.nv
    mass = np.empty((n, nv, nv))
    ct_v = np.empty((n, nv))
    grav = np.empty((n, nv))
    crba, coriolis, gravity = pin.crba, pin.computeCoriolisMatrix, pin.computeGeneralizedGravity
    for i in range(n):
        mass[i] = crba(model, data, q[i])
        ct_v[i] = coriolis(model, data, q[i], v[i]).T @ v[i]
        grav[i] = gravity(model, data, q[i])
    # crba fills (at least) the upper triangle: mirror it
    upper = np.triu(mass)
    mass = upper + np.swapaxes(np.triu(mass, 1), 1, 2)
    momentum = np.einsum("nij,nj->ni", mass, v)
    beta = tau_m + ct_v - grav

    r = np.zeros((n, nv))
    if n > 1:
        h = np.diff(t)
        step = h > 0
        safe_h = np.where(step, h, 1.0)
        y = np.diff(momentum, axis=0) - 0.5 * (beta[1:] + beta[:-1]) * safe_h[:, None]
        y /= safe_h[:, None]
        decay = np.where(step, np.exp(-gain * np.where(step, h, 0.0)), 1.0)
        inject = (1.0 - decay)[:, None] * y  # zero on zero-length steps
        ri = np.zeros(nv)
        for k in range(n - 1):  # inherently sequential; two small vector ops per step
            ri = decay[k] * ri + inject[k]
            r[k + 1] = ri
    return robot.joint_values(r)


def check_mob(logs: Sequence[PreparedLog]) -> None:
    """MethodSkipped unless every log has a robot model whose joints are the log's joints."""
    for log in logs:
        robot = log.robot
        if robot is None:
            raise MethodSkipped(
                f"the momentum observer needs a robot model ({log.source} has none: give one)"
            )
        if set(robot.joint_names) != set(log.joint_names):
            raise MethodSkipped(
                f"the robot model's joints ({', '.join(robot.joint_names)}) are not the log's "
                f"({', '.join(log.joint_names)}) in {log.source}"
            )
        if robot.model.nv != robot.dof:
            raise MethodSkipped(
                f"the robot model has {robot.model.nv} velocity dimensions but "
                f"{robot.dof} logged joints ({log.source})"
            )


def _robot_of(log: PreparedLog) -> RobotModel:
    check_mob([log])
    assert log.robot is not None
    return log.robot


def filtered_velocity(log: PreparedLog, lowpass: LowPass) -> FloatArray:
    """q̇ low-pass filtered like the efforts (log column order; lstm-mob's inputs)."""
    out: FloatArray = lowpass.apply(log.states.t_s, log.states.velocity, log.source)
    return out


def mob_tau_ext(
    log: PreparedLog, gain: float = DEFAULT_GAIN, lowpass: LowPass | None = None
) -> FloatArray:
    """τ_ext of one prepared log, (N, dof) in the log's column order.

    The observer runs on the logged q, q̇ and measured effort; its output is then low-pass
    filtered with ``lowpass`` (default: the filter the log's efforts went through), the paper's
    "low-pass filtered data". Filtering the output rather than the inputs keeps the observer's
    nonlinear model consistent (filtered q̇ and effort do not satisfy the dynamics of the raw
    q); the observer is linear in the effort, so for the effort both orders agree.

    Not cached: every method pays for its own τ_ext, so train and test times compare fairly.
    """
    lowpass = lowpass or log.lowpass
    robot = _robot_of(log)
    cols = [log.joint_names.index(name) for name in robot.joint_names]
    t_s = log.states.t_s
    tau_r = momentum_observer(
        robot,
        t_s,
        log.states.position[:, cols],
        log.states.velocity[:, cols],
        log.effort[:, cols],
        gain,
    )
    tau_r = lowpass.apply(t_s, tau_r, log.source)
    tau = np.empty_like(tau_r)
    tau[:, cols] = tau_r
    return tau


class NaiveMob(ScoringMethod):
    """Paper IV-B 2: score = ‖τ_ext‖² with τ_ext from the momentum observer (gain 100).

    No training; deterministic (no ``seed``, so evaluate runs it once).
    """

    name = "naive-mob"
    unit = "sample"
    learns = False

    def __init__(self, gain: float = DEFAULT_GAIN, lowpass: LowPass | None = None) -> None:
        self.gain = gain
        self.lowpass = lowpass

    def check(self, logs: Sequence[PreparedLog]) -> None:
        check_mob(logs)

    def fit(self, train: Sequence[PreparedLog]) -> NaiveMob:
        return self

    def score(self, log: PreparedLog) -> FloatArray:
        tau = mob_tau_ext(log, self.gain, self.lowpass)
        out: FloatArray = np.einsum("ij,ij->i", tau, tau)
        return out


def mob_features(
    log: PreparedLog,
    joint_names: Sequence[str],
    gain: float = DEFAULT_GAIN,
    lowpass: LowPass | None = None,
) -> FloatArray:
    """τ_ext of ``log`` with columns in ``joint_names`` order (a fitted method's order)."""
    missing = [n for n in joint_names if n not in log.joint_names]
    if missing or len(joint_names) != len(log.joint_names):
        raise MethodSkipped(
            f"{log.source} has joints {', '.join(log.joint_names)}, the method was trained "
            f"on {', '.join(joint_names)}"
        )
    tau = mob_tau_ext(log, gain, lowpass)
    out: FloatArray = tau[:, [log.joint_names.index(n) for n in joint_names]]
    return out


class MobFeatureMethod(ScoringMethod):
    """Base of the learners on τ_ext (point and window OCSVM and autoencoders, paper IV-B 3, 4,
    6, 7): τ_ext from the momentum observer, per sample or in windows of ``window`` samples
    taken every ``stride`` samples, min–max normalised with the training data's range (eq. 8).

    Subclasses implement ``_fit_scaled(x)`` and ``_score_scaled(x)`` on normalised rows.
    """

    window: ClassVar[int] = 1  # samples per unit: 1 = per sample, else per window

    def __init__(
        self,
        gain: float = DEFAULT_GAIN,
        lowpass: LowPass | None = None,
        stride: int = WINDOW_SIZE,
    ) -> None:
        self.gain = gain
        self.lowpass = lowpass
        self.stride = stride
        self.note: str | None = None  # set by fit() when it had to deviate (e.g. subsampling)
        self.joint_names_: tuple[str, ...] | None = None
        self.scaler_: MinMaxScaler | None = None

    def check(self, logs: Sequence[PreparedLog]) -> None:
        check_mob(logs)

    def _starts(self, log: PreparedLog) -> NDArray[np.int64]:
        return window_starts(log.states.t_s, self.window, self.stride)

    def features(self, log: PreparedLog, joint_names: Sequence[str]) -> FloatArray:
        """Unnormalised model inputs of ``log``: one row per unit."""
        tau = mob_features(log, joint_names, self.gain, self.lowpass)
        if self.window == 1:
            return tau
        return windows(tau, self._starts(log), self.window)

    def unit_labels(self, log: PreparedLog) -> BoolArray:
        if self.window == 1:
            return super().unit_labels(log)
        return window_labels(log.labels, len(log), self._starts(log), self.window)

    def unit_stamps(self, log: PreparedLog) -> NDArray[np.int64]:
        if self.window == 1:
            return super().unit_stamps(log)
        return log.states.stamp_ns[self._starts(log) + self.window - 1]

    def fit(self, train: Sequence[PreparedLog]) -> MobFeatureMethod:
        if not train:
            raise DataError(
                f"{self.name} needs training logs",
                "training logs",
                "give collision-free training logs",
                option="train",
            )
        self.check(train)
        names = train[0].joint_names
        x = np.concatenate([self.features(log, names) for log in train])
        if len(x) == 0:
            raise DataError(
                f"the training logs are too short for {self.window}-sample windows",
                "training logs",
                "give longer logs",
                option="train",
            )
        self.note = None
        scaler = MinMaxScaler().fit(x)
        self._fit_scaled(scaler.transform(x))
        self.joint_names_ = names
        self.scaler_ = scaler
        return self

    def score(self, log: PreparedLog) -> FloatArray:
        if self.scaler_ is None or self.joint_names_ is None:
            raise NotFittedError(f"{self.name} used before fit()", self.name, "call fit() first")
        x = self.scaler_.transform(self.features(log, self.joint_names_))
        if len(x) == 0:
            return np.zeros(0)
        return self._score_scaled(x)

    def _training_rows(self, x: FloatArray, cap: int | None, seed: int, why: str) -> FloatArray:
        """``x``, or a seeded random ``cap`` of its rows (in order) when it has more; the
        method's ``note`` then says so (``why``: the parameter that caps it)."""
        rows = subsample(len(x), cap, seed)
        if rows is None:
            return x
        self.note = (
            f"trained on a random {len(rows)} of {len(x)} training "
            f"{'windows' if self.window > 1 else 'samples'} ({why}, subsample_seed {seed})"
        )
        out: FloatArray = x[rows]
        return out

    @abstractmethod
    def _fit_scaled(self, x: FloatArray) -> None:
        """Learn from normalised training rows."""

    @abstractmethod
    def _score_scaled(self, x: FloatArray) -> FloatArray:
        """One anomaly score per normalised row (higher = more anomalous)."""
