"""``twincd inspect``: what a log holds and what twincd will make of it, without the twin."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from .common import Debug, Quiet, command, finish, stdout
from .options import (
    GIVEN,
    RECORDING,
    Json,
    Logs,
    reads,
)

if TYPE_CHECKING:
    from twincd.commands.inspection import Inspection
    from twincd.prepare.settings import SetupOptions


def _number(value: float | None, spec: str = ".4g") -> str:
    return "—" if value is None or value != value else format(value, spec)


def _joint_table(found: Inspection) -> Table:
    table = Table(title="joints (position in rad or m, effort in N·m or N)", title_justify="left")
    for col in ("joint", "position min", "max", "model limits", "effort min", "max", "std"):
        table.add_column(col, justify="left" if col == "joint" else "right")
    for j in found.joints:
        limits = (
            "—"
            if j.lower_limit is None or j.upper_limit is None
            else f"{j.lower_limit:.4g} … {j.upper_limit:.4g}"
        )
        table.add_row(
            j.name,
            _number(j.position_min),
            _number(j.position_max),
            limits,
            _number(j.effort_min),
            _number(j.effort_max),
            _number(j.effort_std),
        )
    return table


def render(found: Inspection) -> None:
    """The inspection as a person reads it."""
    say = stdout.print
    say(f"[bold]{found.path}[/bold]")
    say("  topics: " + ", ".join(f"{t.name} ({t.type.rsplit('/', 1)[-1]})" for t in found.topics))
    if found.joint_topic:
        say(f"  joint states: {found.joint_topic}, {len(found.joint_sets)} joint set(s):")
        for js in found.joint_sets:
            parts = [f"{js.messages} msgs"]
            if js.with_velocity < js.messages:
                parts.append(f"{js.messages - js.with_velocity} without velocity")
            if js.with_effort < js.messages:
                parts.append(f"{js.messages - js.with_effort} without effort")
            if js.zero_stamps:
                every = js.zero_stamps == js.messages
                parts.append(f"{js.zero_stamps} stamped 0" + (" (log time used)" if every else ""))
            say(f"    [{', '.join(js.joints)}]: {'; '.join(parts)}", soft_wrap=True, markup=False)
    if found.robot:
        default = " (the default; pass --robot for another arm)"
        say(f"  robot model: {found.robot}{default if found.robot_is_default else ''}")
        say(f"    matched: {', '.join(found.matched) or 'none'}", soft_wrap=True)
        if found.ignored:
            say(f"    ignored (not in the model): {', '.join(found.ignored)}", soft_wrap=True)
        if found.locked:
            say(f"    locked at neutral (not in the log): {', '.join(found.locked)}")
    if found.twin_source:
        say(f"  twin effort: {found.twin_source}")
    s = found.sampling
    if s is not None:
        say(
            f"  samples: {s.samples} over {s.duration_s:.3f} s at {_number(s.rate_hz)} Hz, "
            f"jitter {s.jitter_ms:.3g} ms, {s.gaps} gap(s)"
            + (f" (largest {s.largest_gap_s:.3g} s)" if s.gaps else "")
        )
    if found.other_publisher:
        say(
            f"  second publisher on the same joints: {found.other_publisher} message(s) of "
            "zero efforts between the live samples, left out"
        )
    bad = found.absurd
    if bad.samples:
        times = ", ".join(f"{t:.3f}" for t in bad.times_s) + (
            ", …" if bad.samples > len(bad.times_s) else ""
        )
        joints = "; ".join(f"{kind} on {', '.join(names)}" for kind, names in bad.joints.items())
        say(
            f"  absurd samples: {bad.samples} dropped, at {times} s ({joints})",
            soft_wrap=True,
            markup=False,
        )
    off = found.drives_off
    if off.samples:
        spans = ", ".join(f"{a:.3f}–{b:.3f}" for a, b in off.spans_s)
        more = ", …" if off.spans > len(off.spans_s) else ""
        say(
            f"  drives off: {off.samples} sample(s) whose efforts are all exactly 0, left out, "
            f"at {spans}{more} s",
            soft_wrap=True,
            markup=False,
        )
    labels = (
        f"{found.label_messages} message(s)"
        if found.label_messages
        else "none (fit uses every sample)"
    )
    say(f"  labels: {labels}")
    if found.link_labels:
        say(f"  contact links: {', '.join(found.link_labels)}")
    if found.joints:
        say(_joint_table(found))
    for line in found.warnings:
        say(f"  warning: {line}", soft_wrap=True, markup=False)
    verdict = "usable" if found.usable else f"NOT usable: {found.problem}"
    say(f"  → {verdict}", soft_wrap=True, markup=False)


@command
@reads(*RECORDING, "strict")
def inspect(
    logs: Logs,
    calibration: Annotated[
        Path | None,
        typer.Option(
            "--calibration", "-c", help="Also check the logs against this calibration's joints."
        ),
    ] = None,
    json_: Json = False,
    asked: SetupOptions = GIVEN,
    quiet: Quiet = False,
    debug: Debug = False,
) -> None:
    """Say what logs hold and what twincd will make of them, without running the twin.

    Topics, joint sets per publisher, joints matched to the robot model (ignored, locked),
    rate, jitter, gaps, ranges against the model's limits, labels, where the twin effort comes
    from, and every warning detect would give. The first thing to run on a new robot's logs.

    Exit code 0 when every log is usable, 2 when one is not (one line why).

    Example: twincd inspect run.mcap --robot panda
    """
    import json

    from twincd.commands import inspect_logs

    done = inspect_logs(logs, calibration, **asked.keywords())
    if json_:
        stdout.out(json.dumps(done.to_dict(), allow_nan=False), highlight=False)
    for found in [] if json_ else done.logs:
        render(found)
    for f in done.logs:
        if not f.usable:
            if debug and f.error is not None:  # --debug: where the log's problem was raised
                import traceback

                typer.echo("".join(traceback.format_exception(f.error)).rstrip(), err=True)
            typer.echo(f"twincd: error: {f.problem}", err=True)
    finish(done)
