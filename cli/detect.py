"""``twincd detect``: score and flag every sample; list collision events; exit 1 on a finding."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

if TYPE_CHECKING:
    from twincd.commands import RunOptions
    from twincd.detection import DetectionSummary
    from twincd.prepare.settings import SetupOptions

from .common import command, finish, json_document, stdout
from .options import (
    GIVEN,
    RECORDING,
    WINDOW,
    CalibrationIn,
    Force,
    Json,
    Logs,
    ReportOptions,
    reads,
)

DetectOut = Annotated[
    Path | None,
    typer.Option(
        "--output",
        "-o",
        help="Per-sample output: .mcap (input plus /twincd/residual, /twincd/score, "
        "/twincd/collision), .csv or .jsonl; a folder for several logs.",
    ),
]


def events_table(result: DetectionSummary) -> Table:
    from twincd.reports.tables import event_columns, event_rows

    table = Table(
        title=f"{result.source}: {len(result.events)} collision event(s), "
        f"{result.collision_samples}/{result.samples} samples flagged"
    )
    for col in event_columns(result):
        table.add_column(col, justify="left" if col in ("joint", "link") else "right")
    for row in event_rows(result):
        table.add_row(*row)
    return table


@command
@reads(*RECORDING, "causal", *WINDOW, "allow_urdf_change", run=True, reports=True)
def detect(
    logs: Logs,
    calibration: CalibrationIn,
    output: DetectOut = None,
    json_: Json = False,
    reports: ReportOptions = GIVEN,
    asked: SetupOptions = GIVEN,
    run: RunOptions = GIVEN,
    force: Force = False,
) -> None:
    """Find collisions: flag samples whose score reaches the calibrated threshold.

    Prints the collision events (contiguous flagged runs) of each log.

    Exit code 1 when any collision is found, 0 when none, 2 on errors, 3 on a defect in twincd.

    With GITHUB_STEP_SUMMARY set, a Markdown summary is appended to it (off: --no-summary).

    Example: twincd detect run.mcap -c calibration.json -o run.detect.mcap
    """
    from twincd.commands import detect_files

    done = detect_files(
        logs, calibration, output=output, force=force, **reports, **run, **asked.keywords()
    )  # fmt: skip
    if json_:
        json_document(done, done.to_dict())
    for result in [] if json_ else done.logs:
        coverage = result.coverage()
        if result.events:
            stdout.print(events_table(result))
            if coverage:
                stdout.print(f"{result.source}: {coverage}")
        elif result.too_short:
            stdout.print(f"{result.source}: too short to judge ({result.samples} samples)")
        else:
            more = f"; {coverage}" if coverage else ""
            stdout.print(f"{result.source}: no collision ({result.samples} samples{more})")
    finish(done)
