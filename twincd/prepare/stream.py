"""One log streamed block by block (``Setup.open``, a ``PreparedStream``): read, its bad and
absurd rows dropped (``_finite_rows``, ``_bounded_rows``), sent down the chain of
``twincd.prepare.chain`` (twin, or the log's own ``/twincd/sim_effort``, then the low-pass
filter) and cropped to the setup's window, at flat memory whatever the log's length (what
``fit``, ``threshold``, ``detect``, ``simulate`` and ``evaluate``'s calibration model use).

The stream decides from the log's first samples (``PEEK_SAMPLES``) the twin's source, the
joints and the nominal period, then builds the chain; at its end it says what it found
(``twincd.prepare.notices``).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from twincd.defaults import DEFAULT_ROBOT
from twincd.errors import DataError, JointMismatchError, UsageError
from twincd.io.logs import JointStates
from twincd.io.stream import iter_blocks, warn_ignored_joints
from twincd.prepare.chain import BuiltChain, JointLayout, build_chain
from twincd.prepare.frames import Frame, prefetched
from twincd.prepare.joints import joint_order
from twincd.prepare.notices import (
    SHORT_FACTOR,
    gap_ns,
    judged_period,
    refuse_gapped,
    require_effort,
    require_enough_samples,
    warn_short,
    warn_unwrapped,
    warn_velocity_from_position,
)
from twincd.prepare.prepared import PreparedLog
from twincd.prepare.progress import samples_done
from twincd.prepare.robots import (
    check_robot,
    model_joints,
    require_default_robot,
    robot_for,
    sample_bounds,
)
from twincd.signal.checks import SignalChecks
from twincd.signal.features import FittedModel, ModelFeatures
from twincd.types import BoolArray, FloatArray, IndexArray, IntArray

if TYPE_CHECKING:
    from twincd.io.stream import LogStream
    from twincd.prepare.grid import GridStage
    from twincd.prepare.setup import Setup
    from twincd.signal.bounds import SampleBounds
    from twincd.twin.robot import RobotModel

log = logging.getLogger("twincd")


# samples per block when fit sums a coarse grid's nodes (twincd.prepare.grid): the nodes' regressor
# and its products stay a few MB (16384 took fit's peak RSS from 236 to 287 MB on a 1 kHz log)
GRID_BLOCK = 8192
# samples looked at before the stages are set up: enough for a stable nominal period
PEEK_SAMPLES = 1001


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
        self._read_to_ns = 0  # how far the log was read (a window none of it lies in says it)

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
            layout=layout,
            period_s=self.period_s,
            twin=model,
            fill_velocity=fill,
            regressor=regressor,
            threads=setup.twin_threads,
            filtered=self.filtered,
            nodes=self.nodes,
            model=self.model,
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
        """The period the log is judged at (``judged_period``)."""
        from twincd.signal import nominal_period

        return judged_period(self.source, nominal_period(stamp_ns), self.setup.period_s)

    def __iter__(self) -> Iterator[Frame]:
        assert self._log is not None, "use PreparedStream as a context manager"
        blocks = prefetched(self._log)
        first = self._first_samples(blocks)
        built = self._set_up(first)
        start_ns = int(first["stamp_ns"][0])
        first_ns = last_ns = None
        cleaned = self._cleaned(first, blocks, built.layout.to_twin)
        gap, gapped = gap_ns(self.period_s), 0
        for out in self._windowed(built.chain.run(cleaned), start_ns):
            if out.n:
                stamps = out["stamp_ns"]
                steps = np.diff(stamps) if last_ns is None else np.diff(stamps, prepend=last_ns)
                gapped += int(np.count_nonzero(steps > gap))
                first_ns = int(stamps[0]) if first_ns is None else first_ns
                last_ns = int(stamps[-1])
            self.samples += out.n
            samples_done(out.n)
            if "edge_factor" in out:
                self.near_ends += int(np.count_nonzero(out["edge_factor"][:, 0] >= SHORT_FACTOR))
            yield out
        seconds = 0.0 if first_ns is None or last_ns is None else (last_ns - first_ns) * 1e-9
        refuse_gapped(self.source, gapped, max(self.samples - 1, 0), self.setup.period_s)
        self._finish(built, start_ns, seconds)

    def _first_samples(self, blocks: Iterator[Any]) -> Frame:
        """The log's first blocks, up to ``PEEK_SAMPLES`` samples: what the chain is set up
        from (a ``DataError`` for a log without any)."""
        head = self._peek(blocks)
        if not head:
            raise DataError(
                "the log has no joint-state samples", self.source, "record joint states"
            )
        return Frame.concat([_frame(b) for b in head])

    def _cleaned(self, first: Frame, blocks: Iterator[Any], used: IndexArray) -> Iterator[Frame]:
        """``first`` and the frames of the remaining ``blocks``, less their rows with a NaN or
        infinite value (counted in ``dropped_bad``) or an absurd one (``bounds``) in a column
        every sample needs, judged on the twin's joints (``used``); ``checks`` sees the rows
        kept."""
        checks, bounds = self.checks, self.bounds
        assert checks is not None and bounds is not None
        needed = ["position", "effort"] + ([] if self.velocity_from_position else ["velocity"])
        if not self.simulated:
            needed.append("sim_effort")
        for frame in itertools.chain([first], map(_frame, blocks)):
            ok = _finite_rows(frame, needed, used)
            self.dropped_bad += int((~ok).sum())
            ok = _bounded_rows(bounds, frame, needed, used, ok)
            if not ok.all():
                frame = Frame({k: v[ok] for k, v in frame.items()})
            effort = frame.get("effort") if self.need_effort else None
            checks.push(frame["position"][:, used], None if effort is None else effort[:, used])
            yield frame

    def _windowed(self, frames: Iterable[Frame], start_ns: int) -> Iterator[Frame]:
        """``frames`` cropped to the setup's window (all of them without one): those before it
        only warm the filters, and reading stops past it; ``_read_to_ns`` follows how far the
        log was read."""
        self._read_to_ns = start_ns
        if self.setup.window is None:
            yield from frames
            return
        low, high = self.setup.window.bounds_ns(start_ns)
        for out in frames:
            if out.n:
                stamps = out["stamp_ns"]
                self._read_to_ns = int(stamps[-1])
                if int(stamps[0]) > high:
                    return  # past the window: nothing more to judge, nor to read
                inside = (stamps >= low) & (stamps <= high)
                if not inside.any():
                    continue  # before the window: it warmed the filters
                if not inside.all():
                    out = Frame({k: v[inside] for k, v in out.items()})
            yield out

    def _finish(self, built: BuiltChain, start_ns: int, seconds: float) -> None:
        """What the whole log read says (rows dropped, absurd samples, unwrapped positions,
        the signal checks, a short log), and the refusal of a log with too few usable samples
        (none in the window, the drives off throughout, fewer than ``MIN_SAMPLES``)."""
        checks, bounds = self.checks, self.bounds
        assert checks is not None and bounds is not None
        if self.dropped_bad:
            log.warning(
                "%s: dropped %d sample(s) with NaN or infinite values",
                self.source,
                self.dropped_bad,
            )
        if self.setup.window is not None and not self.samples:
            span = (self._read_to_ns - start_ns) * 1e-9
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


def _whole_regressor(compact: FloatArray | None, mask: BoolArray | None) -> FloatArray | None:
    """The (N, D, P) regressor with zeros outside ``mask``, from the frames' (N, kept)."""
    if compact is None or mask is None:
        return None
    whole = np.zeros((len(compact), *mask.shape))
    whole[:, mask] = compact
    return whole
