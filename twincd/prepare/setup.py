"""From a log on disk to the arrays every method works on: a log streamed block by block
(``Setup.open``, a ``PreparedStream``) or whole (``Setup.prepare``, a ``PreparedLog``), read and
sent down the chain of ``twincd.prepare.chain`` (twin, or the log's own ``/twincd/sim_effort``,
then the low-pass filter).

``Setup.open(path)`` streams a log of any length at flat memory (what ``fit``, ``threshold``,
``detect``, ``simulate`` and ``evaluate``'s calibration model use); ``Setup.prepare(path)``
concatenates the same blocks into one ``PreparedLog`` (what the baselines and ``evaluate``'s
methods that fit on training logs use, one log at a time).
``twincd.detection.OnlineDetector`` builds the same chain for live samples.

Sampling rate and gaps: a log's nominal period is the calibration's (``Setup.period_s``) when
there is one, so batch and live detection filter alike; otherwise the median interval of the
log's first samples (``twincd.signal.nominal_period``), never the whole log. A gap is an
interval longer than 5 periods; stages restart after it.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from twincd.defaults import DEFAULT_ROBOT
from twincd.errors import DataError, JointMismatchError, UsageError
from twincd.io.logs import JointStates
from twincd.io.options import LogOptions
from twincd.io.stream import iter_blocks, warn_ignored_joints
from twincd.io.window import TimeWindow
from twincd.prepare.chain import (
    BuiltChain,
    JointLayout,
    build_chain,
    check_robot,
    model_joints,
    require_default_robot,
    robot_for,
    sample_bounds,
    warn_unwrapped,
)
from twincd.prepare.frames import Frame, prefetched
from twincd.prepare.progress import samples_done
from twincd.signal.checks import SignalChecks
from twincd.signal.derivatives import differentiate
from twincd.signal.features import FittedModel, ModelFeatures
from twincd.signal.filters import LowPass
from twincd.types import BoolArray, FloatArray, IndexArray, IntArray

if TYPE_CHECKING:
    from twincd.io.stream import LogStream
    from twincd.prepare.grid import GridStage
    from twincd.signal.bounds import SampleBounds
    from twincd.twin.robot import RobotModel

log = logging.getLogger("twincd")


DEFAULT_BLOCK = 16384  # samples per block: bounded memory, per-block Python cost negligible
# samples per block with the joint-torque regressor (identified models): each sample then
# carries hundreds of filtered values, and a block's copies must stay a few MB
REGRESSOR_BLOCK = 2048
# samples per block when fit sums a coarse grid's nodes (twincd.prepare.grid): the nodes' regressor
# and its products stay a few MB (16384 took fit's peak RSS from 236 to 287 MB on a 1 kHz log)
GRID_BLOCK = 8192
# samples looked at before the stages are set up: enough for a stable nominal period
PEEK_SAMPLES = 1001
# fewer usable samples than this: a log is refused, not scored (a few samples say nothing)
MIN_SAMPLES = 20


# a sample is near a segment's end (``warn_short``) where its filtered values carry this many
# times the noise of the segment's middle
SHORT_FACTOR = 1.5


@dataclass(frozen=True)
class PreparedLog:
    """One whole log ready for fitting or scoring: raw and filtered efforts in ``joint_names``
    order.

    ``effort_f`` is the paper's τ̃ and ``sim_effort_f`` its τ̂̃ (prepared for a fit: every input
    of the features through the filter). Prepared for a fitted model (scoring) it carries the
    model's residual in each band instead (``residual``, ``residual_fast``, ``predicted``,
    ``fast_off``: ``twincd.prepare.chain.build_chain``), and no ``sim_effort_f``. ``robot`` is
    None when the twin's effort came from the log itself and no model was asked for.
    """

    states: JointStates  # restricted to joint_names
    # τ̂ of every sample (None: prepared for scoring on a coarse grid, which has it on its nodes)
    sim_effort: FloatArray | None
    effort_f: FloatArray
    sim_effort_f: FloatArray | None
    robot: RobotModel | None
    simulated: bool  # False: the log carried /twincd/sim_effort
    # the filter behind effort_f: methods that filter other inputs do it alike
    lowpass: LowPass = field(default_factory=LowPass)
    period_s: float | None = None
    velocity_f: FloatArray | None = None  # q̇̃, the velocity through the same filter (friction)
    coulomb_f: FloatArray | None = None  # filtered tanh(q̇/ε), (N, E, joints), ε in coulomb_eps
    # what the chain computed for a model: the ε of ``coulomb_f``, the θ of
    # ``regressor_effort_f``
    features: ModelFeatures = field(default_factory=ModelFeatures)
    # Y(q, q̇, q̈) through the same filter, (N, joints, parameters) (identified models)
    regressor_f: FloatArray | None = None
    # Ỹθ per joint, (N, D), instead of ``regressor_f`` when prepared to score a fitted
    # identified model (its ``ModelFeatures.theta``)
    regressor_effort_f: FloatArray | None = None
    # (N, bands) each sample's edge factor: the noise of its filtered values over the segment's
    # middle (``twincd.signal.edges``; None: unfiltered)
    edge_factor: FloatArray | None = None
    # prepared for a fitted model: its residual in the filter's band and in the fast band, its
    # prediction (τ̃ − residual) and where the fast band is not judged (a velocity jump)
    residual: FloatArray | None = None
    residual_fast: FloatArray | None = None
    predicted: FloatArray | None = None
    fast_off: FloatArray | None = None
    model: FittedModel | None = None  # the fitted model of ``residual``

    @property
    def source(self) -> str:
        return self.states.source

    @property
    def coulomb_eps(self) -> tuple[float, ...]:
        return self.features.coulomb_eps

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

    @property
    def twin_f(self) -> FloatArray:
        """τ̂̃, the twin's filtered effort (a log prepared with a fit's features; a
        ``DataError`` for one prepared for scoring, which holds its model's residual)."""
        if self.sim_effort_f is None:
            raise DataError(
                "this log was prepared for scoring: it holds its model's residual, not the "
                "filtered twin effort",
                self.source,
                "prepare it with the features to fit (Setup.prepare(path, features))",
            )
        return self.sim_effort_f

    def __len__(self) -> int:
        return len(self.states)

    @property
    def samples(self) -> int:
        return len(self.states)


