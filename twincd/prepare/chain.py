"""The chain of stages a calibration's samples go down, built in one place (``build_chain``):
pick the twin's joint columns, twin them (velocity where the log has none, acceleration,
τ̂ = RNEA(q, q̇, q̈), the joint-torque regressor for identified models), put the joints in the
output order, low-pass filter τ, τ̂ and the model's other inputs alike.

The same function builds the chain of a log streamed from disk (``twincd.prepare.stream``, which
feeds ``fit``, ``threshold`` and ``detect`` with a zero-phase or a causal filter) and of live
samples (``twincd.detection.OnlineDetector``): the filter's kind comes from the settings, the
joints from a ``JointLayout``, so a causal calibration gives the same numbers in batch and live.
The robot models it twins with come from ``twincd.prepare.robots``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from twincd.prepare.frames import Chain, Derived, Frame, Mapped, Stage
from twincd.prepare.grid import GridStage, grid_period_ns
from twincd.signal.features import FittedModel, ModelFeatures, ModelInputs
from twincd.signal.filters import LowPass
from twincd.types import BoolArray, FloatArray, IndexArray

if TYPE_CHECKING:
    from twincd.signal.unwrap import StreamingUnwrap
    from twincd.twin.robot import RobotModel


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
    warmup: int = 0,
) -> list[Stage]:
    """τ̃ and τ̂̃: measured and twin effort through the same low-pass filter, in one pass (a
    causal one started after ``warmup`` samples of each segment: ``warmup_samples``).

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
        Derived(StreamingLowPass(lowpass, period_s, warmup=warmup), "both", "both_f", keep=False),
        Mapped(split),
        *(() if on_grid else edge_stages(lowpass, period_s, None, warmup)),
    ]


def edge_stages(
    lowpass: LowPass,
    period_s: float,
    run_period_s: float | None = None,
    warmup: int = 0,
    fast: LowPass | None = None,
) -> list[Stage]:
    """An ``edge_factor`` column, (N, bands): each sample's edge factor
    (``twincd.signal.edges``) for ``lowpass`` and, with a ``fast`` upper filter, for the band
    between them, run every ``run_period_s`` (a coarse grid's period; default the samples')
    after ``warmup`` of them, by its time from its segment's ends."""
    from twincd.signal.bands import Band, slow_band
    from twincd.signal.edges import EdgeFactors, edge_profile

    run = run_period_s or period_s
    profiles = [edge_profile(slow_band(lowpass), run, warmup)]
    if fast is not None:
        profiles.append(edge_profile(Band("fast", fast, lowpass), run, warmup))
    return [Derived(EdgeFactors(profiles, period_s), "stamp_ns", "edge_factor")]


