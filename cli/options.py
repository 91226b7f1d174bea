"""The command-line options several subcommands share, declared once (typer ``Annotated``
aliases), and the library settings they become: ``reads`` gives a command the reading settings
(and the run options) it takes, each declared once in ``SETTINGS``, as one argument."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypedDict

import typer

from twincd.defaults import (
    DEFAULT_CAUSAL_CUTOFF_HZ,
    DEFAULT_CUTOFF_HZ,
    DEFAULT_FAST_CUTOFF_HZ,
    DEFAULT_LABEL_TOPIC,
    DEFAULT_LINK_TOPIC,
    DEFAULT_ORDER,
    DEFAULT_ROBOT,
    DEFAULT_SIM_TOPIC,
    DEFAULT_TOPIC,
)

if TYPE_CHECKING:
    from twincd.prepare.settings import SetupOptions

Logs = Annotated[
    list[Path],
    typer.Argument(help="Logs: rosbag2 folders, .mcap or .bag files, or folders of logs."),
]
Robot = Annotated[
    str | None,
    typer.Option(
        "--robot",
        "-r",
        help="example-robot-data name, URDF path or package:// URI [default: the "
        f"calibration's, else {DEFAULT_ROBOT}]",
    ),
]
Topic = Annotated[
    str | None, typer.Option("--topic", help=f"JointState topic [default: {DEFAULT_TOPIC}]")
]
LabelTopic = Annotated[
    str | None,
    typer.Option("--label-topic", help=f"Bool collision labels [default: {DEFAULT_LABEL_TOPIC}]"),
]
SimTopic = Annotated[
    str | None,
    typer.Option("--sim-topic", help=f"simulated effort topic [default: {DEFAULT_SIM_TOPIC}]"),
]
LinkTopic = Annotated[
    str | None,
    typer.Option(
        "--link-topic",
        help="std_msgs/String contact link (isolation ground truth), when logs have it "
        f"[default: {DEFAULT_LINK_TOPIC}].",
    ),
]
JointMap = Annotated[
    str | None, typer.Option("--joint-map", help="rename log joints: old=new,old2=new2")
]
JointPrefix = Annotated[
    str | None,
    typer.Option(
        "--joint-prefix",
        help="read log joints named PREFIX+name as name (--joint-prefix left_: left_joint1 is "
        "joint1); with --joint-map, its entries come first",
    ),
]
Json = Annotated[bool, typer.Option("--json", help="Print one JSON document.", metavar="")]
Jobs = Annotated[
    int,
    typer.Option(
        "--jobs", "-j", help="Logs processed at once in local processes (0: every core).", min=0
    ),
]
Scheduler = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        help="Run on a Dask cluster: a scheduler address (tcp://host:8786), or 'local' for a "
        "LocalCluster of -j workers. Logs must be at the same path on every worker.",
    ),
]
Report = Annotated[
    Path | None,
    typer.Option(
        "--report",
        help="Also write a report here: .md, or .html (one self-contained page with figures; "
        "figures need the plot extra: without it, .html is refused before any work).",
    ),
]
Junit = Annotated[
    Path | None, typer.Option("--junit", help="Also write JUnit XML here (for CI systems).")
]
NoSummary = Annotated[
    bool,
    typer.Option(
        "--no-summary",
        help="Do not append the Markdown summary to $GITHUB_STEP_SUMMARY (appended when set).",
        metavar="",
    ),
]
Start = Annotated[
    str | None,
    typer.Option(
        "--start",
        help="Judge each log from this time on: seconds from its first sample (12.5), or @ and "
        "seconds since the epoch (@1695811234.5). Earlier samples still warm the filters.",
        metavar="S",
    ),
]
End = Annotated[
    str | None,
    typer.Option(
        "--end",
        help="Judge each log up to this time (as --start); later samples are not read.",
        metavar="S",
    ),
]
Strict = Annotated[
    bool,
    typer.Option(
        "--strict",
        help="Refuse a truncated log instead of reading it up to the damage.",
        metavar="",
    ),
]
KeepGoing = Annotated[
    bool,
    typer.Option(
        "--keep-going",
        help="Process every log even if some fail; report each failure, exit 2 at the end (3 "
        "when a failure was a defect in twincd).",
        metavar="",
    ),
]
AllowUrdfChange = Annotated[
    bool,
    typer.Option(
        "--allow-urdf-change",
        help="Use a robot model whose dynamics (joints, inertias, kinematics, limits) differ "
        "from those the calibration was fitted with (for calibrations of older versions: a "
        "URDF whose file changed); refused otherwise.",
        metavar="",
    ),
]
Force = Annotated[
    bool,
    typer.Option(
        "--force",
        help="Overwrite an output even if it is not twincd's own output of its kind (never an "
        "input of the run, nor a read-only file).",
        metavar="",
    ),
]

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
FastCutoff = Annotated[
    float | None,
    typer.Option(
        "--fast-cutoff",
        help=f"Upper cut-off in Hz of the fast band a strike shows in (default "
        f"{DEFAULT_FAST_CUTOFF_HZ:g}, as far as the sampling rate allows; 0: the filter's band "
        "only). Models scored by depth only.",
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


def settings(*, joint_map: str | None = None, **given: Any) -> SetupOptions:
    """The library's settings object of the options given (``--joint-map`` parsed)."""
    from twincd.io.options import parse_joint_map
    from twincd.prepare.settings import SetupOptions

    parsed = None if joint_map is None else parse_joint_map(joint_map)
    return SetupOptions(joint_map=parsed, **given)