# ------------------------------------------------------------------ one log, streamed


def _finite_rows(frame: Frame, columns: Sequence[str], used: IndexArray) -> BoolArray:
    ok = np.ones(frame.n, dtype=bool)
    for c in columns:
        if c in frame:
            values = frame[c]
            if len(used) != values.shape[1] or np.any(used != np.arange(len(used))):
                values = values[:, used]  # only the twin's joints (a copy)
            finite = np.isfinite(values)
            if not finite.all():  # row by row only when needed (a row-wise all is slower)
                ok &= finite.all(axis=1)
    return ok


def _bounded_rows(
    bounds: SampleBounds, frame: Frame, columns: Sequence[str], used: IndexArray, ok: BoolArray
) -> BoolArray:
    """``ok`` less the rows ``bounds`` finds absurd among them (``twincd.signal.bounds``: the
    causal rule every path applies), judged on the twin's joints of ``columns``."""
    rows = None if ok.all() else np.flatnonzero(ok)
    whole = len(used) == frame["position"].shape[1] and bool(np.all(used == np.arange(len(used))))
    values = {}
    for c in columns:
        if c in frame:
            v = frame[c] if whole else frame[c][:, used]
            values[c] = v if rows is None else v[rows]
    stamps = frame["stamp_ns"] if rows is None else frame["stamp_ns"][rows]
    keep = bounds.keep(stamps, **values)
    if keep.all():
        return ok
    out: BoolArray = ok.copy()
    out[np.flatnonzero(ok)[~keep]] = False
    return out