def warmup_samples(causal: bool, fill_velocity: bool) -> int:
    """Samples a causal filter waits at each segment's start before it starts: those whose
    causal derivative has no full window yet (acceleration; and velocity, differentiated from
    position), so the twin's effort there (RNEA of an acceleration from one or two samples)
    never enters the filter's state. Zero-phase: none (its derivative's window is centred and
    shifted inside the segment)."""
    from twincd.signal.derivatives import DEFAULT_WINDOW

    return (DEFAULT_WINDOW - 1) * (2 if fill_velocity else 1) if causal else 0


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
        what it found is for the caller to say (``twincd.prepare.notices.warn_unwrapped``)."""
        from twincd.signal.unwrap import StreamingUnwrap

        for stage in self.chain.stages:
            if isinstance(stage, Derived) and isinstance(stage.signal, StreamingUnwrap):
                return stage.signal
        return None


def build_chain(
    lowpass: LowPass,
    features: ModelFeatures,
    *,
    layout: JointLayout,
    period_s: float,
    twin: RobotModel | None,
    fill_velocity: bool,
    regressor: RobotModel | None = None,
    threads: int | None = None,
    filtered: bool = True,
    nodes: bool = False,
    model: FittedModel | None = None,
    fast_hz: float | None = None,
    jump: FloatArray | None = None,
) -> BuiltChain:
    """The one chain for ``lowpass`` (zero-phase or causal) and a model's ``features`` (the
    friction models' ε, the identified models' θ: ``FittedModel.features`` of a fitted
    ``model``) on frames whose joints are laid out as ``layout``: pick the twin's columns, twin
    (``twin`` None: the frames carry ``sim_effort``; ``regressor``: the robot model whose
    joint-torque regressor the identified models need, ``layout.twin`` in its order), put the
    joints in the output order, and with ``filtered`` low-pass filter (``filtered=False`` stops
    after the twin: what ``simulate`` writes).

    Fitting (no ``model``): every input the features name through the filter (what a
    ``PreparedLog`` holds; ``fit`` sums them). Scoring (a fitted ``model``): its residual of
    the raw samples through each band's filter (``scoring_stages``): ``effort_f``,
    ``residual`` and ``predicted`` (= ``effort_f`` − ``residual``) in the filter's band and, with
    a fast band up to ``fast_hz`` (``twincd.signal.bands``), ``residual_fast``; ``edge_factor``
    (N, bands); with a ``jump`` threshold (the score's), ``fast_off`` where the fast band is
    not judged.

    Where the log is sampled far faster than the filters keep
    (``twincd.prepare.grid.grid_period_ns``: a 1 kHz log), the twin and the filters run on a
    coarse grid's cell means and come back on the samples by interpolation
    (``twincd.prepare.grid.GridStage``); with ``nodes`` (fit) the grid keeps its filtered nodes
    (``BuiltChain.grid.take_nodes``) and the samples come back without the regressor's hundreds
    of entries."""
    causal = lowpass.causal
    mask = _output_mask(regressor, layout) if filtered else None
    theta = None if mask is None else features.theta
    fast = None if fast_hz is None else _fast_high(lowpass, fast_hz, period_s)
    scoring = filtered and model is not None and not nodes
    warmup = warmup_samples(causal, fill_velocity)  # on a grid: as many nodes as samples
    fast_cutoff = None if fast is None else fast.cutoff_hz
    grid = grid_period_ns(lowpass.cutoff_hz, period_s, fast_cutoff) if filtered else None
    if grid is not None:
        models = (twin, regressor, model if scoring else None)
        stage = _grid_stage(
            lowpass, features, layout, grid, period_s, models, threads, nodes, warmup, fast
        )
        run = grid * 1e-9
        stages: list[Stage] = [
            pick_columns(layout.to_twin),
            *twin_stages(None, period_s, causal, fill_velocity),  # the velocity, if missing
            pick_columns(layout.to_output),
            *edge_stages(lowpass, period_s, run, warmup, fast if scoring else None),
            *(jump_stages(jump, fast, period_s) if scoring else ()),
            stage,
        ]
        return BuiltChain(Chain(stages), layout, period_s, mask, stage)
    stages = [
        pick_columns(layout.to_twin),
        *twin_stages(twin, period_s, causal, fill_velocity, threads, regressor),
        pick_columns(layout.to_output),
    ]
    if scoring:
        assert model is not None
        stages += [
            _raw_residual(model, features.coulomb_eps, mask, theta, None),
            *_band_stages(lowpass, fast, period_s, warmup),
            *edge_stages(lowpass, period_s, None, warmup, fast),
            *jump_stages(jump, fast, period_s),
        ]
    elif filtered:
        stages += filter_stages(lowpass, period_s, features.coulomb_eps, mask, theta, False, warmup)
    return BuiltChain(Chain(stages), layout, period_s, mask)


def _output_mask(regressor: RobotModel | None, layout: JointLayout) -> BoolArray | None:
    """The (D, P) mask of the regressor's entries that can be non-zero
    (``twincd.twin.dynamics.regressor_mask``), its joints in the output order (None without a
    regressor)."""
    if regressor is None:
        return None
    from twincd.twin.dynamics import regressor_mask

    assert regressor.joint_names == layout.twin, "the regressor runs on the twin's joints"
    return regressor_mask(regressor)[layout.to_output]  # robot order → the output's


def _fast_high(lowpass: LowPass, fast_hz: float, period_s: float) -> LowPass | None:
    """The fast band's upper filter, at ``fast_hz`` as far as the sampling rate allows (None:
    it has no room for one, ``twincd.signal.bands.fast_band_at``)."""
    from twincd.signal.bands import fast_band_at

    band = fast_band_at(lowpass, fast_hz, period_s)
    return None if band is None else band.high


def _grid_stage(
    lowpass: LowPass,
    features: ModelFeatures,
    layout: JointLayout,
    grid_ns: int,
    period_s: float,
    models: tuple[RobotModel | None, RobotModel | None, FittedModel | None],
    threads: int | None,
    nodes: bool,
    warmup: int = 0,
    fast: LowPass | None = None,
) -> GridStage:
    """The grid's stage: on its nodes (joints in the output order) the twin's and the filter's
    stages as ``build_chain`` runs them per sample, at the grid's period: fitting, every
    filtered input; scoring (``models``: the twin's robot model, the regressor's and the fitted
    model, as ``build_chain`` takes them), the model's residual in each band."""
    twin, regressor, model = models
    eps = features.coulomb_eps
    step = grid_ns * 1e-9
    mask = _output_mask(regressor, layout)
    theta = None if mask is None else features.theta
    # a fitted model reads one Coulomb feature per joint, at the joint's own ε: only those are
    # averaged, and set among the others (zeros) before the model reads them
    own = None if model is None else joint_epsilon(model, eps, len(layout.output))
    node_stages: list[Stage] = [
        pick_columns(np.argsort(layout.to_output).astype(np.intp)),  # output → twin order
        # one thread: a few hundred nodes a call, and the reader's thread has the other core
        *twin_stages(twin, step, lowpass.causal, False, 1, regressor, on_grid=True),
        pick_columns(layout.to_output),
    ]
    if model is not None:
        node_stages += [
            _raw_residual(model, eps, mask, theta, own, on_grid=True),
            *_band_stages(lowpass, fast, step, warmup),
        ]
        interpolate = ["effort_f", "residual", "predicted", "residual_fast"]
    else:
        node_stages += filter_stages(lowpass, step, eps, mask, theta, True, warmup)
        interpolate = ["effort_f", "sim_effort_f"]
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


