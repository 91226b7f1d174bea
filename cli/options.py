"""The command-line options several subcommands share, declared once (typer ``Annotated``
aliases), and the library settings they become."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, cast

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
    from twincd.commands import Settings

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
Quiet = Annotated[
    bool, typer.Option("--quiet", "-q", help="Silence stderr except errors.", metavar="")
]
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
Debug = Annotated[bool, typer.Option("--debug", help="Show tracebacks on errors.", metavar="")]
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


def settings(*, joint_map: str | None = None, **given: Any) -> Settings:
    """The library's reading settings of the options given (``--joint-map`` parsed)."""
    from twincd.io.options import parse_joint_map

    parsed = None if joint_map is None else parse_joint_map(joint_map)
    return cast("Settings", {"joint_map": parsed, **given})
