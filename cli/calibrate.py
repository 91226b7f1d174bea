"""``twincd fit`` and ``twincd threshold``: the paper's regression and its μ + kσ threshold."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from twincd.defaults import DEFAULT_FALSE_ALARMS_PER_HOUR, DEFAULT_K_SIGMA

from .common import command, finish, json_document, stdout
from .options import (
    FILTER,
    GIVEN,
    RECORDING,
    WINDOW,
    CalibrationIn,
    Force,
    Json,
    Logs,
    Report,
    reads,
)

if TYPE_CHECKING:
    from twincd.calibration import Calibration, Threshold
    from twincd.commands import RunOptions
    from twincd.prepare.settings import SetupOptions


Model = Annotated[
    str | None,
    typer.Option(
        "--model",
        help="Calibration model (default: the best the logs allow, identified-whitened "
        "with a robot model, friction-whitened with only a logged twin effort): affine "
        "(the paper's a·twin + b), affine-whitened, friction (+ c·tanh(q̇/ε) + d·q̇), "
        "identified (+ the URDF's inertial parameters re-fitted through the joint-torque "
        "regressor; needs a robot model); *-whitened: each joint's residual over its noise "
        "at its speed, scored by depth.",
    ),
]
CalibrationOut = Annotated[Path, typer.Option("--output", "-o", help="Calibration JSON to write.")]
Sigma = Annotated[
    float | None,
    typer.Option(
        "--sigma",
        "-k",
        help="The paper's threshold μ + kσ, mean and standard deviation (default: a "
        f"budget of {DEFAULT_FALSE_ALARMS_PER_HOUR:g} false alarm per hour for the whitened "
        f"models, μ + {DEFAULT_K_SIGMA:g}σ for the others).",
        min=0,
    ),
]
FalseAlarmsPerHour = Annotated[
    float | None,
    typer.Option(
        "--false-alarms-per-hour",
        help="The false-alarm budget per hour of collision-free time that the threshold "
        "keeps, extrapolated from the tail of the score's excursions on the validation "
        f"logs (default {DEFAULT_FALSE_ALARMS_PER_HOUR:g} for the whitened models).",
    ),
]
ThresholdOut = Annotated[
    Path | None,
    typer.Option("--output", "-o", help="Write here instead of rewriting -c in place."),
]


def fit_table(cal: Calibration) -> Table:
    held = cal.fit.held or ((),) * len(cal.joint_names)
    c = cal.model.coefficients()
    a, b, cs, ds, eps = c["a"], c["b"], c.get("c"), c.get("d"), c.get("epsilon")
    assert a is not None and b is not None
    caption = (
        "* held: not determined by these logs' motion (see the warning above); θ*: the "
        "joint's inertial parameters held at the URDF's"
        if any("theta" in h for h in held)
        else "* held: not determined by these logs' motion (see the warning above)"
        if any(held)
        else None
    )
    title = f"{cal.model.kind} twin calibration ({cal.fit.samples} samples)"
    table = Table(title=title, caption=caption)
    friction = cs is not None and ds is not None and eps is not None
    extra = ("c (N·m)", "d (N·m·s)", "ε (rad/s)") if friction else ()
    for col in ("joint", "a", "b", *extra, "R²", "RMSE (N·m)"):
        table.add_column(col, justify="left" if col == "joint" else "right")
    for i, name in enumerate(cal.joint_names):
        r2 = "n/a" if cal.model.r2_ is None else f"{cal.model.r2_[i]:.3f}"
        rmse = "n/a" if cal.model.rmse_ is None else f"{cal.model.rmse_[i]:.3g}"

        def mark(key: str, text: str, i: int = i) -> str:
            return f"{text}*" if key in held[i] else text

        more = []
        if cs is not None and ds is not None and eps is not None:
            more = [
                mark("c", f"{cs[i]:+.3f}"),
                mark("d", f"{ds[i]:+.3f}"),
                f"{eps[i]:g}",
            ]
        joint = mark("theta", f"{name} θ") if "theta" in held[i] else name
        table.add_row(joint, mark("a", f"{a[i]:.3f}"), f"{b[i]:+.3f}", *more, r2, rmse)
    return table


@command
@reads(*RECORDING, *FILTER, *WINDOW, run=True)
def fit(
    logs: Logs,
    output: CalibrationOut = Path("calibration.json"),
    report: Report = None,
    asked: SetupOptions = GIVEN,
    model: Model = None,
    run: RunOptions = GIVEN,
    force: Force = False,
) -> None:
    """Fit the twin to the robot: per joint, how the measured effort follows the twin's.

    Without --model, the best model the logs allow: identified-whitened with a robot model
    (measured ≈ a·twin + Yθ + b + friction, the URDF's inertial parameters re-fitted, scored by
    the depth statistic), friction-whitened with only a logged twin effort; --model affine is
    the paper's measured ≈ a·twin + b.

    Give collision-free logs of the arm moving; samples labelled as collisions are left out.
    Logs in which no joint moves are refused; coefficients the motion does not determine are
    held (a = 1, friction 0) and said.

    Writes a calibration JSON (the model, filter, log options) for threshold, detect, evaluate.

    Example: twincd fit logs/train/*.mcap -o calibration.json
    """
    from twincd.commands import fit_calibration

    done = fit_calibration(
        logs, model=model, output=output, report=report, force=force, **run, **asked.keywords()
    )  # fmt: skip
    stdout.print(fit_table(done.calibration))
    finish(done)


@command
@reads(*RECORDING, *WINDOW, "allow_urdf_change", run=True)
def threshold(
    logs: Logs,
    calibration: CalibrationIn,
    sigma: Sigma = None,
    false_alarms_per_hour: FalseAlarmsPerHour = None,
    output: ThresholdOut = None,
    json_: Json = False,
    asked: SetupOptions = GIVEN,
    run: RunOptions = GIVEN,
    force: Force = False,
) -> None:
    """Set the detection threshold from the score on collision-free logs: by default, for the
    whitened models, the threshold that keeps a budget of 1 false alarm per hour of
    collision-free time (--false-alarms-per-hour sets another), extrapolated from the score's
    excursions (its interval is printed and stored); the paper's μ + kσ with -k, and by default
    for the affine model.

    Give collision-free validation logs other than those given to fit, of the motion fit
    saw: logs the calibration does not fit (an arm at rest, another effort scale or sign) are
    refused.

    The calibration file is rewritten atomically (or written to -o). One line says the
    threshold; --json prints the details as one JSON document.

    Example: twincd threshold logs/val/*.mcap -c calibration.json

    Or: twincd threshold logs/val -c calibration.json --false-alarms-per-hour 1
    """
    from twincd.commands import threshold_calibration

    done = threshold_calibration(
        logs, calibration, k_sigma=sigma,
        false_alarms_per_hour=false_alarms_per_hour,
        output=output or calibration, force=force, **run, **asked.keywords()
    )  # fmt: skip
    if json_:
        json_document(done, done.to_dict())
    else:
        stdout.print(threshold_line(done.calibration.require_threshold()), soft_wrap=True)
    finish(done)


def threshold_line(th: Threshold) -> str:
    """What ``threshold`` prints: the threshold, the rule that set it and what it gave on its
    own logs, in one short line (the details: ``--json``, and the calibration's
    ``threshold``)."""
    if th.tail is not None:
        tail = th.tail
        high = "∞" if tail.high is None else f"{tail.high:.4g}"
        rule = (
            f"budget {th.budget_per_hour or tail.per_hour:g} false alarm/h, "
            f"{100 * tail.confidence:.0f} % interval "
            f"{tail.low:.4g}–{high}"
        )
    else:
        mu, sigma = ("median", "σ (MAD)") if th.estimator == "median-mad" else ("μ", "σ")
        rule = f"μ + {th.k_sigma:g}σ, {mu} {th.mu:.4g}, {sigma} {th.sigma:.4g}"
    logs = f"{len(th.logs)} log{'' if len(th.logs) == 1 else 's'}"
    if th.judged_s is None or th.false_alarms is None:
        return f"threshold {th.value:.4g} ({rule}); {logs}"
    alarms = f"{th.false_alarms} false alarm{'' if th.false_alarms == 1 else 's'}"
    return (
        f"threshold {th.value:.4g} ({rule}); {alarms} in {_duration(th.judged_s)} of clean "
        f"data, {logs}"
    )


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"
