"""``fit`` over many logs: each log streamed block by block into mergeable statistics."""

from __future__ import annotations

import logging
import math
import statistics
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from twincd.calibration.affine import fit_rows, solve, warn_ill_conditioned
from twincd.calibration.crossfit import FOLD_BLOCK_S, MAX_FOLDS, Folds, VelocitySteps
from twincd.calibration.crossfit import time_folds as crossfit_folds
from twincd.calibration.excitation import check_motion, independent_samples
from twincd.calibration.file import Calibration, calibration_from_fit
from twincd.calibration.models import (
    EPSILON_GRID,
    FRICTION_WHITENED,
    IDENTIFIED_WHITENED,
    SPEED_BINS,
    FitStats,
    ResidualModel,
    depth_order,
    fit_features,
    make_model,
    model_class,
    speed_bin,
)
from twincd.errors import DataError, UsageError
from twincd.executors.run import Each
from twincd.prepare.frames import Frame
from twincd.prepare.joints import agreed_joints
from twincd.prepare.setup import Setup
from twincd.prepare.stream import PreparedStream
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.types import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from twincd.prepare.frames import FrameSink

log = logging.getLogger("twincd")


@dataclass(frozen=True)
class LogFit:
    """What one log contributes to a fit: small, picklable, mergeable (the per-log step)."""

    source: str
    stats: FitStats
    joint_names: tuple[str, ...]
    period_s: float
    simulated: bool
    # (name, URDF sha256, dynamics sha256, package URI or "") when a model was used
    robot: tuple[str, str, str, str] | None
    seconds: float  # time spent in the regression sums, as the paper times training
    samples: int = 0  # every sample read (labelled ones too): what progress counts
    labelled: bool = True  # the log has collision labels (else every sample is taken as clean)
    # with time folds (a one-log fit, ``twincd.calibration.crossfit``): the statistics of each
    # fold's samples (``stats`` is their sum), and the log's first stamp the folds start at
    folds: tuple[FitStats | None, ...] = ()
    first_ns: int = 0
    # one-period velocity changes: the jump threshold
    steps: VelocitySteps = field(default_factory=VelocitySteps)


def fit_log(
    path: str | Path,
    setup: Setup,
    sinks: Sequence[FrameSink] = (),
    features: ModelFeatures | None = None,
    time_folds: bool = False,
) -> LogFit:
    """Stream one log through read → twin → filter into the statistics of the model kinds
    ``features`` prepares for (``fit_features``; None: the best model's, every kind's);
    every frame also goes to ``sinks`` (e.g. what a report's figure draws). On a coarse grid
    (``twincd.prepare.grid``: a 1 kHz log) the sums run over the grid's nodes, each standing for the
    samples of its cell (``FitStats.from_cells``). ``time_folds``: the statistics of each of
    the log's time folds apart (a one-log fit's cross-fitting, ``twincd.calibration.crossfit``).
    """
    folds: list[FitStats | None] = [None] * (MAX_FOLDS if time_folds else 1)
    seconds = 0.0
    labelled = False
    steps = VelocitySteps()
    first_ns: int | None = None
    features = fit_features(None) if features is None else features
    speed = features.speed_stats
    with setup.open(path, nodes=True, features=features) as stream:
        cells = _Cells()
        for frame in stream:
            labelled |= "labels" in frame
            start = time.perf_counter()
            first_ns = int(frame["stamp_ns"][0]) if first_ns is None else first_ns
            clean = fit_rows(frame.get("labels"), frame.n, frame.get("edge_factor"))
            steps = steps + VelocitySteps.of(
                frame["velocity"][clean], frame["stamp_ns"][clean], stream.period_s
            )
            fold = crossfit_folds(frame["stamp_ns"], first_ns) if time_folds else None
            # the stream knows its regressor's entries once its first block is read
            eps, mask = stream.coulomb_eps, stream.regressor_mask
            if "node" in frame:
                parts = cells.stats(frame, clean, stream.take_nodes(), eps, mask, speed, fold)
            else:
                parts = _per_fold(clean, fold, partial(_sample_stats, frame, eps, mask, speed))
            folds = [_add(mine, theirs) for mine, theirs in zip(folds, parts, strict=True)]
            seconds += time.perf_counter() - start
            for sink in sinks:
                sink.write(frame, [])
        kept = [f for f in folds if f is not None]
        assert kept  # the stream raises on logs without samples
        stats = ResidualModel.merge(kept)
        cutoff = setup.lowpass.cutoff_hz
        stats = replace(
            stats, independent=independent_samples(stats.affine.n, cutoff, stream.period_s)
        )
        return LogFit(
            source=stream.source,
            stats=stats,
            joint_names=stream.joint_names,
            period_s=stream.period_s,
            simulated=stream.simulated,
            robot=_robot_of(stream),
            seconds=seconds,
            samples=stream.samples,
            labelled=labelled,
            folds=tuple(folds) if time_folds else (),
            first_ns=first_ns or 0,
            steps=steps,
        )


