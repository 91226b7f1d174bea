"""``twincd evaluate``: the seed paper's Table II on labelled test logs (contract: Metrics,
Methods)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich import box
from rich.table import Table

from twincd.defaults import DEFAULT_REPEATS

from .common import command, finish, json_document, stdout
from .options import (
    FILTER,
    GIVEN,
    RECORDING,
    WINDOW,
    Force,
    Json,
    Logs,
    ReportOptions,
    reads,
)

if TYPE_CHECKING:
    from twincd.commands import RunOptions
    from twincd.evaluation.results import Evaluation
    from twincd.prepare.settings import SetupOptions

CalibrationMaybe = Annotated[
    Path | None,
    typer.Option(
        "--calibration",
        "-c",
        help="Calibration JSON (fit + threshold); optional when --train and --val are given.",
    ),
]
Methods = Annotated[
    str | None,
    typer.Option(
        "--methods",
        "-m",
        help="Comma-separated method names, or all [default: the calibration's own model; "
        "proposed without one]",
    ),
]
Train = Annotated[
    list[Path] | None,
    typer.Option("--train", help="Collision-free logs methods fit on (repeatable)."),
]
Val = Annotated[
    list[Path] | None,
    typer.Option("--val", help="Collision-free logs that set μ and σ (repeatable)."),
]
Sigma = Annotated[
    float | None,
    typer.Option(
        "--sigma",
        "-k",
        help=(
            "k of μ + kσ for the at-threshold figures (default: the calibration's threshold"
            " itself, else 4)."
        ),
        min=0,
    ),
]
Repeats = Annotated[
    int,
    typer.Option(
        "--repeats",
        help="Runs (seeds 0..N-1) of randomised (deep) methods; mean ± std as Table II.",
        min=1,
    ),
]
MinF1 = Annotated[
    float | None,
    typer.Option(
        "--min-f1",
        help="Exit 1 if a method's F1 at the threshold it is run at is lower (the "
        "calibration's threshold for its own model, μ + kσ of --val for the others; not the "
        "best F1 over μ + iσ).",
    ),
]
MinAuc = Annotated[
    float | None, typer.Option("--min-auc", help="Exit 1 if a method's AUC is lower.")
]


@command
@reads(*RECORDING, *FILTER, *WINDOW, "allow_urdf_change", run=True, reports=True)
def evaluate(
    logs: Logs,
    calibration: CalibrationMaybe = None,
    methods: Methods = None,
    train: Train = None,
    val: Val = None,
    sigma: Sigma = None,
    repeats: Repeats = DEFAULT_REPEATS,
    json_: Json = False,
    reports: ReportOptions = GIVEN,
    min_f1: MinF1 = None,
    min_auc: MinAuc = None,
    asked: SetupOptions = GIVEN,
    run: RunOptions = GIVEN,
    force: Force = False,
) -> None:
    """Score methods on labelled test logs: F1 over μ + iσ, F1 at threshold, ROC AUC, times.

    The positional logs are the test set; they need collision labels.

    With -c alone, proposed uses the calibration's a, b, μ and σ.

    With --train and --val, every method (proposed too) fits on --train; μ, σ come from --val.

    With GITHUB_STEP_SUMMARY set, a Markdown summary is appended to it (off: --no-summary).

    Example: twincd evaluate logs/test -c calibration.json --report report.html
    """
    from twincd.commands import evaluate_logs

    done = evaluate_logs(
        logs, calibration, methods=methods, train=train or (), val=val or (), k_sigma=sigma,
        repeats=repeats, min_f1=min_f1, min_auc=min_auc, force=force, **reports, **run,
        **asked.keywords()
    )  # fmt: skip
    if json_:
        json_document(done, done.to_dict(), allow_nan=True)
    else:
        render(done.evaluation)
    finish(done)


def render(result: Evaluation) -> None:
    """The evaluation as a person reads it: Table II, the events at the threshold, notes."""
    from twincd.evaluation.markdown import (
        SHORT_COLUMNS,
        SHORT_EVENT_COLUMNS,
        evaluation_rows,
        event_rows,
    )

    table = Table(
        title=f"{result.samples} test samples, {result.positives} labelled as collision",
        box=box.SIMPLE_HEAD,
        show_edge=False,
        padding=(0, 0),
        pad_edge=False,
        caption="* per time window" if any(m.unit != "sample" for m in result.methods) else None,
    )
    rows = [[c.replace(" + ", "+") for c in row] for row in evaluation_rows(result)]
    stdout.print(_fill(table, SHORT_COLUMNS, rows))
    events = Table(
        title="events at the threshold (FA: false alarms, count and per hour)",
        box=box.SIMPLE_HEAD,
        show_edge=False,
        padding=(0, 1),
        pad_edge=False,
    )
    stdout.print(_fill(events, SHORT_EVENT_COLUMNS, event_rows(result)))
    for m in result.methods:
        if m.note:
            stdout.print(f"note: {m.name}: {m.note}")


def _fill(table: Table, columns: Sequence[str], rows: list[list[str]]) -> Table:
    for i, col in enumerate(columns):
        width = max([len(col)] + [len(r[i]) for r in rows])
        table.add_column(col, justify="left" if i == 0 else "right", no_wrap=True, min_width=width)
    for row in rows:
        table.add_row(*row)
    return table
