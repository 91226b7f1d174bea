"""``twincd detect``: score and flag every sample; list collision events; exit 1 on a finding."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from twincd.run import all_or_nothing

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.detection import DetectionSummary

from .common import (
    WARNINGS,
    check_reports,
    command,
    error_docs,
    exit_if_failed,
    run_per_log,
    stdout,
)
from .options import (
    AllowUrdfChange,
    CalibrationIn,
    Causal,
    Debug,
    Force,
    Jobs,
    JointMap,
    Json,
    Junit,
    KeepGoing,
    LabelTopic,
    Logs,
    NoSummary,
    Quiet,
    Report,
    Robot,
    Scheduler,
    SimTopic,
    Strict,
    Topic,
    setup_options,
)

log = logging.getLogger("twincd")


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


def _write_reports(
    results: list[DetectionSummary],
    cal: Calibration,
    report: Path | None,
    junit: Path | None,
    no_summary: bool,
) -> None:
    from twincd.reports import (
        append_step_summary,
        calibration_settings,
        detection_junit,
        detection_markdown,
        detection_report,
    )
    from twincd.reports.documents import write_text

    settings = calibration_settings(cal)
    if report is not None:
        detection_report(report, results, settings)
        log.info("wrote %s", report)
    if junit is not None:
        write_text(junit, detection_junit(results))
        log.info("wrote %s", junit)
    if not no_summary:
        append_step_summary(detection_markdown(results, settings))


@command
def detect(
    logs: Logs,
    calibration: CalibrationIn,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="Per-sample output: .mcap (input plus /twincd/residual, /twincd/score, "
            "/twincd/collision), .csv or .jsonl; a folder for several logs.",
        ),
    ] = None,
    json_: Json = False,
    report: Report = None,
    junit: Junit = None,
    no_summary: NoSummary = False,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    causal: Causal = None,
    jobs: Jobs = 0,
    scheduler: Scheduler = None,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    allow_urdf_change: AllowUrdfChange = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Find collisions: flag samples whose score reaches the calibrated threshold.

    Prints the collision events (contiguous flagged runs) of each log.

    Exit code 1 when any collision is found, 0 when none, 2 on errors, 3 on a defect in twincd.

    With GITHUB_STEP_SUMMARY set, a Markdown summary is appended to it (off: --no-summary).

    Example: twincd detect run.mcap -c calibration.json -o run.detect.mcap
    """
    from twincd.calibration import Calibration
    from twincd.executors import Bound
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs
    from twincd.outputs import detect_and_write, detect_targets

    cal = Calibration.load(calibration)
    cal.require_threshold()
    paths = expand_logs(logs)
    setup = setup_options(
        robot=robot,
        topic=topic,
        label_topic=label_topic,
        sim_topic=sim_topic,
        joint_map=joint_map,
        causal=causal,
        strict=strict,
        allow_urdf_change=allow_urdf_change,
    ).resolve(cal)
    setup = setup.for_logs(paths)  # a named option no log has: refused before any work
    targets = detect_targets(paths, output)
    inputs = [*paths, calibration]
    # one log at a time: only the small summaries are kept, so memory stays flat
    for target in targets:
        if target is not None:
            kind = "detect" if target.suffix.lower() == ".mcap" else "table"
            check_target(target, kind, force=force, inputs=inputs)
    check_reports(report, junit, force=force, inputs=inputs)
    trace = report is not None and report.suffix.lower() == ".html"
    items = list(zip(paths, targets, strict=True))
    with all_or_nothing() as written:
        written.extend(target for target in targets if target is not None)
        work = Bound(detect_and_write, cal, setup, trace)
        done = run_per_log(
            work, items, "detecting", quiet, jobs=jobs, scheduler=scheduler, keep_going=keep_going
        )
        results = done.results
        written.extend(p for p in (report, junit) if p is not None)
        _write_reports(results, cal, report, junit, no_summary)
    outputs = {str(path): target for path, target in items}
    for result in results:  # the per-sample outputs written, as other commands say theirs
        written_to = outputs.get(result.source)
        if written_to is not None:
            log.info("wrote %s (%d samples)", written_to, result.samples)
    summaries = [r.to_dict() for r in results]
    for result in results:
        if json_:
            continue
        if result.events:
            stdout.print(events_table(result))
        elif result.too_short:
            stdout.print(f"{result.source}: too short to judge ({result.samples} samples)")
        else:
            stdout.print(f"{result.source}: no collision ({result.samples} samples)")
    found = any(s["events"] for s in summaries)
    if json_:
        doc = {
            "collision": found,
            "threshold": cal.require_threshold().value,
            "logs": summaries,
            "errors": error_docs(done),
            "warnings": list(WARNINGS),
        }
        stdout.out(json.dumps(doc, allow_nan=False), highlight=False)
    exit_if_failed(done)
    if found:
        raise typer.Exit(1)