def _per_fold(
    clean: BoolArray, fold: IntArray | None, stats: Callable[[BoolArray], FitStats]
) -> list[FitStats | None]:
    """``stats`` of the clean rows, or of each time fold's (``fold``: each row's) apart (None:
    a fold without clean rows in this frame)."""
    if fold is None:
        return [stats(clean)]
    out: list[FitStats | None] = []
    for k in range(MAX_FOLDS):
        rows = clean & (fold == k)
        out.append(stats(rows) if rows.any() else None)
    return out


def _sample_stats(
    frame: Frame,
    eps: tuple[float, ...],
    mask: BoolArray | None,
    speed: bool,
    rows: BoolArray,
) -> FitStats:
    """The statistics of a frame's samples at ``rows`` (no grid)."""
    return FitStats.from_inputs(ModelInputs.of(frame, eps, mask), rows, speed)


def _add(mine: FitStats | None, theirs: FitStats | None) -> FitStats | None:
    if mine is None:
        return theirs
    return mine if theirs is None else mine + theirs


class _Cells:
    """A grid's filtered nodes, kept until every sample of their cells has been counted."""

    def __init__(self) -> None:
        self.table = Frame()

    def stats(
        self,
        frame: Frame,
        clean: BoolArray,
        nodes: Frame,
        coulomb_eps: tuple[float, ...],
        regressor_mask: BoolArray | None,
        speed: bool,
        fold: IntArray | None = None,
    ) -> list[FitStats | None]:
        """The statistics of ``frame``'s clean samples, each counted at its cell's node
        (``nodes``: the grid's filtered nodes since the last call, ``ModelInputs.of``'s
        columns); with each sample's time ``fold``, each fold's apart (``_per_fold``)."""
        table = self.table = Frame.concat([self.table, nodes])
        first = int(table["node"][0])
        node = np.asarray(frame["node"], dtype=np.int64) - first
        inputs = ModelInputs.of(table, coulomb_eps, regressor_mask)
        velocity = np.asarray(frame["velocity"], dtype=np.float64)

        def stats(rows: BoolArray) -> FitStats:
            at = node[rows]
            count = np.bincount(at, minlength=table.n)
            bins = speed_bin(velocity[rows])
            joints, width = bins.shape[1], len(SPEED_BINS) + 1
            cell = (at[:, None] * joints + np.arange(joints)) * width + bins
            by_speed = np.bincount(cell.ravel(), minlength=table.n * joints * width)
            by_speed = by_speed.reshape(table.n, joints, width)
            used = np.flatnonzero(count)  # a fold's nodes only (the others weigh nothing)
            if len(used) < table.n:
                picked = inputs.take(used)
                return FitStats.from_cells(picked, count[used], by_speed[used], speed)
            return FitStats.from_cells(inputs, count, by_speed, speed)

        parts = _per_fold(clean, fold, stats)
        # the last sample's cell may go on in the next frame
        self.table = table.tail(int(frame["node"][-1]) - first)
        return parts


def _robot_of(stream: PreparedStream) -> tuple[str, str, str, str] | None:
    """How the calibration names the stream's robot model: as the user gave it, by its file's
    sha256 (for older readers), by its dynamics, and by its package when it lies in one."""
    from twincd.twin.robot import package_uri

    robot = stream.robot
    if robot is None:
        return None
    package = package_uri(robot.urdf_path) or ""
    return robot.name, robot.urdf_sha256, robot.dynamics_sha256, package


