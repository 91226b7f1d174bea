"""``twincd detect``: score and flag every sample; list collision events; exit 1 on a finding."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from twincd.errors import UsageError

if TYPE_CHECKING:
    from twincd.detection import DetectionSummary

from .calibrate import CalibrationIn, Causal, resolve_setup
from .common import (
    WARNINGS,
    Debug,
    Force,
    Jobs,
    JointMap,
    KeepGoing,
    LabelTopic,
    Logs,
    Quiet,
    Robot,
    SimTopic,
    Strict,
    Topic,
    all_or_nothing,
    command,
    run_per_log,
    stdout,
)

log = logging.getLogger("twincd")


def _targets(paths: list[Path], output: Path | None) -> list[Path | None]:
    """Where each log's per-sample output goes: -o itself, or a file per log in folder -o."""
    from twincd.outputs import OUTPUT_SUFFIXES

    if output is None:
        return [None] * len(paths)
    if len(paths) == 1 and output.suffix:
        if output.suffix.lower() not in OUTPUT_SUFFIXES:
            raise UsageError(
                f"unknown output type {output.suffix!r}",
                str(output),
                "end -o with .mcap, .csv or .jsonl",
            )
        return [output]
    if output.suffix:
        raise UsageError("several logs need an output folder", str(output), "give -o a folder name")
    output.mkdir(parents=True, exist_ok=True)
    return [output / f"{p.stem if p.is_file() else p.name}.detect.mcap" for p in paths]


def events_table(result: DetectionSummary) -> Table:
    t0 = result.first_stamp_ns
    table = Table(
        title=f"{result.source}: {len(result.events)} collision event(s), "
        f"{result.collision_samples}/{result.samples} samples flagged"
    )
    for col in ("#", "start (s)", "end (s)", "duration (s)", "peak score", "joint"):
        table.add_column(col, justify="left" if col == "joint" else "right")
    for i, e in enumerate(result.events, 1):
        table.add_row(
            str(i),
            f"{(e.start_ns - t0) * 1e-9:.3f}",
            f"{(e.end_ns - t0) * 1e-9:.3f}",
            f"{e.duration_s:.3f}",
            f"{e.peak_score:.4g}",
            e.joint,
        )
    return table


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
    json_: Annotated[
        bool, typer.Option("--json", help="Print one JSON document.", metavar="")
    ] = False,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    causal: Causal = None,
    jobs: Jobs = 0,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Find collisions: flag samples whose score reaches the calibrated threshold.

    Prints the collision events (contiguous flagged runs) of each log.

    Exit code 1 when any collision is found, 0 when none, 2 on errors.

    Example: twincd detect run.mcap -c calibration.json -o run.detect.mcap
    """
    from twincd.calibration import Calibration
    from twincd.executors import Bound
    from twincd.io.atomic import check_target
    from twincd.io.logs import expand_logs
    from twincd.outputs import detect_and_write

    cal = Calibration.load(calibration)
    cal.require_threshold()
    paths = expand_logs(logs)
    setup = resolve_setup(
        cal, robot, topic, label_topic, sim_topic, joint_map, causal=causal, strict=strict
    )
    targets = _targets(paths, output)
    # one log at a time: only the small summaries are kept, so memory stays flat
    for target in targets:
        if target is not None:
            kind = "detect" if target.suffix.lower() == ".mcap" else "table"
            check_target(target, kind, force=force, inputs=paths)
    items = list(zip(paths, targets, strict=True))
    with all_or_nothing() as written:
        written.extend(target for target in targets if target is not None)
        work = Bound(detect_and_write, cal, setup)
        done = run_per_log(work, items, paths, jobs, "detecting", quiet, keep_going)
    results = done.results
    summaries = [r.to_dict() for r in results]
    for result in results:
        for line in result.warnings:
            log.warning("%s", line)
        if json_:
            continue
        if result.events:
            stdout.print(events_table(result))
        else:
            stdout.print(f"{result.source}: no collision ({result.samples} samples)")
    found = any(s["events"] for s in summaries)
    if json_:
        doc = {
            "collision": found,
            "threshold": cal.require_threshold().value,
            "logs": summaries,
            "errors": done.error_docs(),
            "warnings": list(WARNINGS),
        }
        stdout.out(json.dumps(doc, allow_nan=False), highlight=False)
    done.exit_if_failed()
    if found:
        raise typer.Exit(1)
