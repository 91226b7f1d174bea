"""``twincd watch``: live detection on a running robot; exit 1 when a collision was seen."""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from .common import Quiet, command, stderr, stdout
from .options import (
    CalibrationIn,
    Force,
    JointMap,
    JointPrefix,
    Json,
    LabelTopic,
    LinkTopic,
    Robot,
    SimTopic,
    Topic,
)

if TYPE_CHECKING:
    from twincd.live import WatchEvent, WatchItem, WatchNotice, WatchStatus, WatchSummary


LiveSource = Annotated[
    str,
    typer.Argument(
        help="ws://HOST:PORT (a foxglove_bridge), ros2 (rclpy) or zenoh/tcp/HOST:PORT "
        "(rmw_zenoh's router)."
    ),
]
RecordOut = Annotated[
    Path | None,
    typer.Option(
        "--output",
        "-o",
        help="Record the session: what arrived plus twincd's channels (.mcap), written as it goes.",
    ),
]
Duration = Annotated[
    float | None, typer.Option("--duration", help="Stop after this many seconds.", min=0)
]
IdleTimeout = Annotated[
    float | None,
    typer.Option("--idle-timeout", help="Stop after this many seconds without a message.", min=0),
]
ConnectTimeout = Annotated[
    float,
    typer.Option(
        "--connect-timeout",
        help="Seconds to wait for the source and its first usable JointState.",
        min=0,
    ),
]
ReorderWindow = Annotated[
    float,
    typer.Option(
        "--reorder-window",
        help="Milliseconds a sample is held so that samples out of order are sorted "
        "(0: none; later ones are dropped and counted).",
        min=0,
    ),
]


@contextlib.contextmanager
def _stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """SIGINT and SIGTERM end the session (the summary is still printed)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        stop.set()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _event_row(item: WatchEvent) -> str:
    e = item.event
    link = e.link or "-"
    return (
        f"collision  {e.start_ns * 1e-9:.3f}–{e.end_ns * 1e-9:.3f} s  "
        f"{e.duration_s:.2f} s  peak {e.peak_score:.4g}  joint {e.joint}  link {link}"
    )


def _status_line(item: WatchStatus, source: str) -> str:
    latency = "-" if math.isnan(item.latency_ms) else f"{item.latency_ms:.1f} ms"
    score = "-" if math.isnan(item.score) else f"{item.score:.3g}"
    return (
        f"{source}: {item.rate_hz:.0f} Hz, latency {latency}, score {score} / "
        f"{item.threshold:.3g}, {item.events} event(s), {item.samples} samples"
    )


def _summary_line(item: WatchSummary) -> str:
    verdict = "collision" if item.collision else "no collision"
    back = f", source back {item.reconnects}×" if item.reconnects else ""
    return (
        f"{verdict}: {item.events} event(s) in {item.samples} samples "
        f"({item.elapsed_s:.1f} s, ended: {item.ended}{back})"
    )


def _notice_line(item: WatchNotice) -> str:
    """A notice on stderr as every warning (or note) is written."""
    return f"twincd: {'warning: ' if item.warning else ''}{item.text}"


def _emit(obj: dict[str, Any]) -> None:
    """One JSON line on stdout (--json), flushed at once."""
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _show(items: Iterable[WatchItem], source: str, json_: bool, quiet: bool) -> WatchSummary | None:
    """Show the session's items as they come: each event and notice (JSON lines with --json),
    a status line redrawn on a terminal (cleared before any other line and at the end); the
    summary that ends them is returned, not shown."""
    from twincd.live import WatchEvent, WatchNotice, WatchStatus, WatchSummary

    status_shown = False
    terminal = stderr.is_terminal and not quiet
    summary: WatchSummary | None = None
    for item in items:
        if isinstance(item, WatchStatus):
            if terminal:
                stderr.file.write("\r\x1b[2K" + _status_line(item, source))
                stderr.file.flush()
                status_shown = True
            continue
        if status_shown:
            stderr.file.write("\r\x1b[2K")
            status_shown = False
        if isinstance(item, WatchEvent):
            if json_:
                _emit(item.to_dict())
            else:
                stdout.print(_event_row(item), markup=False, highlight=False)
                sys.stdout.flush()
        elif isinstance(item, WatchNotice):
            if json_:
                _emit(item.to_dict())
            elif not quiet:
                stderr.file.write(_notice_line(item) + "\n")
                stderr.file.flush()
        elif isinstance(item, WatchSummary):
            summary = item
    if status_shown:
        stderr.file.write("\r\x1b[2K")
    return summary


def _exit_with_summary(summary: WatchSummary | None, json_: bool) -> NoReturn:
    """Print the summary and leave with the session's exit code: 1 for a collision, 0 for
    none, 2 when the session ended on an error."""
    if summary is None:  # pragma: no cover - the iterator always ends with one
        raise typer.Exit(3)
    if json_:
        _emit(summary.to_dict())
    else:
        stdout.print(_summary_line(summary), markup=False, highlight=False)
    if summary.error:
        sys.stderr.write(f"twincd: error: {summary.error}\n")
        raise typer.Exit(2)
    raise typer.Exit(1 if summary.collision else 0)


@command
def watch(
    source: LiveSource,
    calibration: CalibrationIn,
    topic: Topic = None,
    label_topic: LabelTopic = None,
    link_topic: LinkTopic = None,
    sim_topic: SimTopic = None,
    joint_map: JointMap = None,
    joint_prefix: JointPrefix = None,
    robot: Robot = None,
    json_: Json = False,
    output: RecordOut = None,
    duration: Duration = None,
    idle_timeout: IdleTimeout = None,
    connect_timeout: ConnectTimeout = 10.0,
    reorder_window: ReorderWindow = 20.0,
    force: Force = False,
    quiet: Quiet = False,
) -> None:
    """Watch a running robot: live collision detection on its joint states.

    Runs the calibration's causal chain (fit it with --causal): the events and flags are
    those of `detect --causal` on the same messages. Prints each event when it closes, a
    status line on a terminal, a line when the source goes away and comes back or is sampled
    at another rate than the calibration, and a summary at the end (--duration,
    --idle-timeout, Ctrl-C). The topics, joint names and robot URDF default to the
    calibration's.

    Exit code 1 when a collision was seen, 0 when none, 2 on errors, 3 on a defect in twincd.

    Example: twincd watch ws://localhost:8765 -c calibration.json -o session.mcap
    """
    from twincd.io.options import parse_joint_map
    from twincd.live import watch as live_watch

    stop = threading.Event()
    with _stop_on_signals(stop):
        items = live_watch(
            source,
            calibration,
            topic=topic,
            label_topic=label_topic,
            link_topic=link_topic,
            sim_topic=sim_topic,
            joint_map=None if joint_map is None else parse_joint_map(joint_map),
            joint_prefix=joint_prefix,
            robot=robot,
            record=output,
            force=force,
            duration_s=duration,
            idle_timeout_s=idle_timeout,
            connect_timeout_s=connect_timeout,
            reorder_ns=round(reorder_window * 1e6),
            stop=stop,
        )
        summary = _show(items, source, json_, quiet)
    _exit_with_summary(summary, json_)
