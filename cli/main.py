"""The ``twincd`` application: registers the subcommands; each lives in its own module."""

from __future__ import annotations

import signal
import sys
import threading
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from twincd import __version__

from . import calibrate, detect, evaluate, inspect, simulate, synth, watch


class _NoFlagMetavar:
    """``--help`` is a flag: no ``<bool>`` after it in the help text."""

    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)  # type: ignore[misc]
        if option is not None:
            option.metavar = ""
        return option


class _Command(_NoFlagMetavar, TyperCommand):
    pass


class _Group(_NoFlagMetavar, TyperGroup):
    pass


app = typer.Typer(
    cls=_Group,
    name="twincd",
    help="Find robot-arm collisions in recorded ROS 2 logs with a digital twin.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"twincd {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version.", metavar=""
        ),
    ] = False,
) -> None:
    """Find robot-arm collisions in recorded ROS 2 logs with a digital twin."""


app.command("simulate", cls=_Command)(simulate.simulate)
app.command("fit", cls=_Command)(calibrate.fit)
app.command("threshold", cls=_Command)(calibrate.threshold)
app.command("detect", cls=_Command)(detect.detect)
app.command("evaluate", cls=_Command)(evaluate.evaluate)
app.command("synth", cls=_Command)(synth.synth)
app.command("inspect", cls=_Command)(inspect.inspect)
app.command("watch", cls=_Command)(watch.watch)


def _exit_terminated(signum: int, frame: object) -> None:
    # SIGTERM before a command runs: nothing is written yet, so leave at once with 143, saying
    # so as a running command does (it raises ``Terminated`` instead and cleans up first)
    sys.stderr.write("twincd: terminated\n")
    sys.exit(128 + signum)


def main() -> None:
    """The ``twincd`` program: SIGTERM before a command runs exits 143 at once; exit 3 with one
    line for a defect anywhere (never 1), and a closed stdout (``| head``) ends quietly, even
    while typer prints help."""
    from .common import closed_stdout_ends_quietly, internal_error_exit

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _exit_terminated)
    with closed_stdout_ends_quietly():
        try:
            app()
        except Exception as exc:
            internal_error_exit(exc, "--debug" in sys.argv[1:])


if __name__ == "__main__":
    main()
