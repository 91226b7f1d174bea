"""``twincd evaluate``: the seed paper's Table II on labelled test logs (contract: Metrics,
Methods)."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich import box
from rich.table import Table

from twincd.defaults import DEFAULT_LINK_TOPIC, DEFAULT_REPEATS
from twincd.run import LogRun, all_or_nothing

from .common import (
    WARNINGS,
    check_reports,
    command,
    error_docs,
    exit_if_failed,
    progress,
    run_per_log,
    stdout,
)
from .options import (
    AllowUrdfChange,
    Causal,
    Cutoff,
    Debug,
    FilterKind,
    FilterOrder,
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

if TYPE_CHECKING:
    from twincd.calibration import Calibration
    from twincd.evaluation.runner import Evaluation

log = logging.getLogger("twincd")


def _write_reports(
    result: Evaluation,
    missed: list[str],
    cal: Calibration | None,
    report: Path | None,
    junit: Path | None,
    no_summary: bool,
    gates: tuple[float | None, float | None],
) -> None:
    from twincd.evaluation.markdown import evaluation_markdown
    from twincd.reports import (
        append_step_summary,
        calibration_settings,
        evaluation_junit,
        evaluation_report,
    )
    from twincd.reports.documents import write_text

    settings = calibration_settings(cal) if cal is not None else []
    if report is not None:
        evaluation_report(report, result, missed, settings, gates)
        log.info("wrote %s", report)
    if junit is not None:
        write_text(junit, evaluation_junit(result, *gates))
        log.info("wrote %s", junit)
    if not no_summary:
        append_step_summary(evaluation_markdown(result, missed))


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
        str | None,
        typer.Option(
            "--methods",
            "-m",
            help="Comma-separated method names, or all [default: the calibration's own model; "
            "proposed without one]",
        ),
    ] = None,
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
            help=(
                "k of μ + kσ for the at-threshold figures (default: the calibration's threshold"
                " itself, else 4)."
            ),
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
    json_: Json = False,
    report: Report = None,
    junit: Junit = None,
    no_summary: NoSummary = False,
    min_f1: Annotated[
        float | None,
        typer.Option(
            "--min-f1",
            help="Exit 1 if a method's F1 at the threshold it is run at is lower (the "
            "calibration's threshold for its own model, μ + kσ of --val for the others; not the "
            "best F1 over μ + iσ).",
        ),
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
    filter_kind: FilterKind = None,
    causal: Causal = None,
    jobs: Jobs = 0,
    scheduler: Scheduler = None,
    link_topic: Annotated[
        str | None,
        typer.Option(
            "--link-topic",
            help="std_msgs/String contact link (isolation ground truth), when logs have it "
            f"[default: {DEFAULT_LINK_TOPIC}].",
        ),
    ] = None,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    allow_urdf_change: AllowUrdfChange = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Score methods on labelled test logs: F1 over μ + iσ, F1 at threshold, ROC AUC, times.

    The positional logs are the test set; they need collision labels.

    With -c alone, proposed uses the calibration's a, b, μ and σ.

    With --train and --val, every method (proposed too) fits on --train; μ, σ come from --val.

    With GITHUB_STEP_SUMMARY set, a Markdown summary is appended to it (off: --no-summary).

    Example: twincd evaluate logs/test -c calibration.json --report report.html
    """
    from twincd.calibration import Calibration
    from twincd.cluster import open_executor
    from twincd.evaluation.markdown import (
        SHORT_COLUMNS,
        SHORT_EVENT_COLUMNS,
        evaluation_rows,
        event_rows,
    )
    from twincd.evaluation.runner import evaluate as run_evaluation
    from twincd.evaluation.runner import method_for, parse_methods
    from twincd.io.logs import expand_logs

    cal = Calibration.load(calibration) if calibration is not None else None
    names = parse_methods(methods, method_for(cal.model.kind) if cal is not None else "proposed")
    test_paths = expand_logs(logs)
    train_paths = expand_logs(train) if train else []
    val_paths = expand_logs(val) if val else []
    inputs = [*test_paths, *train_paths, *val_paths, *([calibration] if calibration else [])]
    check_reports(report, junit, force=force, inputs=inputs)
    setup = setup_options(
        robot=robot,
        topic=topic,
        label_topic=label_topic,
        sim_topic=sim_topic,
        joint_map=joint_map,
        cutoff_hz=cutoff,
        filter_order=filter_order,
        filter_kind=filter_kind,
        causal=causal,
        strict=strict,
        allow_urdf_change=allow_urdf_change,
    ).resolve(cal)

    def bar(items: Sequence[Any], desc: str) -> Iterable[Any]:
        return progress(items, desc, quiet)

    every_log = [*test_paths, *train_paths, *val_paths]
    with open_executor(jobs, scheduler, every_log) as executor:
        failed: LogRun[Any] = LogRun()

        def run(func: Callable[[Path], Any], paths: Sequence[Path], desc: str) -> list[Any]:
            if not paths:
                return []
            run = run_per_log(
                func, paths, f"reading {desc}", quiet, executor=executor, keep_going=keep_going
            )
            for failure in run.failures:  # with --keep-going: reported, the rest goes on
                if failure.path not in {f.path for f in failed.failures}:  # once per log
                    failed.failures.append(failure)
            return list(run.results)

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
            run=run,
            link_topic=link_topic,
            batch=max(1, getattr(executor, "workers", 1) or 1),
        )
    if result.positives == 0:
        log.warning(
            "no test sample is labelled as a collision: F1 is 0 and AUC undefined "
            "(evaluate wants logs with collisions and their %s labels)",
            setup.options.label_topic,
        )
    missed = result.missed_gates(min_f1, min_auc)
    with all_or_nothing() as written:  # the report and the JUnit file: both or neither
        written.extend(p for p in (report, junit) if p is not None)
        _write_reports(result, missed, cal, report, junit, no_summary, (min_f1, min_auc))
    if json_:
        doc = {**result.to_dict(), "errors": error_docs(failed), "warnings": list(WARNINGS)}
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
    for m in result.methods:
        if m.skipped is not None:
            log.warning("method %s skipped: %s", m.name, m.skipped)
    exit_if_failed(failed)  # --keep-going: a log that failed is exit 2, before any gate
    if missed:
        for line in missed:
            log.warning("gate missed: %s", line)
        raise typer.Exit(1)


def _fill(table: Table, columns: Sequence[str], rows: list[list[str]]) -> Table:
    for i, col in enumerate(columns):
        width = max([len(col)] + [len(r[i]) for r in rows])
        table.add_column(col, justify="left" if i == 0 else "right", no_wrap=True, min_width=width)
    for row in rows:
        table.add_row(*row)
    return table
