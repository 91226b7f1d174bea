"""``twincd simulate``: the twin's effort written into MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from twincd.errors import UsageError

from .common import command, finish, stdout

if TYPE_CHECKING:
    from twincd.commands import RunOptions
    from twincd.prepare.settings import SetupOptions

from .options import (
    GIVEN,
    RECORDING,
    Force,
    reads,
)


@command
@reads(*RECORDING, "strict", run=True)
def simulate(
    logs: Annotated[
        list[Path] | None,
        typer.Argument(help="Logs: rosbag2 folders, .mcap or .bag files, or folders of logs."),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Output .mcap (one log) or folder (several logs)."),
    ] = None,
    asked: SetupOptions = GIVEN,
    in_place: Annotated[
        bool, typer.Option("--in-place", help="Rewrite a bare .mcap input atomically.", metavar="")
    ] = False,
    list_robots_: Annotated[
        bool,
        typer.Option("--list-robots", help="List the robot names --robot accepts.", metavar=""),
    ] = False,
    run: RunOptions = GIVEN,
    force: Force = False,
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
    given = asked.keywords()
    done = simulate_logs(logs, output=output, in_place=in_place, force=force, **run, **given)
    for result in done.outputs:
        stdout.print(f"{result.output}\t{result.samples} samples\t{len(result.joints)} joints")
    finish(done)