def check_model(model: str | None) -> None:
    if model is not None:
        model_class(model)


def filter_kind_for(model: str | None) -> str:
    """The low-pass kind a model fits best with: an identified model's residual is at the noise
    floor, where a Butterworth filter's ringing around a push shows as alarms before and after
    it, so it (and the best model, which is identified when it can be) filters without
    overshoot."""
    return "critical" if model is None or model_class(model)[0].needs_regressor else "butterworth"


def scored_by_depth(model: str | None) -> bool:
    """Whether a fit of ``model`` (None: the best the logs allow, whitened) scores by the depth
    statistic: its noise is then cross-fitted and it judges the fast band too."""
    return model is None or model_class(model)[1]


def best_model(stats: FitStats) -> str:
    """The best model the prepared logs allow: identified and whitened when every log had the
    robot model's regressor, else friction and whitened (logs that carry their own twin effort
    and no robot model). Chosen on the real arm's rotations and synth (docs: models)."""
    return IDENTIFIED_WHITENED if stats.identified is not None else FRICTION_WHITENED


def merge_fits(parts: Iterable[LogFit], setup: Setup, model: str | None = None) -> Calibration:
    """The calibration of ``model`` (None: ``best_model``) from per-log statistics, merged in
    any order (exact merges)."""
    check_model(model)
    parts = sorted(parts, key=lambda p: p.source)  # any completion order gives one answer
    if not parts:
        raise DataError("no logs to fit", "fit", "give at least one collision-free log")
    names = agreed_joints(parts)  # from the robot model (or by name), whichever log is first
    total = ResidualModel.merge(p.stats for p in parts)
    check_motion(total.motion, names)  # before anything is said of the model
    if model is None:
        model = best_model(total)
        log.info("fit: model %s, the best these logs allow (--model affine is the paper's)", model)
    robots = sorted({p.robot for p in parts if p.robot is not None})
    name, sha, dynamics, package = robots[0] if robots else (setup.robot, None, None, None)
    links, depths = _links_and_depths(name, names)
    start = time.perf_counter()
    fitted = make_model(model, depth_order(depths, len(names)))
    fitted.joint_names_ = names
    fitted.solve(total)
    fitted.fit_s_ = sum(p.seconds for p in parts) + time.perf_counter() - start
    period = statistics.median(p.period_s for p in parts)
    # a friction model's slope a is conditioned by its other terms too: no affine warning
    if not fitted.needs_coulomb:
        affine = solve(total.affine)
        warn_ill_conditioned(names, total.affine, affine.ill_conditioned, affine.a)
    for line in fitted.held_.messages(names, fitted.kind):
        log.warning("fit: %s", line)
    r2 = fitted.r2_
    assert r2 is not None
    independent = independent_samples(total.affine.n, setup.lowpass.cutoff_hz, period)
    gain, error = twin_gain(fitted, total, independent)
    _warn_about_fit(names, fitted, gain, error, r2, [p.source for p in parts if not p.labelled])
    cal = calibration_from_fit(
        fitted,
        names,
        setup.lowpass,
        setup.options,
        name,
        sha,
        any(p.simulated for p in parts),
        [p.source for p in parts],
        period_s=period,
        dynamics_sha256=dynamics,
        robot_package=package or None,
    )
    return replace(cal, links=links, depths=depths)


def _links_and_depths(
    robot: str | None, names: tuple[str, ...]
) -> tuple[tuple[str, ...] | None, tuple[int, ...] | None]:
    """Each joint's child link and depth, when the robot model can be loaded (else None: logs
    with their own twin effort need no model, and isolation then names joints' links less)."""
    from twincd.errors import TwincdError
    from twincd.prepare.robots import robot_for
    from twincd.twin.robot import child_links

    if robot is None:
        return None, None
    try:
        return child_links(robot_for(robot, names), names)
    except TwincdError:
        return None, None


