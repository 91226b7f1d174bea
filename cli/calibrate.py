"""``twincd fit`` and ``twincd threshold``: the paper's regression and its μ + kσ threshold.

Also the option handling that detect and evaluate share: a calibration's recorded settings are
the defaults, and an explicit option that contradicts them is an error (contract: Inputs).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from twincd.defaults import (
    DEFAULT_CAUSAL_CUTOFF_HZ,
    DEFAULT_CUTOFF_HZ,
    DEFAULT_FALSE_ALARMS_PER_HOUR,
    DEFAULT_K_SIGMA,
    DEFAULT_ORDER,
)
from twincd.errors import UsageError

from .common import (
    AllowUrdfChange,
    Debug,
    Force,
    Jobs,
    JointMap,
    KeepGoing,
    LabelTopic,
    Logs,
    Quiet,
    Report,
    Robot,
    Scheduler,
    SimTopic,
    Strict,
    Topic,
    all_or_nothing,
    check_reports,
    command,
    log_options,
    run_per_log,
    stdout,
)

if TYPE_CHECKING:
    from twincd.calibration import Calibration, Threshold
    from twincd.pipeline import Setup

log = logging.getLogger("twincd")

CalibrationIn = Annotated[
    Path, typer.Option("--calibration", "-c", help="Calibration JSON written by `twincd fit`.")
]
Cutoff = Annotated[
    float | None,
    typer.Option(
        "--cutoff",
        help=f"Low-pass cut-off in Hz (default {DEFAULT_CUTOFF_HZ:g}; "
        f"{DEFAULT_CAUSAL_CUTOFF_HZ:g} with --causal).",
        min=0.0,
    ),
]
FilterOrder = Annotated[
    int | None,
    typer.Option("--filter-order", help=f"Low-pass filter order (default {DEFAULT_ORDER}).", min=1),
]
FilterKind = Annotated[
    str | None,
    typer.Option(
        "--filter-kind",
        help="Low-pass kind: butterworth, or critical (no overshoot, no ringing around a "
        "push). Default: butterworth; fit: critical for the identified models.",
    ),
]
Causal = Annotated[
    bool | None,
    typer.Option(
        "--causal/--zero-phase",
        help="Filter forward only, as a live detector would (default: zero-phase).",
        metavar="",
    ),
]


def _contradiction(option: str, given: object, recorded: object, calibration: Calibration) -> None:
    raise UsageError(
        f"{option} {given} contradicts the calibration's {recorded}",
        calibration.source or "calibration",
        f"drop {option}, or re-run `twincd fit` with it",
    )


def resolve_setup(
    calibration: Calibration | None,
    robot: str | None,
    topic: str | None,
    label_topic: str | None,
    sim_topic: str | None,
    joint_map: str | None,
    cutoff: float | None = None,
    filter_order: int | None = None,
    causal: bool | None = None,
    strict: bool = False,
    filter_kind: str | None = None,
    allow_urdf_change: bool = False,
) -> Setup:
    """Settings for reading logs: explicit options over the calibration's, never against them
    (``filter_kind`` None: Butterworth without a calibration)."""
    from twincd.io.options import parse_joint_map
    from twincd.pipeline import Setup
    from twincd.signal.filters import LowPass

    if calibration is None:
        default_cutoff = DEFAULT_CAUSAL_CUTOFF_HZ if causal else DEFAULT_CUTOFF_HZ
        lowpass = LowPass(
            cutoff_hz=default_cutoff if cutoff is None else cutoff,
            order=DEFAULT_ORDER if filter_order is None else filter_order,
            causal=bool(causal),
            kind="butterworth" if filter_kind is None else filter_kind,
        )
        options = log_options(topic, label_topic, sim_topic, joint_map)
        return Setup(options, robot, lowpass, strict=strict)
    cal = calibration
    recorded = cal.options
    for option, given, was in (
        ("--topic", topic, recorded.topic),
        ("--label-topic", label_topic, recorded.label_topic),
        ("--sim-topic", sim_topic, recorded.sim_topic),
    ):
        if given is not None and given != was:
            _contradiction(option, given, was, cal)
    if joint_map is not None and parse_joint_map(joint_map) != dict(recorded.joint_map or {}):
        was_map = ",".join(f"{k}={v}" for k, v in (recorded.joint_map or {}).items())
        _contradiction("--joint-map", joint_map, was_map or "empty map", cal)
    if robot is not None and cal.robot is not None and not _same_robot(robot, cal.robot):
        _contradiction("--robot", robot, cal.robot, cal)
    lp = cal.lowpass
    if causal is not None and causal != lp.causal:
        raise UsageError(
            f"{'--causal' if causal else '--zero-phase'} contradicts the calibration's "
            f"{'causal' if lp.causal else 'zero-phase'} filter",
            cal.source or "calibration",
            "drop the option, or re-run `twincd fit` with it",
        )
    for option, given_f, was_f in (
        ("--cutoff", cutoff, lp.cutoff_hz),
        ("--filter-order", filter_order, lp.order),
    ):
        if given_f is not None and given_f != was_f:
            _contradiction(option, f"{given_f:g}", f"{was_f:g}", cal)
    if filter_kind is not None and filter_kind != lp.kind:
        _contradiction("--filter-kind", filter_kind, lp.kind, cal)
    setup = replace(Setup.from_calibration(cal), strict=strict, allow_urdf_change=allow_urdf_change)
    if robot is not None and cal.robot is None:
        setup = replace(setup, robot=robot)
    return setup


def _same_robot(a: str, b: str) -> bool:
    if a == b:
        return True
    pa, pb = Path(a), Path(b)
    return pa.exists() and pb.exists() and pa.resolve() == pb.resolve()


def fit_table(cal: Calibration) -> Table:
    table = Table(title=f"{cal.kind} twin calibration ({cal.fit_samples} samples)")
    friction = cal.c is not None and cal.d is not None and cal.epsilon is not None
    extra = ("c (N·m)", "d (N·m·s)", "ε (rad/s)") if friction else ()
    for col in ("joint", "a", "b", *extra, "R²", "RMSE (N·m)"):
        table.add_column(col, justify="left" if col == "joint" else "right")
    for i, name in enumerate(cal.joint_names):
        r2 = "n/a" if cal.r2 is None else f"{cal.r2[i]:.3f}"
        rmse = "n/a" if cal.rmse is None else f"{cal.rmse[i]:.3g}"
        more = []
        if cal.c is not None and cal.d is not None and cal.epsilon is not None:
            more = [f"{cal.c[i]:+.3f}", f"{cal.d[i]:+.3f}", f"{cal.epsilon[i]:g}"]
        table.add_row(name, f"{cal.a[i]:.3f}", f"{cal.b[i]:+.3f}", *more, r2, rmse)
    return table


@command
def fit(
    logs: Logs,
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Calibration JSON to write.")
    ] = Path("calibration.json"),
    report: Report = None,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    cutoff: Cutoff = None,
    filter_order: FilterOrder = None,
    filter_kind: FilterKind = None,
    causal: Causal = None,
    model: Annotated[
        str | None,
        typer.Option(
            "--model",
            help="Calibration model: affine (the paper's a·twin + b), affine-whitened, "
            "friction (+ c·tanh(q̇/ε) + d·q̇), identified (+ the URDF's inertial parameters "
            "re-fitted through the joint-torque regressor; needs a robot model); *-whitened: "
            "each joint's residual over its noise at its speed, scored by depth "
            "[default: the best the logs allow: identified-whitened with a robot model, "
            "friction-whitened with only a logged twin effort].",
            show_default=False,
        ),
    ] = None,
    jobs: Jobs = 0,
    scheduler: Scheduler = None,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Fit the twin to the robot: per joint, measured ≈ a·twin + b (least squares).

    Give collision-free logs; samples labelled as collisions are left out.

    Writes a calibration JSON (a, b, filter, log options) for threshold, detect, evaluate.

    Example: twincd fit logs/train/*.mcap -o calibration.json
    """
    from twincd.calibration import fit_log, merge_fits
    from twincd.calibration.setup import setup_for_model
    from twincd.executors import Bound
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs

    paths = expand_logs(logs)
    check_target(output, "calibration", force=force, inputs=paths)
    check_reports(report, None, force=force, inputs=paths)
    from twincd.calibration.setup import filter_kind_for

    kind = filter_kind_for(model) if filter_kind is None else filter_kind
    setup = resolve_setup(
        None, robot, topic, label_topic, sim_topic, joint_map, cutoff, filter_order, causal,
        strict, kind,
    )  # fmt: skip
    setup = setup_for_model(setup, model)
    figure = report is not None and report.suffix.lower() == ".html"
    if figure:
        from twincd.reports.traces import fit_log_with_pairs

        work = Bound(fit_log_with_pairs, setup)
    else:
        work = Bound(fit_log, setup)
    done = run_per_log(
        work, paths, paths, jobs, "fitting", quiet, keep_going=keep_going, scheduler=scheduler
    )
    parts = [part for part, _ in done.results] if figure else done.results
    cal = merge_fits(parts, setup, model)
    with all_or_nothing() as written:  # the report, then the calibration: both or neither
        if report is not None:
            from twincd.reports import ThinnedPairs, fit_report

            pairs = ThinnedPairs.merge([p for _, p in done.results]) if figure else None
            written.append(report)
            fit_report(report, replace(cal, source=str(output)), pairs)
        cal.save(output)
    stdout.print(fit_table(cal))
    if report is not None:
        log.info("wrote %s", report)
    log.info("wrote %s (%d samples from %d log(s))", output, cal.fit_samples, len(cal.fit_logs))
    done.exit_if_failed()