class PreparedStream:
    """One log read, twinned and filtered block by block: a context manager whose iteration
    yields Frames with ``stamp_ns``, ``log_time_ns``, ``position``, ``velocity``, ``effort``,
    ``sim_effort`` (τ̂), ``effort_f`` (τ̃), ``sim_effort_f`` (τ̂̃) and ``labels`` (if the log has
    them), joints in ``joint_names`` order.

    ``filtered=False`` stops after the twin (what ``simulate`` writes); ``need_effort=False``
    accepts logs without measured effort. ``features``: what the chain computes for a model
    (``twincd.signal.features.ModelFeatures``: a fit's: every input filtered); with a fitted
    ``model`` (scoring), its residual in each band instead (``residual``, ``residual_fast``
    with the setup's fast band, ``predicted``, ``edge_factor``, and ``fast_off`` near a jump of
    the velocity above ``jump``: ``twincd.prepare.chain.build_chain``).

    On logs sampled far faster than the filter keeps, the twin and the filter run on a coarse
    grid (``twincd.prepare.grid``; ``grid`` is then its stage): ``nodes=True`` keeps its filtered
    nodes (``take_nodes``) for ``fit``, and the frames then carry each sample's ``node`` instead of
    the regressor's entries.
    """

    def __init__(
        self,
        path: str | Path,
        setup: Setup,
        filtered: bool = True,
        need_effort: bool = True,
        force_simulate: bool = False,
        nodes: bool = False,
        model: FittedModel | None = None,
        features: ModelFeatures | None = None,
        jump: FloatArray | None = None,
    ) -> None:
        if model is not None and features is not None:
            raise UsageError(
                "a fitted model's stream takes the model's own features",
                str(path),
                "pass the model, or features without a model",
            )
        self.path = Path(path)
        self.setup = setup
        self.filtered = filtered
        self.need_effort = need_effort
        self.force_simulate = force_simulate
        self.robot: RobotModel | None = None
        self.simulated = True
        self.joint_names: tuple[str, ...] = ()
        self.period_s = 0.0
        self.samples = 0
        self.dropped_bad = 0
        self.velocity_from_position = False
        if features is None:
            features = ModelFeatures() if model is None else model.features
        self.features = features if filtered else ModelFeatures()
        self.coulomb_eps = self.features.coulomb_eps
        self.regressor = self.features.regressor  # identified models: Y(q, q̇, q̈) filtered
        # (D, P): the regressor's entries the frames' ``regressor_f`` (N, kept) holds
        self.regressor_mask: BoolArray | None = None
        self.checks: SignalChecks | None = None
        self.near_ends = 0  # samples whose filtered values are ≥ SHORT_FACTOR× the middle's noise
        self.bounds: SampleBounds | None = None  # absurd samples (twincd.signal.bounds)
        self.nodes = nodes
        self.model = model
        self.jump = jump  # a score's jump threshold: the fast band is not judged around one
        self.grid: GridStage | None = None  # the coarse grid's stage, when there is one
        self._log: LogStream | None = None

    @property
    def source(self) -> str:
        return str(self.path)

    def __enter__(self) -> PreparedStream:

        known, known_from = self._known_joints()
        self._log = iter_blocks(
            self.path,
            self.setup.options,
            block_size=self.setup.block_size_for(self.regressor),
            strict=self.setup.strict,
            known=known,
            known_from=known_from,
        )
        self._log.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._log is not None:
            self._log.__exit__(*exc)
            self._log = None

    def _known_joints(self) -> tuple[tuple[str, ...] | None, str]:
        """The joints to read from the log when they are known before reading it: the
        calibration's (with its robot model's, so that a model joint the calibration lacks is
        refused, not ignored), else the robot model's (None: the log decides, see
        ``LogStream``)."""
        setup = self.setup
        robot = setup.robot or (DEFAULT_ROBOT if self.force_simulate else None)
        model = model_joints(robot) if robot else None
        if setup.joint_names is not None:
            return (*setup.joint_names, *(model or ())), "the calibration"
        return model, "the robot model"

    @property
    def topic(self) -> str:
        assert self._log is not None
        return str(self._log.topic)

    def _peek(self, blocks: Iterator[Any]) -> list[Any]:
        head: list[Any] = []
        n = 0
        for block in blocks:
            head.append(block)
            n += len(block.stamp_ns)
            if n >= PEEK_SAMPLES:
                break
        return head

    def _set_up(self, first: Frame) -> BuiltChain:
        """Decide, from the first samples, the twin source, the joints and the period, and
        build the chain."""
        assert self._log is not None
        names = tuple(self._log.joint_names)
        if self.need_effort:
            require_effort("effort" in first, self.source, self.topic, self._log.no_effort_why)
        twin_names, model = self._twin_source(first.get("sim_effort"), names)
        regressor = self._regressor(twin_names)
        self.joint_names = self._output_joints(twin_names)
        self._check_robot(model)
        self.period_s = self._period(first["stamp_ns"])
        layout = JointLayout(names, twin_names, self.joint_names)
        velocity = first["velocity"][:, layout.to_twin]
        fill = not bool(np.isfinite(velocity).all())
        if fill:
            warn_velocity_from_position(self.source, velocity, twin_names)
        self.velocity_from_position = fill
        robot = self.robot
        self.checks = SignalChecks(twin_names, robot.position_limits if robot else {})
        self.bounds = sample_bounds(robot, twin_names, drives_off=self.need_effort)
        setup = self.setup
        built = build_chain(
            setup.lowpass,
            self.features,
            layout,
            self.period_s,
            model,
            fill,
            regressor,
            setup.twin_threads,
            self.filtered,
            self.nodes,
            self.model,
            fast_hz=setup.fast_hz,
            jump=self.jump,
        )
        self.regressor_mask = built.regressor_mask
        self.grid = built.grid
        if built.grid is not None and self.regressor:
            # the regressor's entries are on the grid's nodes only, never on the samples
            # (fit's nodes all of them: fewer samples a block keep its sums' memory small)
            self._log.block_size = min(setup.block_size, GRID_BLOCK if self.nodes else 1 << 30)
        return built

    def take_nodes(self) -> Frame:
        """The grid's filtered nodes since the last call (with ``nodes=True``; empty without a
        grid)."""
        return Frame() if self.grid is None else self.grid.take_nodes()

    def _twin_source(
        self, sim: FloatArray | None, names: tuple[str, ...]
    ) -> tuple[tuple[str, ...], RobotModel | None]:
        """The joints the twin runs on, and the robot model that computes τ̂ (None: the log's
        own twin effort, used when the log carries it and no simulation was forced); sets
        ``robot`` (the model of those joints, if any) and ``simulated``."""
        setup = self.setup
        twin_names: tuple[str, ...] = ()
        if sim is not None and not self.force_simulate:
            # a joint has the log's twin effort when most samples carry it (a NaN here and
            # there is a bad sample, dropped later)
            have = np.flatnonzero(np.isfinite(sim).mean(axis=0) > 0.5)
            twin_names = tuple(names[i] for i in have.tolist())
        if twin_names:
            self.simulated = False
            self.robot = robot_for(setup.robot, twin_names) if setup.robot else None
            twin_names = joint_order(twin_names, self.robot)
            warn_ignored_joints(self.source, names, twin_names, "the log's twin effort")
            model = None
        else:
            if setup.robot is None:  # nobody named a robot: the default, on its own joints only
                require_default_robot(names, self.source)
            self.robot = model = robot_for(setup.robot or DEFAULT_ROBOT, names)
            twin_names = model.joint_names
            warn_ignored_joints(self.source, names, twin_names, "the robot model")
        return twin_names, model

    def _check_robot(self, model: RobotModel | None) -> None:
        """The robot model that twins (``model``) or gives the regressor must have the
        calibration's dynamics (``check_robot``), once the log's joints are known to be the
        calibration's."""
        setup = self.setup
        if self.robot is not None and (model is not None or self.regressor):
            check_robot(
                self.robot,
                setup.dynamics_sha256,
                setup.urdf_sha256,
                setup.allow_urdf_change,
                self.source,
            )

    def _regressor(self, twin_names: tuple[str, ...]) -> RobotModel | None:
        """The robot model whose joint-torque regressor the identified models need (None when
        none is asked for, or ``regressor_optional`` and no model of every joint is known)."""
        robot = self.robot
        usable = robot is not None and robot.joint_names == twin_names
        if self.regressor and not usable and self.features.regressor_optional:
            self.regressor = False  # evaluate: the identified methods are then skipped
        if not self.regressor:
            return None
        if robot is None or not usable:
            raise DataError(
                "the identified model needs the robot model of every joint (its URDF)",
                self.source,
                "name the robot the log was recorded on, or fit a model that needs no URDF "
                "(friction-whitened)",
                option="robot",
            )
        return robot

    def _output_joints(self, twin_names: tuple[str, ...]) -> tuple[str, ...]:
        """The joints out, in the calibration's order: exactly the twin's."""
        calibrated = self.setup.joint_names
        if calibrated is None:
            return twin_names
        missing = [n for n in calibrated if n not in twin_names]
        if missing:
            raise JointMismatchError(
                f"the log lacks calibrated joint(s) {', '.join(missing)}",
                self.source,
                "use a calibration made for this robot, or a joint map",
            )
        extra = [n for n in twin_names if n not in calibrated]
        if extra:
            raise JointMismatchError(
                f"the log has joint(s) {', '.join(extra)} that the calibration lacks "
                f"({len(calibrated)} joints calibrated, {len(twin_names)} in the log)",
                self.source,
                "use a calibration made for this robot, or a joint map",
            )
        return tuple(calibrated)

    def _period(self, stamp_ns: IntArray) -> float:
        """The calibration's sampling period (said when the log's differs), else the log's."""
        from twincd.signal import nominal_period

        own = nominal_period(stamp_ns)
        calibrated = self.setup.period_s
        text = other_rate(self.source, own, calibrated)
        if text is not None:
            log.warning("%s", text)
        return calibrated or own

    def __iter__(self) -> Iterator[Frame]:
        assert self._log is not None, "use PreparedStream as a context manager"
        blocks = prefetched(self._log)
        head = self._peek(blocks)
        if not head:
            raise DataError(
                "the log has no joint-state samples", self.source, "record joint states"
            )
        first = Frame.concat([_frame(b) for b in head])
        built = self._set_up(first)
        used = built.layout.to_twin
        needed = ["position", "effort"] + ([] if self.velocity_from_position else ["velocity"])
        if not self.simulated:
            needed.append("sim_effort")

        def frames() -> Iterator[Frame]:
            yield first
            for block in blocks:
                yield _frame(block)

        checks, bounds = self.checks, self.bounds
        assert checks is not None and bounds is not None

        def clean(frames_in: Iterable[Frame]) -> Iterator[Frame]:
            for frame in frames_in:
                ok = _finite_rows(frame, needed, used)
                self.dropped_bad += int((~ok).sum())
                ok = _bounded_rows(bounds, frame, needed, used, ok)
                if not ok.all():
                    frame = Frame({k: v[ok] for k, v in frame.items()})
                effort = frame.get("effort") if self.need_effort else None
                checks.push(frame["position"][:, used], None if effort is None else effort[:, used])
                yield frame

        first_ns = last_ns = None
        low, high = (
            (None, None) if self.setup.window is None
            else self.setup.window.bounds_ns(int(first["stamp_ns"][0]))
        )  # fmt: skip
        read_to = int(first["stamp_ns"][0])
        for out in built.chain.run(clean(frames())):
            if low is not None and high is not None and out.n:
                stamps = out["stamp_ns"]
                read_to = int(stamps[-1])
                if int(stamps[0]) > high:
                    break  # past the window: nothing more to judge, nor to read
                inside = (stamps >= low) & (stamps <= high)
                if not inside.any():
                    continue  # before the window: it warmed the filters
                if not inside.all():
                    out = Frame({k: v[inside] for k, v in out.items()})
            if out.n:
                first_ns = int(out["stamp_ns"][0]) if first_ns is None else first_ns
                last_ns = int(out["stamp_ns"][-1])
            self.samples += out.n
            samples_done(out.n)
            if "edge_factor" in out:
                self.near_ends += int(np.count_nonzero(out["edge_factor"][:, 0] >= SHORT_FACTOR))
            yield out
        if self.dropped_bad:
            log.warning(
                "%s: dropped %d sample(s) with NaN or infinite values",
                self.source,
                self.dropped_bad,
            )
        if self.setup.window is not None and not self.samples:
            start_ns = int(first["stamp_ns"][0])
            span = (read_to - start_ns) * 1e-9
            raise DataError(
                f"no sample of the log lies in the window {self.setup.window} (its samples run "
                f"0–{span:.3f} s from the first, whose stamp is @{start_ns * 1e-9:.3f})",
                self.source,
                "give a window within the log (seconds from its first sample, "
                "or @ and seconds since the epoch)",
                option="start,end",
            )
        bounds.warn(self.source)
        if not self.samples and bounds.off.samples:
            raise DataError(
                "every sample's efforts are exactly 0 on every joint: the drives were off "
                "throughout, or the driver measures no effort",
                self.source,
                "record the arm with its drives on and its effort measured",
            )
        require_enough_samples(self.samples, self.source)
        warn_unwrapped(self.source, built.unwrap, built.layout.twin)
        checks.warn(self.source)
        if self.filtered:
            seconds = 0.0 if first_ns is None or last_ns is None else (last_ns - first_ns) * 1e-9
            warn_short(self.source, self.samples, self.near_ends, seconds, self.setup.lowpass,
                       self.period_s)  # fmt: skip

    def read_whole(self) -> PreparedLog:
        """Every remaining frame of the stream, concatenated into one ``PreparedLog``."""
        whole = Frame.concat(list(self))
        states = JointStates(
            source=self.source,
            topic=self.topic,
            joint_names=self.joint_names,
            stamp_ns=whole["stamp_ns"],
            log_time_ns=whole["log_time_ns"],
            position=whole["position"],
            velocity=whole["velocity"],
            effort=whole["effort"],
            velocity_from_position=self.velocity_from_position,
            labels=whole.get("labels"),
            sim_effort=None if self.simulated else whole["sim_effort"],
        )
        return PreparedLog(
            states=states,
            sim_effort=whole.get("sim_effort"),
            effort_f=whole["effort_f"],
            sim_effort_f=whole.get("sim_effort_f"),
            velocity_f=whole.get("velocity_f"),
            coulomb_f=whole.get("coulomb_f"),
            features=self.features,
            regressor_f=_whole_regressor(whole.get("regressor_f"), self.regressor_mask),
            regressor_effort_f=whole.get("regressor_effort_f"),
            robot=self.robot,
            simulated=self.simulated,
            lowpass=self.setup.lowpass,
            period_s=self.period_s,
            edge_factor=whole.get("edge_factor"),
            residual=whole.get("residual"),
            residual_fast=whole.get("residual_fast"),
            predicted=whole.get("predicted"),
            fast_off=whole.get("fast_off"),
            model=self.model if "residual" in whole else None,
        )


