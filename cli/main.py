"""The ``twincd`` application: registers the subcommands; each lives in its own module."""

from __future__ import annotations

from typing import Annotated

import typer

from twincd import __version__

from . import calibrate, detect, evaluate, simulate, synth

app = typer.Typer(
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
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    """Find robot-arm collisions in recorded ROS 2 logs with a digital twin."""


app.command("simulate")(simulate.simulate)
app.command("fit")(calibrate.fit)
app.command("threshold")(calibrate.threshold)
app.command("detect")(detect.detect)
app.command("evaluate")(evaluate.evaluate)
app.command("synth")(synth.synth)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
