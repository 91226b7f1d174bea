"""The ``twincd`` application: registers the subcommands; each lives in its own module."""

from __future__ import annotations

import importlib
from typing import Annotated

import typer

from twincd import __version__

app = typer.Typer(
    name="twincd",
    help="Find robot-arm collisions in recorded ROS 2 logs with a digital twin.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# (module in cli/, function, command name); a module that is not there yet is skipped
_COMMANDS = [
    ("simulate", "simulate", "simulate"),
    ("calibrate", "fit", "fit"),
    ("calibrate", "threshold", "threshold"),
    ("detect", "detect", "detect"),
    ("evaluate", "evaluate", "evaluate"),
    ("synth", "synth", "synth"),
]


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


for _module, _func, _name in _COMMANDS:
    try:
        mod = importlib.import_module(f"{__package__}.{_module}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.{_module}":
            raise
        continue
    app.command(_name)(getattr(mod, _func))


def main() -> None:
    app()


if __name__ == "__main__":
    main()