# below this on every joint, the twin explains next to none of the measured effort
LOW_R2 = 0.1
# a gain on the twin's effort is said to be negative when it is below 0 by this many standard
# errors (a gain the logs barely determine, on a joint whose twin effort hardly varies, is not)
SIGN_ERRORS = 3.0


def twin_gain(
    model: ResidualModel, stats: FitStats, independent: float
) -> tuple[FloatArray, FloatArray]:
    """(D,) the gain the fitted model puts on the twin's effort, and its standard error with
    ``independent`` samples: ``a`` for the affine and friction maps; for the identified map
    the slope of its rigid-body effort a·τ̂̃ + Ỹθ on τ̂̃ (its ``a`` alone is only the share
    left on the URDF's effort). The error is the residual's RMSE over the part of τ̂̃ the
    model's other columns do not reproduce."""
    rmse = np.asarray(model.rmse_, dtype=np.float64)
    n = max(stats.affine.n, 1)
    gain = np.asarray(model.a_, dtype=np.float64)
    spread = np.sqrt(stats.affine.cxx / n)  # the affine map: τ̂̃ against the intercept alone
    if model.needs_coulomb and stats.friction is not None:
        at = np.array([EPSILON_GRID.index(float(e)) for e in model.epsilon_])  # type: ignore[attr-defined]
        joints = np.arange(len(at))
        cross = stats.friction.cross[at, joints, :3, :3] / stats.friction.n  # (D, 3, 3)
        inverse = np.linalg.pinv(cross)
        spread = 1.0 / np.sqrt(np.maximum(inverse[:, 0, 0], 1e-300))
    theta = getattr(model, "theta_", None)
    if theta is not None and stats.identified is not None:
        cross = stats.identified.cross
        p = theta.shape[1]
        twin = np.maximum(cross[:, 0, 0], 1e-300)
        gain = (gain * cross[:, 0, 0] + np.einsum("dp,dp->d", cross[:, 0, 1 : p + 1], theta)) / twin
    error = rmse / np.maximum(spread * math.sqrt(max(independent, 1.0)), 1e-300)
    return gain, error


def _warn_about_fit(
    names: Sequence[str],
    model: ResidualModel,
    gain: FloatArray,
    error: FloatArray,
    r2: FloatArray,
    unlabelled: list[str],
) -> None:
    """Fits that are likely wrong say so (one line each), of the model that was fitted: a gain
    on the twin's effort below 0 by ``SIGN_ERRORS`` standard errors (``twin_gain``: the
    measured effort runs against the twin's, a sign or a joint map to check; not where the
    gain was held); a model that explains next to nothing (a wrong robot model or joint map);
    logs without labels whose collisions, if any, were fitted as if normal."""
    held = model.held_.a
    negative = [
        f"{n} ({g:+.3g} ± {e:.2g})"
        for n, g, e, h in zip(names, gain, error, held, strict=True)
        if not h and g + SIGN_ERRORS * e < 0
    ]
    if negative:
        what = (
            "the slope of its rigid-body effort a·twin + Yθ on the twin's"
            if getattr(model, "theta_", None) is not None
            else "its gain a on the twin's effort"
        )
        log.warning(
            "fit: the %s model's gain on the twin's effort is negative on %s (%s): the "
            "measured effort runs against the twin's there; check the robot model, the joint "
            "map and the effort sign",
            model.kind,
            ", ".join(negative),
            what,
        )
    if len(r2) and bool(np.all(np.nan_to_num(r2, nan=0.0) < LOW_R2)):
        log.warning(
            "fit: R² below %g on every joint (best %.3f): the model explains almost none of "
            "the measured effort; check the robot model and the joint map",
            LOW_R2,
            float(np.nanmax(r2)) if np.isfinite(r2).any() else 0.0,
        )
    if unlabelled:
        log.warning(
            "fit: %d log(s) have no collision labels (%s): every sample was taken as "
            "collision-free; fit on logs known to be free of collisions",
            len(unlabelled),
            unlabelled[0] + (", ..." if len(unlabelled) > 1 else ""),
        )


