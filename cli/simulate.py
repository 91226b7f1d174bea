"""``twincd simulate``: the twin's effort written into MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from twincd.errors import UsageError

from .common import command, finish, run_options, stdout
from .options import (
    Debug,
    Force,
    Jobs,
    JointMap,
    JointPrefix,
    KeepGoing,
    LabelTopic,
    LinkTopic,
    Quiet,
    Robot,
    Scheduler,
    SimTopic,
    Strict,
    Topic,
    settings,
)


@command
def simulate(
    logs: Annotated[
        list[Path] | None,
        typer.Argument(help="Logs: rosbag2 folders, .mcap or .bag files, or folders of logs."),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Output .mcap (one log) or folder (several logs)."),
    ] = None,
    robot: Robot = None,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    sim_topic: SimTopic = None,
    link_topic: LinkTopic = None,
    joint_map: JointMap = None,
    joint_prefix: JointPrefix = None,
    in_place: Annotated[
        bool, typer.Option("--in-place", help="Rewrite a bare .mcap input atomically.", metavar="")
    ] = False,
    list_robots_: Annotated[
        bool,
        typer.Option("--list-robots", help="List the robot names --robot accepts.", metavar=""),
    ] = False,
    jobs: Jobs = 0,
    scheduler: Scheduler = None,
    strict: Strict = False,
    keep_going: KeepGoing = False,
    force: Force = False,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Run the digital twin over logs and write its effort to /twincd/sim_effort.

    Each output is the input copied losslessly into MCAP plus the twin's channel.

    Example: twincd simulate run.mcap --robot xarm7 -o run.twin.mcap
    """
    from twincd.commands import simulate_logs
    from twincd.twin.robot import list_robots

    if list_robots_:
        for name in list_robots():
            stdout.print(name)
        return
    if not logs:
        raise UsageError("no logs given", "simulate", "pass LOG... or --list-robots")
    asked = settings(
        robot=robot, topic=topic, label_topic=label_topic, sim_topic=sim_topic,
        joint_map=joint_map, joint_prefix=joint_prefix, link_topic=link_topic, strict=strict
    )  # fmt: skip
    run = run_options(quiet, jobs, scheduler, keep_going)
    done = simulate_logs(logs, output=output, in_place=in_place, force=force, **run, **asked)
    for result in done.outputs:
        stdout.print(f"{result.output}\t{result.samples} samples\t{len(result.joints)} joints")
    finish(done)
