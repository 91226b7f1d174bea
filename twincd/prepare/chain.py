"""The chain of stages a calibration's samples go down, built in one place (``build_chain``):
pick the twin's joint columns, twin them (velocity where the log has none, acceleration,
τ̂ = RNEA(q, q̇, q̈), the joint-torque regressor for identified models), put the joints in the
output order, low-pass filter τ, τ̂ and the model's other inputs alike.

The same function builds the chain of a log streamed from disk (``twincd.prepare.setup``, which
feeds ``fit``, ``threshold`` and ``detect`` with a zero-phase or a causal filter) and of live
samples (``twincd.detection.OnlineDetector``): the filter's kind comes from the settings, the
joints from a ``JointLayout``, so a causal calibration gives the same numbers in batch and live.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from twincd.errors import CalibrationError, UsageError
from twincd.prepare.frames import Chain, Derived, Frame, Mapped, Stage
from twincd.prepare.grid import GridStage, grid_period_ns
from twincd.signal.features import FittedModel, ModelFeatures, ModelInputs
from twincd.signal.filters import LowPass
from twincd.types import BoolArray, FloatArray, IndexArray

if TYPE_CHECKING:
    from twincd.signal.unwrap import StreamingUnwrap
    from twincd.twin.robot import RobotModel

log = logging.getLogger("twincd")


# ------------------------------------------------------------------ the robot model


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


# ------------------------------------------------------------------ the stages


def pick_columns(columns: IndexArray) -> Mapped:
    """Select and reorder the joint columns of every per-joint array: the output has exactly
    ``len(columns)`` joints, whatever the frames carry beyond them."""
    n = len(columns)
    keep: IndexArray | slice = slice(0, n) if np.array_equal(columns, np.arange(n)) else columns

    def pick(frame: Frame) -> Frame:
        # a leading run of columns is a view (no copy); any other selection a copy
        return frame.with_columns(**{k: frame[k][:, keep] for k in _JOINT_COLUMNS if k in frame})

    return Mapped(pick)


# per-joint arrays: joints on axis 1 (the regressor has a third axis, its parameters)
_JOINT_COLUMNS = ("position", "velocity", "effort", "sim_effort", "regressor")


def _fill_velocity(frame: Frame) -> Frame:
    velocity = frame["velocity"]
    filled = np.where(np.isfinite(velocity), velocity, frame["dq"])
    return Frame({k: v for k, v in frame.items() if k != "dq"}).with_columns(velocity=filled)


def twin_stages(
    robot: RobotModel | None,
    period_s: float,
    causal: bool,
    fill_velocity: bool,
    threads: int | None = None,
    regressor: RobotModel | None = None,
    on_grid: bool = False,
) -> list[Stage]:
    """Velocity (from position where the log has none, unwrapped first: a joint reported in
    (−π, π] does not jump by 2π; ``twincd.signal.unwrap``), acceleration, τ̂ = RNEA(q, q̇, q̈), and
    with ``regressor`` the joint-torque regressor Y(q, q̇, q̈) (column ``regressor``, (N, D, P);
    the ``identified`` models).

    Columns must be in the robot's joint order. ``robot`` None: the frames carry
    ``sim_effort`` already, only the velocity (and the regressor) is completed. ``on_grid``
    (a grid's nodes, ``twincd.prepare.grid``): with the regressor of the twin's own model, τ̂ is
    Y θ_URDF (RNEA is linear in the inertial parameters; equal to 1e-13) instead of a second
    pass of the dynamics.
    """
    from twincd.signal.derivatives import StreamingDerivative
    from twincd.signal.unwrap import StreamingUnwrap
    from twincd.twin.dynamics import (
        inertial_effort,
        inertial_parameters,
        inverse_dynamics,
        torque_regressor,
    )

    stages: list[Stage] = []
    if fill_velocity:
        dq = StreamingDerivative(period_s=period_s, causal=causal)
        stages += [
            Derived(StreamingUnwrap(period_s), "position", "unwrapped"),
            Derived(dq, "unwrapped", "dq", keep=False),
            Mapped(_fill_velocity),
        ]
    if robot is None and regressor is None:
        return stages
    ddq = StreamingDerivative(period_s=period_s, causal=causal)
    urdf = None  # θ_URDF per joint, (D, P), when τ̂ comes from the regressor
    if on_grid and robot is not None and robot is regressor:
        theta = inertial_parameters(robot)
        urdf = np.ascontiguousarray(np.broadcast_to(theta, (robot.dof, len(theta))))

    def twin(frame: Frame) -> Frame:
        q, v, a = frame["position"], frame["velocity"], frame["ddq"]
        out = Frame({k: x for k, x in frame.items() if k != "ddq"})
        y = None if regressor is None else torque_regressor(regressor, q, v, a)
        if urdf is not None and y is not None:
            out = out.with_columns(sim_effort=inertial_effort(y, urdf))
        elif robot is not None:
            out = out.with_columns(sim_effort=inverse_dynamics(robot, q, v, a, threads=threads))
        return out if y is None else out.with_columns(regressor=y)

    return [*stages, Derived(ddq, "velocity", "ddq"), Mapped(twin)]


def filter_stages(
    lowpass: LowPass,
    period_s: float,
    coulomb_eps: Sequence[float] = (),
    regressor: BoolArray | None = None,
    theta: FloatArray | None = None,
    on_grid: bool = False,
) -> list[Stage]:
    """τ̃ and τ̂̃: measured and twin effort through the same low-pass filter, in one pass.

    With ``coulomb_eps`` (friction models), also the velocity (``velocity_f``) and tanh(q̇/ε)
    for each ε (``coulomb_f``, (N, E, joints)) through the same filter, so that they lag as the
    efforts do: the Coulomb friction steps where a joint turns, and only the step itself
    filtered matches the filtered effort (tanh of the filtered velocity steps too sharply
    there). With ``regressor`` (identified models: the (D, P) mask of the regressor's entries
    that can be non-zero, ``twincd.twin.dynamics.regressor_mask``, in the frames' joint order),
    the joint-torque regressor too, as ``regressor_f`` (N, kept): only the masked entries,
    in row-major order (``PreparedLog`` has it whole, (N, D, P)). With ``theta`` too (scoring
    with a fitted identified model: its (D, P) weights), only each joint's Y_j θ_j goes through
    the filter, as ``regressor_effort_f`` (N, D): the filter is linear, so LP(Y) θ = LP(Y θ),
    and D channels are filtered instead of hundreds. Without either, nothing more is filtered:
    the seed's model costs what it did.

    ``on_grid``: the frames are a grid's nodes (``twincd.prepare.grid``): their ``coulomb`` column
    ((N, E, joints), the cells' means of tanh(q̇/ε)) is filtered instead of tanh of their
    velocity, Y_j θ_j is summed over the whole regressor row (``inertial_effort``), and the
    zero-phase edges are left to the samples."""
    from twincd.signal.filters import StreamingLowPass
    from twincd.twin.dynamics import inertial_effort, regressor_effort

    eps = tuple(float(e) for e in coulomb_eps)
    extra = 1 + len(eps) if eps else 0  # velocity and one Coulomb feature per ε
    kept = 0 if regressor is None else int(np.count_nonzero(regressor))
    if regressor is not None and theta is not None:
        kept = len(theta)  # Y_j θ_j: one channel per joint

    def stack(frame: Frame) -> Frame:
        v = frame["velocity"]
        coulomb = frame.get("coulomb")
        if not eps:
            friction: tuple[FloatArray, ...] = ()
        elif coulomb is not None:  # a grid's cell means of tanh(q̇/ε), one per ε
            friction = (v, *np.moveaxis(coulomb, 1, 0))
        else:
            friction = (v, *(np.tanh(v / e) for e in eps))
        columns = [frame["effort"], frame["sim_effort"], *friction]
        if regressor is not None and theta is not None and on_grid:
            columns.append(inertial_effort(frame["regressor"], theta))
        elif regressor is not None:
            y = frame["regressor"][:, regressor]
            columns.append(y if theta is None else regressor_effort(y, theta, regressor))
        rest = {k: x for k, x in frame.items() if k not in ("regressor", "coulomb")}
        return Frame(rest, frame.n).with_columns(both=np.hstack(columns))

    def split(frame: Frame) -> Frame:
        both = frame["both_f"]
        d = (both.shape[1] - kept) // (2 + extra)
        rest = {k: v for k, v in frame.items() if k not in ("both", "both_f")}
        out = Frame(rest).with_columns(effort_f=both[:, :d], sim_effort_f=both[:, d : 2 * d])
        if eps:
            out = out.with_columns(
                velocity_f=both[:, 2 * d : 3 * d],
                coulomb_f=both[:, 3 * d : (3 + len(eps)) * d].reshape(len(both), len(eps), d),
            )
        if regressor is not None and theta is not None:
            out = out.with_columns(regressor_effort_f=both[:, (2 + extra) * d :])
        elif regressor is not None:  # only the masked entries, (N, kept): no zeros copied
            out = out.with_columns(regressor_f=both[:, (2 + extra) * d :])
        return out

    return [
        Mapped(stack),
        Derived(StreamingLowPass(lowpass, period_s=period_s), "both", "both_f", keep=False),
        Mapped(split),
        *(() if on_grid else edge_stages(lowpass, period_s)),
    ]


def edge_stages(lowpass: LowPass, period_s: float) -> list[Stage]:
    """An ``edge`` column: 1.0 within the filter's edge span (its settling time) of a
    segment's start and, zero-phase, of its end; else 0.0."""
    from twincd.signal.filters import EdgeMarker, edge_span

    span = edge_span(lowpass, period_s)
    marker = EdgeMarker(span, period_s, ends=not lowpass.causal)
    return [Derived(marker, "stamp_ns", "edge")] if span else []


# ------------------------------------------------------------------ one chain


@dataclass(frozen=True)
class JointLayout:
    """The joints of a chain: ``columns`` those of the frames pushed in, ``twin`` those the twin
    runs on (the robot model's order, or the log's own twin effort's), ``output`` those that
    come out (a calibration's order). Each of ``twin`` must be in ``columns``, each of
    ``output`` in ``twin``."""

    columns: tuple[str, ...]
    twin: tuple[str, ...]
    output: tuple[str, ...]

    @property
    def to_twin(self) -> IndexArray:
        """The columns the twin reads, in its order."""
        return np.array([self.columns.index(n) for n in self.twin], dtype=np.intp)

    @property
    def to_output(self) -> IndexArray:
        """The twin's columns in the output order."""
        return np.array([self.twin.index(n) for n in self.output], dtype=np.intp)


@dataclass(frozen=True)
class BuiltChain:
    """A built chain and what scoring its frames needs besides them."""

    chain: Chain
    layout: JointLayout
    period_s: float
    # (D, P) the regressor entries the frames' ``regressor_f`` (N, kept) holds, output order
    regressor_mask: BoolArray | None = None
    # the coarse grid the twin and the filter run on, when the log is sampled fast enough
    grid: GridStage | None = None

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.layout.output

    @property
    def unwrap(self) -> StreamingUnwrap | None:
        """The stage that unwraps positions before their derivative (None: velocity logged);
        what it found is for the caller to say (``warn_unwrapped``)."""
        from twincd.signal.unwrap import StreamingUnwrap

        for stage in self.chain.stages:
            if isinstance(stage, Derived) and isinstance(stage.signal, StreamingUnwrap):
                return stage.signal
        return None


def warn_unwrapped(source: str, unwrap: StreamingUnwrap | None, joints: Sequence[str]) -> None:
    """One warning for the joints whose positions wrapped (unwrapped before differentiating),
    one naming the steps that cannot be a wrap."""
    if unwrap is None or not len(unwrap.wraps):
        return
    wrapped = [f"{j} ({n})" for j, n in zip(joints, unwrap.wraps.tolist(), strict=True) if n]
    if wrapped:
        log.warning(
            "%s: positions wrap by a whole turn (2π) on %s; unwrapped before differentiating "
            "them into velocity",
            source,
            ", ".join(wrapped),
        )
    jumps = [
        f"{j} ({n}×, up to {big:.3g} rad, first at stamp {first})"
        for j, n, big, first in zip(
            joints,
            unwrap.jumps.tolist(),
            unwrap.largest_jump.tolist(),
            unwrap.first_jump_ns.tolist(),
            strict=True,
        )
        if n
    ]
    if jumps:
        log.warning(
            "%s: positions jump by more than π between two samples, and not by a whole turn: "
            "%s; no joint moves that fast, so the velocity differentiated there is wrong; check "
            "the log",
            source,
            "; ".join(jumps),
        )


def build_chain(
    lowpass: LowPass,
    features: ModelFeatures,
    layout: JointLayout,
    period_s: float,
    twin: RobotModel | None,
    fill_velocity: bool,
    regressor: RobotModel | None = None,
    threads: int | None = None,
    filtered: bool = True,
    nodes: bool = False,
    model: FittedModel | None = None,
) -> BuiltChain:
    """The one chain for ``lowpass`` (zero-phase or causal) and a model's ``features`` (the
    friction models' ε, the identified models' θ: ``FittedModel.features`` of a fitted
    ``model``) on frames whose joints are laid out as ``layout``: pick the twin's columns, twin
    (``twin`` None: the frames carry ``sim_effort``; ``regressor``: the robot model whose
    joint-torque regressor the identified models need, ``layout.twin`` in its order), put the
    joints in the output order, and with ``filtered`` low-pass filter (``filtered=False`` stops
    after the twin: what ``simulate`` writes).

    Where the log is sampled far faster than the filter keeps
    (``twincd.prepare.grid.grid_period_ns``: a 1 kHz log), the twin and the filter run on a coarse
    grid's cell means and come back on the samples by interpolation
    (``twincd.prepare.grid.GridStage``). What comes back on the samples: every filtered column by
    default (what a ``PreparedLog`` holds); with ``nodes``, all but the regressor's hundreds of
    entries, the grid keeping its filtered nodes for ``fit`` (``BuiltChain.grid.take_nodes``); with
    a fitted ``model`` (scoring), its prediction ``predicted``, computed on the nodes (every model
    is linear in its filtered inputs, so it commutes with the interpolation), with ``effort_f`` and
    ``sim_effort_f`` only."""
    causal = lowpass.causal
    mask = None
    if filtered and regressor is not None:
        from twincd.twin.dynamics import regressor_mask

        assert regressor.joint_names == layout.twin, "the regressor runs on the twin's joints"
        mask = regressor_mask(regressor)[layout.to_output]  # robot order → the output's
    theta = None if mask is None else features.theta
    grid = grid_period_ns(lowpass.cutoff_hz, period_s) if filtered else None
    if grid is not None:
        models = (twin, regressor, None if nodes else model)
        stage = _grid_stage(lowpass, features, layout, grid, period_s, models, threads, nodes)
        stages: list[Stage] = [
            pick_columns(layout.to_twin),
            *twin_stages(None, period_s, causal, fill_velocity),  # the velocity, if missing
            pick_columns(layout.to_output),
            *edge_stages(lowpass, period_s),
            stage,
        ]
        return BuiltChain(Chain(stages), layout, period_s, mask, stage)
    stages = [
        pick_columns(layout.to_twin),
        *twin_stages(twin, period_s, causal, fill_velocity, threads, regressor),
        pick_columns(layout.to_output),
    ]
    if filtered:
        stages += filter_stages(lowpass, period_s, features.coulomb_eps, mask, theta)
    return BuiltChain(Chain(stages), layout, period_s, mask)


def _grid_stage(
    lowpass: LowPass,
    features: ModelFeatures,
    layout: JointLayout,
    grid_ns: int,
    period_s: float,
    models: tuple[RobotModel | None, RobotModel | None, FittedModel | None],
    threads: int | None,
    nodes: bool,
) -> GridStage:
    """The grid's stage: on its nodes (joints in the output order) the twin's and the filter's
    stages as ``build_chain`` runs them per sample, at the grid's period, then the fitted
    model's prediction when there is one (``models``: the twin's robot model, the regressor's
    and the fitted model, as ``build_chain`` takes them)."""
    from twincd.twin.dynamics import regressor_mask

    twin, regressor, model = models
    eps = features.coulomb_eps
    step = grid_ns * 1e-9
    mask = None if regressor is None else regressor_mask(regressor)[layout.to_output]
    theta = None if mask is None else features.theta
    # a fitted model reads one Coulomb feature per joint, at the joint's own ε: only those are
    # averaged and filtered, and set among the others (zeros) before the model reads them
    own = None if model is None else joint_epsilon(model, eps, len(layout.output))
    node_stages: list[Stage] = [
        pick_columns(np.argsort(layout.to_output).astype(np.intp)),  # output → twin order
        # one thread: a few hundred nodes a call, and the reader's thread has the other core
        *twin_stages(twin, step, lowpass.causal, False, 1, regressor, on_grid=True),
        pick_columns(layout.to_output),
        *filter_stages(lowpass, step, eps if own is None else eps[:1], mask, theta, on_grid=True),
    ]
    interpolate = ["effort_f", "sim_effort_f"]
    if model is not None:
        node_stages.append(_predicting(model, eps, mask, theta, own))
        interpolate.append("predicted")
    else:
        if eps:
            interpolate += ["velocity_f", "coulomb_f"]
        if mask is not None and theta is not None:
            interpolate.append("regressor_effort_f")
        elif mask is not None and not nodes:
            interpolate.append("regressor_f")
        if twin is not None and not nodes:
            interpolate.append("sim_effort")  # τ̂ on the grid, unfiltered
    return GridStage(
        Chain(node_stages),
        grid_ns,
        period_s,
        lowpass.causal,
        interpolate,
        average_sim=twin is None,
        coulomb_eps=eps,
        joint_eps=own,
        keep_nodes=nodes,
    )


def _predicting(
    model: FittedModel,
    eps: tuple[float, ...],
    mask: BoolArray | None,
    theta: FloatArray | None,
    own: FloatArray | None,
) -> Mapped:
    """The fitted model's prediction (``predicted``) of filtered frames (``theta``: the θ of
    their Ỹθ); ``own``: the frames carry one Coulomb feature per joint, at its ε, set into
    ``eps``' features for the model."""
    at = None if own is None else [eps.index(float(e)) for e in own]

    def predict(frame: Frame) -> Frame:
        inputs = ModelInputs.of(frame, eps, mask, theta)
        if at is not None:
            coulomb = np.zeros((frame.n, len(eps), len(at)))
            coulomb[:, at, np.arange(len(at))] = frame["coulomb_f"][:, 0, :]
            inputs = replace(inputs, coulomb_f=coulomb)
        return frame.with_columns(predicted=model.predict(inputs))

    return Mapped(predict)


def joint_epsilon(model: FittedModel, eps: Sequence[float], joints: int) -> FloatArray | None:
    """Each joint's ε of a fitted friction model, when every one is among ``eps`` (else None:
    the chain then prepares every ε's features, and the model says what is missing)."""
    epsilon = getattr(model, "epsilon_", None)
    if not eps or epsilon is None or len(epsilon) != joints:
        return None
    if any(float(e) not in [float(x) for x in eps] for e in epsilon):
        return None
    return np.asarray(epsilon, dtype=np.float64)