@contextlib.contextmanager
def said_already() -> Iterator[None]:
    """Warnings off: a second pass over logs whose warnings the first pass gave (``threshold``
    counting its false alarms, ``fit`` cross-fitting)."""
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def other_rate(source: str, own_s: float, calibrated_s: float | None) -> str | None:
    """What to say of a log or a live source sampled every ``own_s`` when the calibration was
    fitted at ``calibrated_s`` (more than 5 % apart; None: the same rate, or none recorded)."""
    if not calibrated_s or own_s <= 0 or abs(own_s / calibrated_s - 1) <= 0.05:
        return None
    return (
        f"{source} is sampled every {own_s * 1e3:.4g} ms, the calibration every "
        f"{calibrated_s * 1e3:.4g} ms; its filter and gap rule follow the calibration"
    )


def edges_s(lowpass: LowPass, period_s: float) -> float:
    """How far from a segment's ends the filter's start-up leaves its values noisier than the
    middle's by ``SHORT_FACTOR`` or more (at its start only, causal): a log of twice this (once,
    causal) is near an end throughout."""
    from twincd.signal.bands import slow_band
    from twincd.signal.edges import edge_profile

    profile = edge_profile(slow_band(lowpass), period_s)
    reach = max(_reach(profile.start), _reach(profile.end)) * period_s
    return reach * (1 if lowpass.causal else 2)