def _raw_residual(
    model: FittedModel,
    eps: tuple[float, ...],
    mask: BoolArray | None,
    theta: FloatArray | None,
    own: FloatArray | None,
    on_grid: bool = False,
) -> Mapped:
    """``residual_raw``: the measured effort minus the fitted model's prediction of the raw
    (unfiltered) samples, τ − f(τ̂, q̇, tanh(q̇/ε), Yθ). Every model is linear in its inputs
    and every band is a linear filter, so a band's residual is this through the band: what the
    model predicts of inputs filtered alike (``fit``'s), to rounding, for a third of the
    columns filtered. ``theta``: the θ of the frames' Yθ (None: the model reads the regressor's
    masked entries, ``regressor_f``, e.g. the cross-fit's models of several θ); ``own``: the
    frames carry one Coulomb feature per joint at its ε (a grid's cell means, ``coulomb``),
    set among ``eps``' others (zeros) for the model."""
    at = None if own is None else [eps.index(float(e)) for e in own]

    def residual(frame: Frame) -> Frame:
        velocity = np.asarray(frame["velocity"], dtype=np.float64)
        coulomb = frame.get("coulomb")  # a grid's cell means of tanh(q̇/ε)
        if at is not None and coulomb is not None:
            spread = np.zeros((frame.n, len(eps), len(at)))
            spread[:, at, np.arange(len(at))] = coulomb[:, 0, :]
            coulomb = spread
        elif eps and coulomb is None:
            coulomb = np.stack([np.tanh(velocity / e) for e in eps], axis=1)
        inputs = ModelInputs(
            sim_effort_f=np.asarray(frame["sim_effort"], dtype=np.float64),
            effort_f=np.asarray(frame["effort"], dtype=np.float64),
            velocity_f=velocity,
            coulomb_f=coulomb,
            coulomb_eps=eps,
            regressor_mask=mask,
            regressor_theta=theta,
            stamp_ns=frame.get("stamp_ns"),
            **_regressor_inputs(frame.get("regressor"), mask, theta, on_grid),
        )
        raw = model.residual(inputs)  # the model's own, as evaluate and fit score it
        rest = {k: v for k, v in frame.items() if k not in ("regressor", "coulomb")}
        return Frame(rest, frame.n).with_columns(residual_raw=raw)

    return Mapped(residual)