@command
def threshold(
    logs: Logs,
    calibration: CalibrationIn,
    sigma: Annotated[
        float | None,
        typer.Option(
            "--sigma",
            "-k",
            help="The paper's threshold μ + kσ, mean and standard deviation [default: "
            f"μ + {DEFAULT_K_SIGMA:g}σ, robustly (median and MAD) for a whitened model].",
            min=0,
        ),
    ] = None,
    false_alarms_per_hour: Annotated[
        float | None,
        typer.Option(
            "--false-alarms-per-hour",
            help="The false-alarm budget per hour of collision-free time that the threshold "
            "keeps, extrapolated from the tail of the score's excursions on the validation "
            f"logs (e.g. {DEFAULT_FALSE_ALARMS_PER_HOUR:g}).",
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write here instead of rewriting -c in place."),
    ] = None,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    jobs: Jobs = 0,
    scheduler: Scheduler = None,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    allow_urdf_change: AllowUrdfChange = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Set the detection threshold from the score on collision-free logs: the paper's μ + kσ
    (k = 4), or with --false-alarms-per-hour the threshold that keeps a false-alarm budget per
    hour of collision-free time, extrapolated from the peaks of the score's excursions with a
    generalised Pareto tail (its interval is printed and stored).

    Give validation logs other than those given to fit.

    The calibration file is rewritten atomically (or written to -o).

    Example: twincd threshold logs/val/*.mcap -c calibration.json

    Or: twincd threshold logs/val -c calibration.json --false-alarms-per-hour 1
    """
    from twincd.calibration import Calibration
    from twincd.executors import Bound
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs
    from twincd.threshold import check_threshold_choice, score_log, with_threshold

    check_threshold_choice(sigma, false_alarms_per_hour)
    cal = Calibration.load(calibration)
    target = output or calibration
    paths = expand_logs(logs)
    check_target(target, "calibration", force=force, inputs=paths)
    setup = resolve_setup(
        cal,
        robot,
        topic,
        label_topic,
        sim_topic,
        joint_map,
        strict=strict,
        allow_urdf_change=allow_urdf_change,
    )
    work = Bound(score_log, setup, cal)
    done = run_per_log(
        work, paths, paths, jobs, "scoring", quiet, keep_going=keep_going, scheduler=scheduler
    )
    cal = with_threshold(done.results, cal, sigma, false_alarms_per_hour)
    cal.save(target)
    stdout.print(threshold_line(cal.require_threshold()), soft_wrap=True)
    log.info("wrote %s", target)
    done.exit_if_failed()


def threshold_line(th: Threshold) -> str:
    """What ``threshold`` prints: the method, the budget, the threshold and its interval."""
    line = (
        f"μ = {th.mu:.6g}  σ = {th.sigma:.6g}  threshold = μ + {th.k_sigma:.4g}σ = {th.value:.6g}"
    )
    seen = f"{th.samples} samples, {len(th.logs)} log(s)"
    tail = th.tail
    if tail is None:
        if th.estimator == "median-mad":
            line = line.replace("μ =", "μ (median) =").replace("σ =", "σ (MAD) =")
        return f"k-sigma: {line}  ({seen})"
    high = "∞" if tail.high is None else f"{tail.high:.6g}"
    hours = (th.judged_s or 0.0) / 3600.0
    return (
        f"{tail.method}: budget {tail.per_hour:g} false alarm(s)/h → {line}, "
        f"{100 * tail.confidence:.0f} % interval [{tail.low:.6g}, {high}]  "
        f"(u = {tail.level:.4g}, {tail.peaks} peaks, λ = {tail.rate_per_hour:.4g}/h, "
        f"ξ = {tail.shape:.3g}; {th.false_alarms} false alarm(s) counted in {hours:.3g} h; {seen})"
    )
