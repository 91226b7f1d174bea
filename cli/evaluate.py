"""``twincd evaluate``: the seed paper's Table II on labelled test logs (DESIGN §6–§7)."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.table import Table

from twincd.defaults import DEFAULT_REPEATS

from .calibrate import Causal, Cutoff, FilterOrder, resolve_setup
from .common import (
    WARNINGS,
    Debug,
    Force,
    JointMap,
    LabelTopic,
    Logs,
    Quiet,
    Robot,
    SimTopic,
    Strict,
    Topic,
    command,
    progress,
    stdout,
)

log = logging.getLogger("twincd")


@command
def evaluate(
    logs: Logs,
    calibration: Annotated[
        Path | None,
        typer.Option(
            "--calibration",
            "-c",
            help="Calibration JSON (fit + threshold); optional when --train and --val are given.",
        ),
    ] = None,
    methods: Annotated[
        str,
        typer.Option("--methods", "-m", help="Comma-separated method names, or all."),
    ] = "proposed",
    train: Annotated[
        list[Path] | None,
        typer.Option("--train", help="Collision-free logs methods fit on (repeatable)."),
    ] = None,
    val: Annotated[
        list[Path] | None,
        typer.Option("--val", help="Collision-free logs that set μ and σ (repeatable)."),
    ] = None,
    sigma: Annotated[
        float | None,
        typer.Option(
            "--sigma",
            "-k",
            help="k of μ + kσ for the at-threshold figures (default: the calibration's, else 4).",
            min=0,
        ),
    ] = None,
    repeats: Annotated[
        int,
        typer.Option(
            "--repeats",
            help="Runs (seeds 0..N-1) of randomised (deep) methods; mean ± std as Table II.",
            min=1,
        ),
    ] = DEFAULT_REPEATS,
    json_: Annotated[
        bool, typer.Option("--json", help="Print one JSON document.", metavar="")
    ] = False,
    report: Annotated[
        Path | None, typer.Option("--report", help="Also write a Markdown report here.")
    ] = None,
    min_f1: Annotated[
        float | None, typer.Option("--min-f1", help="Exit 1 if a method's best F1 is lower.")
    ] = None,
    min_auc: Annotated[
        float | None, typer.Option("--min-auc", help="Exit 1 if a method's AUC is lower.")
    ] = None,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    cutoff: Cutoff = None,
    filter_order: FilterOrder = None,
    causal: Causal = None,
    strict: Strict = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Score methods on labelled test logs: F1 over μ + iσ, F1 at threshold, ROC AUC, times.

    The positional logs are the test set; they need collision labels.

    With -c alone, proposed uses the calibration's a, b, μ and σ.

    With --train and --val, every method (proposed too) fits on --train; μ, σ come from --val.

    Example: twincd evaluate logs/test -c calibration.json --report report.md
    """
    from twincd.calibration import Calibration
    from twincd.evaluation.reports import SHORT_COLUMNS, evaluation_markdown, evaluation_rows
    from twincd.evaluation.runner import evaluate as run_evaluation
    from twincd.evaluation.runner import parse_methods
    from twincd.io.atomic import atomic_output, check_target
    from twincd.io.logs import expand_logs

    cal = Calibration.load(calibration) if calibration is not None else None
    names = parse_methods(methods)
    test_paths = expand_logs(logs)
    train_paths = expand_logs(train) if train else []
    val_paths = expand_logs(val) if val else []
    if report is not None:
        check_target(report, "report", force=force, inputs=[*test_paths, *train_paths, *val_paths])
    setup = resolve_setup(
        cal, robot, topic, label_topic, sim_topic, joint_map, cutoff, filter_order, causal, strict
    )

    def bar(items: Sequence[Any], desc: str) -> Iterable[Any]:
        return progress(items, desc, quiet)

    result = run_evaluation(
        test_paths,
        names,
        setup,
        calibration=cal,
        train_paths=train_paths,
        val_paths=val_paths,
        k_sigma=sigma,
        repeats=repeats,
        progress=bar,
    )
    if result.positives == 0:
        log.warning(
            "no test sample is labelled as a collision: F1 is 0 and AUC undefined "
            "(evaluate wants logs with collisions and their %s labels)",
            setup.options.label_topic,
        )
    missed = result.missed_gates(min_f1, min_auc)
    if report is not None:
        with atomic_output(report) as stream:
            stream.write(evaluation_markdown(result, missed).encode("utf-8"))
    if json_:
        doc = {**result.to_dict(), "warnings": list(WARNINGS)}
        stdout.out(json.dumps(doc), highlight=False)
    else:
        table = Table(
            title=f"{result.samples} test samples, {result.positives} labelled as collision",
            box=box.SIMPLE_HEAD,
            show_edge=False,
            padding=(0, 0),
            pad_edge=False,
            caption="* per time window"
            if any(m.unit != "sample" for m in result.methods)
            else None,
        )
        rows = [[c.replace(" + ", "+") for c in row] for row in evaluation_rows(result)]
        for i, col in enumerate(SHORT_COLUMNS):
            width = max([len(col)] + [len(r[i]) for r in rows])
            table.add_column(
                col, justify="left" if i == 0 else "right", no_wrap=True, min_width=width
            )
        for row in rows:
            table.add_row(*row)
        stdout.print(table)
        for m in result.methods:
            if m.note:
                stdout.print(f"note: {m.name}: {m.note}")
    for m in result.methods:
        if m.skipped is not None:
            log.warning("method %s skipped: %s", m.name, m.skipped)
    if missed:
        for line in missed:
            log.warning("gate missed: %s", line)
        raise typer.Exit(1)