def _regressor_inputs(
    regressor: FloatArray | None, mask: BoolArray | None, theta: FloatArray | None, on_grid: bool
) -> dict[str, FloatArray | None]:
    """A model's raw regressor inputs: Yθ per joint with the model's θ (summed in a fixed order
    per sample, as ``filter_stages``), else the regressor's masked entries."""
    if regressor is None or mask is None:
        return {}
    from twincd.twin.dynamics import inertial_effort, regressor_effort

    if theta is not None:
        effort = (
            inertial_effort(regressor, theta)
            if on_grid
            else regressor_effort(regressor[:, mask], theta, mask)
        )
        return {"regressor_effort_f": effort}
    return {"regressor_f": regressor[:, mask]}


def _band_stages(
    lowpass: LowPass, fast: LowPass | None, period_s: float, warmup: int
) -> list[Stage]:
    """``effort_f``, ``residual`` and ``predicted`` in the filter's band (measured effort and
    ``residual_raw`` through it in one pass), and with a ``fast`` upper filter the fast band's
    ``residual_fast``: what the slow band leaves of ``residual_raw`` through it
    (``twincd.signal.bands.Band.apply``)."""
    from twincd.signal.filters import StreamingLowPass

    def stack(frame: Frame) -> Frame:
        both = np.hstack([frame["effort"], frame["residual_raw"]])
        return frame.with_columns(both=both)

    def split(frame: Frame) -> Frame:
        both = frame["both_f"]
        d = both.shape[1] // 2
        rest = {k: v for k, v in frame.items() if k != "both_f"}
        if fast is None:
            rest.pop("residual_raw", None)
        effort_f, residual = both[:, :d], both[:, d:]
        return Frame(rest, frame.n).with_columns(
            effort_f=effort_f, residual=residual, predicted=effort_f - residual
        )

    stages: list[Stage] = [
        Mapped(stack),
        Derived(StreamingLowPass(lowpass, period_s, warmup=warmup), "both", "both_f", keep=False),
        Mapped(split),
    ]
    if fast is not None:

        def left(frame: Frame) -> Frame:
            rest = {k: v for k, v in frame.items() if k != "residual_raw"}
            return Frame(rest, frame.n).with_columns(left=frame["residual_raw"] - frame["residual"])

        high = StreamingLowPass(fast, period_s, warmup=warmup)
        stages += [Mapped(left), Derived(high, "left", "residual_fast", keep=False)]
    return stages


def jump_stages(jump: FloatArray | None, fast: LowPass | None, period_s: float) -> list[Stage]:
    """``fast_off``: samples near a jump of the logged velocity (a one-period change of some
    joint's above ``jump``, ``twincd.calibration.score``), where the fast band is not judged;
    none without a fast band or a jump threshold."""
    if jump is None or fast is None:
        return []
    from twincd.signal.bands import JumpMask

    return [Derived(JumpMask(jump, fast, period_s), "velocity", "fast_off")]


def joint_epsilon(model: FittedModel, eps: Sequence[float], joints: int) -> FloatArray | None:
    """Each joint's ε of a fitted friction model, when every one is among ``eps`` (else None:
    the chain then prepares every ε's features, and the model says what is missing)."""
    epsilon = getattr(model, "epsilon_", None)
    if not eps or epsilon is None or len(epsilon) != joints:
        return None
    if any(float(e) not in [float(x) for x in eps] for e in epsilon):
        return None
    return np.asarray(epsilon, dtype=np.float64)