def _reach(factor: FloatArray) -> int:
    above = np.flatnonzero(factor >= SHORT_FACTOR)
    return int(above[-1]) + 1 if len(above) else 0


def warn_short(
    source: str, samples: int, near_ends: int, seconds: float, lowpass: LowPass, period_s: float
) -> None:
    """A log most of whose samples lie near a segment's end is judged with the noise the
    filter's start-up leaves there, less sensitively than a longer log: say so."""
    if samples and 2 * near_ends > samples:
        log.warning(
            "%s is short (%.3g s): %d of its %d samples lie within %.3g s of a segment's end, "
            "where this filter (%g Hz) leaves at least %g× the noise of a longer log's middle: "
            "collisions there are judged less sensitively",
            source,
            seconds,
            near_ends,
            samples,
            edges_s(lowpass, period_s) / (1 if lowpass.causal else 2),
            lowpass.cutoff_hz,
            SHORT_FACTOR,
        )


def warn_velocity_from_position(
    source: str, velocity: FloatArray, joint_names: Sequence[str]
) -> None:
    """The log lacks (finite) velocities: they are differentiated from position."""
    finite = np.asarray(np.isfinite(velocity).all(axis=0), dtype=bool)
    lacking = [n for i, n in enumerate(joint_names) if not finite[i]]
    log.warning(
        "%s: velocity missing on %s; differentiated from position where missing",
        source,
        ", ".join(lacking) if lacking else "some samples",
    )