# the default of a command's ``asked`` and ``run`` parameters, which ``reads`` fills
GIVEN: Any = None


@dataclass(frozen=True)
class Setting:
    """A reading setting as every command takes it: its option, its default, and its keyword
    among the library's reading settings (``twincd.SetupOptions``' fields)."""

    option: Any
    default: Any
    keyword: str


SETTINGS: dict[str, Setting] = {
    "robot": Setting(Robot, None, "robot"),
    "topic": Setting(Topic, None, "topic"),
    "label_topic": Setting(LabelTopic, None, "label_topic"),
    "sim_topic": Setting(SimTopic, None, "sim_topic"),
    "link_topic": Setting(LinkTopic, None, "link_topic"),
    "joint_map": Setting(JointMap, None, "joint_map"),
    "joint_prefix": Setting(JointPrefix, None, "joint_prefix"),
    "cutoff": Setting(Cutoff, None, "cutoff_hz"),
    "fast_cutoff": Setting(FastCutoff, None, "fast_cutoff_hz"),
    "filter_order": Setting(FilterOrder, None, "filter_order"),
    "filter_kind": Setting(FilterKind, None, "filter_kind"),
    "causal": Setting(Causal, None, "causal"),
    "start": Setting(Start, None, "start"),
    "end": Setting(End, None, "end"),
    "strict": Setting(Strict, False, "strict"),
    "allow_urdf_change": Setting(AllowUrdfChange, False, "allow_urdf_change"),
}
# how a recording is read (every command that reads logs), the filter, the stretch judged
RECORDING = (
    "robot",
    "topic",
    "label_topic",
    "sim_topic",
    "link_topic",
    "joint_map",
    "joint_prefix",
)
FILTER = ("cutoff", "fast_cutoff", "filter_order", "filter_kind", "causal")
WINDOW = ("start", "end", "strict")
# the run options (``RunOptions``: ``twincd.cli.common.run_options``)
RUN: dict[str, tuple[Any, Any]] = {"jobs": (Jobs, 0), "scheduler": (Scheduler, None),
                                   "keep_going": (KeepGoing, False)}  # fmt: skip
# what a run writes for people and CI besides its output (``ReportOptions``)
REPORTS: dict[str, tuple[Any, Any]] = {"report": (Report, None), "junit": (Junit, None),
                                       "no_summary": (NoSummary, False)}  # fmt: skip


class ReportOptions(TypedDict):
    """The library's keywords for --report, --junit and --no-summary (detect, evaluate)."""

    report: Path | None
    junit: Path | None
    step_summary: bool


def reads(
    *names: str, run: bool = False, reports: bool = False
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Give a command the reading settings ``names`` (``SETTINGS``) as options, in the place of
    its parameter ``asked``, which gets them as one ``SetupOptions`` (the --joint-map parsed); with
    ``run``, also --jobs, --scheduler and --keep-going, in the place of its parameter ``run``,
    which gets the library's run options (``run_options``, quiet as --quiet says); with
    ``reports``, --report, --junit and --no-summary in the place of its parameter ``reports``
    (a ``ReportOptions``)."""
    from .common import run_options

    def wrap(func: Callable[..., Any]) -> Callable[..., Any]:
        declared = inspect.signature(func)
        scope = func.__globals__
        injected = {
            "asked": [_parameter(n, SETTINGS[n].option, SETTINGS[n].default) for n in names],
            "run": [_parameter(n, option, d) for n, (option, d) in RUN.items()] if run else [],
            "reports": [_parameter(n, o, d) for n, (o, d) in REPORTS.items()] if reports else [],
        }
        params: list[inspect.Parameter] = []
        for p in declared.parameters.values():
            if p.name in injected:
                params += injected[p.name]
            else:
                kind = eval(p.annotation, scope) if isinstance(p.annotation, str) else p.annotation
                params.append(p.replace(annotation=kind))

        @functools.wraps(func)
        def command(*args: Any, **kwargs: Any) -> Any:
            given = {SETTINGS[n].keyword: kwargs.pop(n) for n in names}
            if run:
                go = {n: kwargs.pop(n) for n in RUN}
                kwargs["run"] = run_options(bool(kwargs.get("quiet")), **go)
            if reports:
                report, junit, no_summary = (kwargs.pop(n) for n in REPORTS)
                kwargs["reports"] = ReportOptions(
                    report=report, junit=junit, step_summary=not no_summary
                )
            for flag in ("quiet", "debug"):  # ``common.command``'s, for run_options above
                if flag not in declared.parameters:
                    kwargs.pop(flag, None)
            return func(*args, asked=settings(**given), **kwargs)

        command.__signature__ = declared.replace(parameters=params)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in params}
        return command

    return wrap


def _parameter(name: str, option: Any, default: Any) -> inspect.Parameter:
    return inspect.Parameter(
        name, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=default, annotation=option
    )