def crossfit_plan(parts: Sequence[LogFit]) -> Folds:
    """How the fit's logs are cross-fitted (``twincd.calibration.crossfit``): several logs in
    folds of logs, one log in folds of its time blocks (``fit_log(time_folds=True)``)."""
    if len(parts) == 1 and parts[0].folds:
        return Folds(MAX_FOLDS, first_ns=parts[0].first_ns)
    return Folds.of_logs([p.source for p in parts])  # (one log left of several: in-sample)


def fold_models(
    calibration: Calibration, parts: Sequence[LogFit], folds: Folds
) -> list[ResidualModel]:
    """For each fold, the calibration's model (kind and joints) fitted without that fold's
    data. A fold whose others cannot fit a model (the log is shorter than two time blocks, or
    they do not move) is scored by the calibration's own model, and said: its scores are then
    in-sample."""
    model = calibration.model
    names = calibration.joint_names
    out: list[ResidualModel] = []
    in_sample: list[int] = []
    for k in range(folds.count):
        if folds.by_time:
            others = [f for j, f in enumerate(parts[0].folds) if j != k and f is not None]
        else:
            others = [p.stats for p in parts if folds.groups[p.source] != k]
        try:
            if not others:
                raise DataError("no other fold", "cross-fit", "")
            fold = make_model(model.kind, model.order)
            fold.joint_names_ = names
            out.append(fold.solve(ResidualModel.merge(others)))
        except DataError:
            out.append(model)
            in_sample.append(k)
    used = {k for k in range(folds.count) if not folds.by_time or parts[0].folds[k] is not None}
    if used & set(in_sample):
        if folds.by_time:
            why = f"it holds a single {FOLD_BLOCK_S:g} s time block"
        elif folds.count == 1:
            why = "no other log is left to fit a model on"
        else:
            why = "the other logs hold too little motion"
        log.warning(
            "fit: %s cannot be scored by a model fitted without it (%s): the noise and the "
            "clean scores the calibration keeps of it are its own model's, optimistic; fit on "
            "two logs or more, or on a log of %g s or more",
            parts[0].source if len(parts) == 1 else "some of the logs",
            why,
            2 * FOLD_BLOCK_S,
        )
    return out


def fit_logs(paths: Sequence[Path], setup: Setup, model: str | None, each: Each) -> Calibration:
    """What ``fit`` makes of ``paths`` (``each`` maps a per-log step over them): every log's
    statistics (``fit_log``), the model solved from them (``merge_fits``), and for a model
    scored by depth its noise cross-fitted, with the fast band (``crossfit_calibration``)."""
    from twincd.calibration.crossfit import crossfit_calibration
    from twincd.executors.local import Bound

    crossfit = scored_by_depth(model)
    features = replace(fit_features(model), speed_stats=not crossfit)
    single = crossfit and len(paths) == 1
    work: Bound[Path, LogFit] = Bound(fit_log, setup, (), features, single)
    parts: list[LogFit] = each(work, paths, "train logs")
    calibration = merge_fits(parts, setup, model)
    return crossfit_calibration(calibration, parts, setup, each) if crossfit else calibration


def fast_cutoff(model: str | None, asked: float | None) -> float | None:
    """The fast band's upper cut-off a fit of ``model`` judges (None: none): ``asked`` (0: none)
    or, not asked, ``DEFAULT_FAST_CUTOFF_HZ`` for a model scored by depth (a strike's band,
    ``twincd.signal.bands``) and none for the others, whose score sums one band."""
    from twincd.defaults import DEFAULT_FAST_CUTOFF_HZ

    if asked is not None and (not np.isfinite(asked) or asked < 0):
        raise UsageError(
            f"fast band cut-off {asked:g} Hz is not a frequency",
            "fast_cutoff_hz",
            "give a cut-off in Hz, or 0 for no fast band",
            option="fast_cutoff_hz",
        )
    if not scored_by_depth(model):
        if asked:
            raise UsageError(
                f"model {model} sums one band: it has no fast band",
                "fast_cutoff_hz",
                "leave the fast band out, or fit a model scored by depth (the default)",
                option="fast_cutoff_hz",
            )
        return None
    if asked is None:
        return DEFAULT_FAST_CUTOFF_HZ
    return asked or None