def require_effort(has_effort: bool, source: str, topic: str, why: str | None = None) -> None:
    """A log without measured effort is refused by every command that compares it with the
    twin (and by ``inspect``, which says what those would do); ``why``: what the log has that
    cannot stand in (its DynamicJointState topic without an effort interface)."""
    if not has_effort:
        raise DataError(
            "the log has no measured effort" + (f", and {why}" if why else ""),
            f"{source}, {topic}",
            "record JointState.effort (or ros2_control's effort state interface); twincd "
            "compares it with the twin",
        )


def require_enough_samples(samples: int, source: str) -> None:
    """A log with fewer than ``MIN_SAMPLES`` usable samples is refused, never scored."""
    if samples < MIN_SAMPLES:
        raise DataError(
            f"log too short: {samples} usable sample(s), at least {MIN_SAMPLES} needed",
            source,
            "record at least a few seconds",
        )


def _frame(block: Any) -> Frame:
    """A reader's SampleBlock as a Frame."""
    return Frame(
        {
            "stamp_ns": block.stamp_ns,
            "log_time_ns": block.log_time_ns,
            "position": block.position,
            "velocity": block.velocity,
            "effort": block.effort,
            "labels": block.labels,
            "sim_effort": block.sim_effort,
        }
    )


# ------------------------------------------------------------------ settings


