"""``twincd detect``: score and flag every sample; list collision events; exit 1 on a finding."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from twincd.calibration import Calibration
from twincd.detection import LogDetection
from twincd.detection import detect as detect_log
from twincd.errors import UsageError
from twincd.io.logs import expand_logs
from twincd.io.mcap_write import check_writable
from twincd.outputs import OUTPUT_SUFFIXES, write_detection

from .calibrate import CalibrationIn, resolve_setup
from .common import (
    Debug,
    JointMap,
    LabelTopic,
    Logs,
    Quiet,
    Robot,
    SimTopic,
    Topic,
    all_or_nothing,
    command,
    progress,
    stdout,
)


def _targets(paths: list[Path], output: Path | None) -> list[Path | None]:
    """Where each log's per-sample output goes: -o itself, or a file per log in folder -o."""
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


def events_table(result: LogDetection) -> Table:
    t0 = int(result.log.states.stamp_ns[0])
    table = Table(
        title=f"{result.source}: {len(result.events)} collision event(s), "
        f"{int(result.flags.sum())}/{len(result.scores)} samples flagged"
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
    json_: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Find collisions: flag samples whose score reaches the calibrated threshold.

    Prints the collision events (contiguous flagged runs) of each log.

    Exit code 1 when any collision is found, 0 when none, 2 on errors.

    Example: twincd detect run.mcap -c calibration.json -o run.detect.mcap
    """
    cal = Calibration.load(calibration)
    cal.require_threshold()
    paths = expand_logs(logs)
    setup = resolve_setup(cal, robot, topic, label_topic, sim_topic, joint_map)
    targets = _targets(paths, output)
    # one log at a time: only the small summaries are kept, so memory stays flat
    for target in targets:
        if target is not None:
            check_writable(target)
    summaries = []
    with all_or_nothing() as written:
        for path, target in progress(list(zip(paths, targets, strict=True)), "detecting", quiet):
            result = detect_log(setup.prepare(path), cal)
            if target is not None:
                write_detection(result, path, target)
                written.append(target)
            summaries.append(result.to_dict())
            if json_:
                continue
            if result.events:
                stdout.print(events_table(result))
            else:
                stdout.print(f"{result.source}: no collision ({len(result.scores)} samples)")
    found = any(s["events"] for s in summaries)
    if json_:
        doc = {
            "collision": found,
            "threshold": cal.require_threshold().value,
            "logs": summaries,
        }
        stdout.out(json.dumps(doc), highlight=False)
    if found:
        raise typer.Exit(1)
