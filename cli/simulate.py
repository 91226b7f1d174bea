"""``twincd simulate``: the twin's effort written into MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from twincd.errors import UsageError
from twincd.run import all_or_nothing

from .common import command, exit_if_failed, run_per_log, stdout
from .options import (
    Debug,
    Force,
    Jobs,
    JointMap,
    KeepGoing,
    LabelTopic,
    Quiet,
    Robot,
    Scheduler,
    SimTopic,
    Strict,
    Topic,
    setup_options,
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
    joint_map: JointMap = None,
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
    from twincd.executors import Bound
    from twincd.io.atomic import check_target, check_writable
    from twincd.io.logs import expand_logs
    from twincd.outputs import distinct_targets, make_output_folder
    from twincd.simulate import default_output, simulate_item
    from twincd.twin.robot import list_robots

    if list_robots_:
        for name in list_robots():
            stdout.print(name)
        return
    if not logs:
        raise UsageError("no logs given", "simulate", "pass LOG... or --list-robots")
    paths = expand_logs(logs)
    if in_place and output is not None:
        raise UsageError("--in-place and --output exclude each other", "simulate", "pick one")
    for path in paths if in_place else []:
        if not (path.is_file() and path.suffix == ".mcap"):
            raise UsageError(
                "--in-place rewrites bare .mcap files only", str(path), "use -o for other logs"
            )
    several = len(paths) > 1
    if several and output is not None:
        if output.suffix == ".mcap":
            raise UsageError("several logs need an output folder", str(output), "give -o a folder")
        make_output_folder(output)
    asked = setup_options(
        topic=topic, label_topic=label_topic, sim_topic=sim_topic, joint_map=joint_map
    )
    from twincd.io.named import settle_named

    # the twin's topic is what simulate writes, not something a log must have
    options = settle_named(paths, asked.log_options().unnamed("sim_topic"))
    targets: list[Path | None] = [None] * len(paths)
    if not in_place:
        folder = output if several else None
        planned = distinct_targets(paths, default_output, folder)
        targets = [output if output is not None and not several else t for t in planned]
    for path, target in zip(paths, targets):
        if target is None:
            check_writable(path)  # --in-place: a read-only log is refused
        else:
            check_target(target, "simulate", force=force, inputs=paths)
    items = list(zip(paths, targets, strict=True))
    with all_or_nothing() as written:
        written.extend(t for t in targets if t is not None)
        work = Bound(simulate_item, robot, options, in_place, strict)
        done = run_per_log(
            work, items, "simulating", quiet, jobs=jobs, scheduler=scheduler, keep_going=keep_going
        )
    for result in done.results:
        stdout.print(f"{result.output}\t{result.samples} samples\t{len(result.joints)} joints")
    exit_if_failed(done)