class CalibrationSettings(Protocol):
    """What a calibration records about reading logs (``twincd.calibration.Calibration``)."""

    @property
    def options(self) -> LogOptions: ...
    @property
    def robot(self) -> str | None: ...
    @property
    def lowpass(self) -> LowPass: ...
    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def urdf_sha256(self) -> str | None: ...
    @property
    def dynamics_sha256(self) -> str | None: ...
    @property
    def period_s(self) -> float | None: ...
    @property
    def fast_hz(self) -> float | None: ...
    @property
    def source(self) -> str: ...


@dataclass(frozen=True)
class Setup:
    """How logs become prepared samples: log options, robot, filter and (optionally) joint
    order and sampling period, all taken from a calibration when there is one. What a model
    needs besides (its features, its learned values) comes from the model
    (``PreparedStream``'s ``model`` or ``features``), never from here.

    ``robot`` None means: use a log's own simulated effort, else simulate with the default
    robot model.
    """

    options: LogOptions = field(default_factory=LogOptions)
    robot: str | None = None
    lowpass: LowPass = field(default_factory=LowPass)
    joint_names: tuple[str, ...] | None = None
    urdf_sha256: str | None = None  # the calibration's (its file's bytes; older files)
    allow_urdf_change: bool = False  # other dynamics (a changed URDF) get a warning instead
    period_s: float | None = None  # the calibration's sampling period
    block_size: int = DEFAULT_BLOCK
    # False: a truncated log is read up to the damage, with one warning (contract: Inputs)
    strict: bool = False
    twin_threads: int | None = None  # None: every core this process may use
    # the fast band's upper cut-off (None: the filter's band only; twincd.signal.bands): as far
    # as the sampling rate allows (a calibration records the one it was fitted with)
    fast_hz: float | None = None
    # the calibration's robot dynamics (``RobotModel.dynamics_sha256``): other ones are refused
    dynamics_sha256: str | None = None
    # the stretch of each log judged (``twincd.io.window``; None: all of it): the run's own,
    # never a calibration's
    window: TimeWindow | None = None

    def block_size_for(self, regressor: bool) -> int:
        """Samples per block read: fewer when the regressor is filtered (``REGRESSOR_BLOCK``)."""
        return min(self.block_size, REGRESSOR_BLOCK) if regressor else self.block_size

    @classmethod
    def from_calibration(cls, calibration: CalibrationSettings) -> Setup:
        """What ``calibration`` learned (filter, joints, period, the robot's dynamics) with its
        recorded way of reading logs (topics, joint names, the robot's URDF) as it is: a run
        may read its logs otherwise (``twincd.SetupOptions.resolve``)."""
        return cls(
            options=calibration.options,
            robot=calibration.robot,
            lowpass=calibration.lowpass,
            joint_names=calibration.joint_names,
            urdf_sha256=calibration.urdf_sha256,
            period_s=calibration.period_s,
            fast_hz=calibration.fast_hz,
            dynamics_sha256=calibration.dynamics_sha256,
        )

    def check_against(self, calibration: CalibrationSettings) -> None:
        """A ``UsageError`` when this setup contradicts what ``calibration`` learned (filter,
        joints, period, the robot's dynamics): a calibration judges only logs prepared its way,
        and a contradiction is never silently resolved either way. How a recording is read
        (topics, joint names, where the URDF is) belongs to the run and is not compared; the
        robot's dynamics are checked by content as logs are read (``check_robot``)."""
        recorded = Setup.from_calibration(calibration)
        differ = [
            name
            for name, given, was in (
                ("filter", self.lowpass, recorded.lowpass),
                ("joint_names", self.joint_names, recorded.joint_names),
                ("period_s", self.period_s, recorded.period_s),
                ("fast band", self.fast_hz, recorded.fast_hz),
                ("urdf_sha256", self.urdf_sha256, recorded.urdf_sha256),
                ("dynamics_sha256", self.dynamics_sha256, recorded.dynamics_sha256),
            )
            if given != was
        ]
        if differ:
            raise UsageError(
                f"the setup's {', '.join(differ)} contradict(s) the calibration's",
                calibration.source or "calibration",
                "read logs with the calibration's settings (Setup.from_calibration, or "
                "SetupOptions.resolve(calibration))",
            )

    def for_logs(self, paths: Sequence[str | Path]) -> Setup:
        """This setup for one run over ``paths``: a named log option that none of them has is
        an error; one that some lack is said and read as unnamed there
        (``twincd.io.named.settle_named``)."""
        from dataclasses import replace

        from twincd.io.named import settle_named

        return replace(self, options=settle_named([Path(p) for p in paths], self.options))

    def open(self, path: str | Path, **kwargs: Any) -> PreparedStream:
        """Stream one log (a context manager; iterate it for Frames)."""
        return PreparedStream(path, self, **kwargs)

    def prepare(
        self,
        path: str | Path,
        features: ModelFeatures | None = None,
        model: FittedModel | None = None,
        jump: FloatArray | None = None,
    ) -> PreparedLog:
        """One whole log in memory (for the baselines, evaluate's fitted methods, studies),
        with ``features`` filtered (a fit's), or prepared for scoring with a fitted ``model``
        (its residual in each band; ``jump``: the score's, ``PreparedStream``)."""
        with self.open(path, features=features, model=model, jump=jump) as stream:
            return stream.read_whole()

    def prepare_all(
        self, paths: Iterable[str | Path], features: ModelFeatures | None = None
    ) -> Iterator[PreparedLog]:
        """Prepare logs lazily, each on its own (see ``joint_order``; ``agreed_joints`` checks
        that they agree)."""
        for path in paths:
            yield self.prepare(path, features)


def prepare_log(
    path: str | Path, setup: Setup, features: ModelFeatures | None = None
) -> PreparedLog:
    """``setup.prepare(path, features)``: the per-log step of ``evaluate``, for any
    executor."""
    return setup.prepare(path, features)


def read_log(path: str | Path, options: LogOptions | None = None) -> JointStates:
    """Read one log's joint states, labels and (if present) simulated effort, unfiltered.

    The whole log in memory: a concatenation of ``iter_blocks``' sample blocks (sorted by
    stamp, duplicates and incomplete samples dropped), velocity differentiated from position
    where the messages carry none.
    """
    options = options or LogOptions()
    path = Path(path)
    with iter_blocks(path, options, strict=True) as stream:
        blocks = list(stream)
        topic, names = stream.topic, stream.joint_names
        has_labels, has_sim = stream.has_labels, stream.has_sim

    def cat(field: str) -> Any:
        return np.concatenate([getattr(b, field) for b in blocks])

    stamp, log_time, position, velocity = (
        cat(f) for f in ("stamp_ns", "log_time_ns", "position", "velocity")
    )
    effort = None if blocks[0].effort is None else cat("effort")
    t_s = (stamp - stamp[0]).astype(np.float64) * 1e-9
    from_position = not np.isfinite(velocity).all()
    if from_position:
        from twincd.signal.unwrap import unwrap_positions

        unwrapped = unwrap_positions(stamp, position)
        velocity = np.where(np.isfinite(velocity), velocity, differentiate(t_s, unwrapped))
    has_effort = effort is not None and bool(np.isfinite(effort).all())
    return JointStates(
        source=str(path),
        topic=topic,
        joint_names=names,
        stamp_ns=stamp,
        log_time_ns=log_time,
        position=position,
        velocity=velocity,
        effort=effort if has_effort else None,
        velocity_from_position=from_position,
        labels=cat("labels") if has_labels else None,
        sim_effort=cat("sim_effort") if has_sim else None,
    )


# ------------------------------------------------------------------ joint order


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


def _whole_regressor(compact: FloatArray | None, mask: BoolArray | None) -> FloatArray | None:
    """The (N, D, P) regressor with zeros outside ``mask``, from the frames' (N, kept)."""
    if compact is None or mask is None:
        return None
    whole = np.zeros((len(compact), *mask.shape))
    whole[:, mask] = compact
    return whole
