"""What every subcommand shares: log options, error mapping to exit codes, stderr messages."""

from __future__ import annotations

import contextlib
import errno
import functools
import inspect
import json
import logging
import os
import signal
import sys
import threading
import time
import traceback
import typing
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer
from rich.console import Console

from twincd.commands import LogsFailed, RunOptions
from twincd.errors import InternalError, OutputError, Terminated, TwincdError, raise_terminated

if TYPE_CHECKING:
    from twincd.commands import CommandRun
    from twincd.executors.local import Progress
    from twincd.executors.run import LogFailure

log = logging.getLogger("twincd")

# the two options every command takes (``command`` declares them)
Quiet = Annotated[
    bool, typer.Option("--quiet", "-q", help="Silence stderr except errors.", metavar="")
]
Debug = Annotated[bool, typer.Option("--debug", help="Show tracebacks on errors.", metavar="")]

stderr = Console(stderr=True, highlight=False)
# not a terminal (a CI log, a pipe): no 80-column default that would cut tables
stdout = Console(highlight=False, width=None if sys.stdout.isatty() else 1000)


class _StderrHandler(logging.Handler):
    def __init__(self, quiet: bool) -> None:
        super().__init__()
        self.quiet = quiet

    def emit(self, record: logging.LogRecord) -> None:
        level = record.levelname.lower()
        prefix = "twincd: " if record.levelno < logging.WARNING else f"twincd: {level}: "
        text = " ".join(record.getMessage().splitlines())  # one line each
        if self.quiet and record.levelno < logging.ERROR:
            return
        if stderr.is_terminal:  # through rich: never glued onto a progress bar's line
            stderr.print(prefix + text, markup=False, highlight=False, soft_wrap=True)
        else:
            sys.stderr.write(prefix + text + "\n")


def setup_logging(quiet: bool, debug: bool) -> None:
    logger = logging.getLogger("twincd")
    logger.handlers[:] = [_StderrHandler(quiet)]
    logger.propagate = False
    logger.setLevel(logging.WARNING if quiet else logging.DEBUG if debug else logging.INFO)


# library setting names (TwincdError.option) → the flags that set them; library messages
# never name a flag, so the CLI adds them here
FLAGS: dict[str, str] = {
    "robot": "--robot",
    "train": "--train",
    "val": "--val",
    "test": "--test",
    "methods": "--methods",
    "repeats": "--repeats",
    "label_topic": "--label-topic",
    "topic": "--topic",
    "sim_topic": "--sim-topic",
    "joint_map": "--joint-map",
    "joint_prefix": "--joint-prefix",
    "calibration": "-c/--calibration",
    "jobs": "--jobs",
    "scheduler": "--scheduler",
    "seed": "--seed",
    "min_duration": "--min-duration",
    "max_duration": "--max-duration",
    "in_place": "--in-place",
    "output": "--output",
    "model": "--model",
    "cutoff_hz": "--cutoff",
    "fast_cutoff_hz": "--fast-cutoff",
    "filter_order": "--filter-order",
    "causal": "--causal/--zero-phase",
    "sigma": "-k/--sigma",
    "filter_kind": "--filter-kind",
    "false_alarms_per_hour": "--false-alarms-per-hour",
    "link_topic": "--link-topic",
    "report": "--report",
    "junit": "--junit",
    "no_summary": "--no-summary",
    "force": "--force",
    "strict": "--strict",
    "keep_going": "--keep-going",
    "allow_urdf_change": "--allow-urdf-change",
}


# per command, settings whose flag is not that command's own (declared here: no command
# rewrites FLAGS when it runs)
COMMAND_FLAGS: dict[str, dict[str, str]] = {"watch": {"causal": "fit --causal"}}


def flag_hint(option: str | None, command: str | None = None) -> str:
    """``(option --robot)`` for ``option="robot"``, ``(options --train, --val)`` for
    ``"train,val"``; an unmapped name becomes ``--name-with-dashes``; empty for None.
    ``command``: the subcommand's name (``COMMAND_FLAGS``; None: the one running, if any)."""
    names = [n.strip() for n in (option or "").split(",") if n.strip()]
    if not names:
        return ""
    known = {**FLAGS, **COMMAND_FLAGS.get(command or _running_command(), {})}
    flags = [known.get(n, "--" + n.replace("_", "-")) for n in names]
    return f"({'option' if len(flags) == 1 else 'options'} {', '.join(flags)})"


def _running_command() -> str:
    """The name of the subcommand running (empty outside one)."""
    import click

    ctx = click.get_current_context(silent=True)
    return (ctx.info_name or "") if ctx is not None else ""


def error_line(exc: TwincdError) -> str:
    """The error's one line (contract: Exit codes and streams) with the flags of the setting it
    concerns."""
    text = exc.message
    hint = flag_hint(exc.option)
    if hint:
        text += f" {hint}"
    return " ".join(text.splitlines())  # one line, whatever the parts hold


def report_error(exc: TwincdError) -> None:
    """The error's one line on stderr: ``twincd: error: …``, or ``twincd: internal error: …``
    for a defect (exit 3)."""
    kind = "internal error" if isinstance(exc, InternalError) else "error"
    sys.stderr.write(f"twincd: {kind}: {error_line(exc)}\n")


def fail(exc: TwincdError, debug: bool) -> NoReturn:
    """Print the one-line error (with ``debug``, its traceback first) and leave with its exit
    code: 2 for an error of use, input or output, 3 for a defect."""
    if debug:
        if isinstance(exc, InternalError) and exc.details:
            sys.stderr.write(exc.details)
        else:
            traceback.print_exception(exc)
    report_error(exc)
    raise typer.Exit(exc.exit_code)


# exceptions typer turns into exit codes itself (its exits, aborts and usage errors)
TYPER_EXITS = (typer.Exit, typer.Abort, typer.TyperException)


def command(func: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a subcommand: its --quiet and --debug (declared here, last; the command gets them
    only if it names them); logging set-up; TwincdError → one line on stderr and its exit code;
    any other exception (a defect) → one ``internal error`` line and exit 3, never 1 (which
    CI reads as "collision found"); a closed stdout ends quietly."""
    shared = {"quiet": Quiet, "debug": Debug}
    declared = inspect.signature(func)
    names = declared.parameters
    kinds = typing.get_type_hints(func, include_extras=True)
    params = [p.replace(annotation=kinds.get(p.name, p.annotation)) for p in names.values()] + [
        inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=False, annotation=kind)
        for n, kind in shared.items()
        if n not in names
    ]
    # the flags go on to a command that names them, and to ``options.reads``' wrapper, which
    # takes **kwargs (its run options need --quiet)
    code = getattr(func, "__code__", None)
    passed = set(shared) if code and code.co_flags & inspect.CO_VARKEYWORDS else set(names)

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        quiet, debug = (
            bool(kwargs.get(n) if n in passed else kwargs.pop(n, False)) for n in shared
        )
        setup_logging(quiet, debug)
        try:
            with terminate_like_interrupt(), closed_stdout_ends_quietly():
                return func(*args, **kwargs)
        except LogsFailed as exc:  # each failure was reported as it came (``run_options``)
            raise typer.Exit(exc.exit_code) from None
        except TwincdError as exc:
            fail(exc, debug)
        except Terminated:
            sys.stderr.write("twincd: terminated\n")
            raise typer.Exit(143) from None
        except KeyboardInterrupt:
            sys.stderr.write("twincd: interrupted\n")
            raise typer.Exit(130) from None
        except TYPER_EXITS:
            raise
        except Exception as exc:
            stop = _stopped_by(exc)
            if stop is not None:  # a signal that landed where Python wraps what it raises
                sys.stderr.write(f"twincd: {'terminated' if stop == 143 else 'interrupted'}\n")
                raise typer.Exit(stop) from None
            fail(InternalError.from_exception(exc), debug)

    wrapper.__signature__ = declared.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params}
    return wrapper


def _stopped_by(exc: BaseException) -> int | None:
    """143 or 130 when ``exc`` was caused by SIGTERM (``Terminated``) or Ctrl-C: a signal that
    arrives while a class is being created comes back wrapped ("Error calling __set_name__"),
    which is not a defect of twincd. None otherwise."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, Terminated):
            return 143
        if isinstance(cause, KeyboardInterrupt):
            return 130
        cause = cause.__cause__ or cause.__context__
    return None


class _QuietStdout:
    """Standard output that a reader may close (``twincd detect … | head -1``): the first
    write that finds the pipe closed points file descriptor 1 at /dev/null, the way Unix tools
    end, so neither the next write nor Python's flush at exit fails; the run goes on to its own
    exit code (1 for a finding, never because of the pipe). Another failure to write stdout
    (``> /dev/full``) is an ``OutputError``."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.gone = False

    def write(self, text: str) -> int:
        if not self.gone:
            self._guarded(self.inner.write, text)
        return len(text)

    def flush(self) -> None:
        if not self.gone:
            self._guarded(self.inner.flush)

    def _guarded(self, call: Callable[..., Any], *args: Any) -> None:
        try:
            call(*args)
        except OSError as exc:
            self.gone = True
            with contextlib.suppress(OSError, ValueError, AttributeError):
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, self.inner.fileno())
                os.close(devnull)
            if exc.errno != errno.EPIPE:
                raise OutputError(
                    f"cannot write standard output: {exc.strerror}",
                    "stdout",
                    "redirect it to a file on a disk with space",
                ) from exc

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@contextlib.contextmanager
def closed_stdout_ends_quietly() -> Iterator[None]:
    """``sys.stdout`` guarded by ``_QuietStdout`` while the block runs (once, if nested); what
    is still buffered is flushed through the guard at the end."""
    if isinstance(sys.stdout, _QuietStdout):
        yield
        return
    guard = _QuietStdout(sys.stdout)
    sys.stdout = guard
    try:
        yield
        guard.flush()
    finally:
        sys.stdout = guard.inner
        if not guard.gone:
            with contextlib.suppress(OSError, ValueError):
                guard.flush()


def internal_error_exit(exc: Exception, debug: bool) -> NoReturn:
    """A defect outside any subcommand (typer itself, a callback): one line, exit 3."""
    try:
        fail(InternalError.from_exception(exc), debug)
    except typer.Exit as done:
        raise SystemExit(done.exit_code) from None


@contextlib.contextmanager
def terminate_like_interrupt() -> Iterator[None]:
    """SIGTERM raises ``Terminated`` (a KeyboardInterrupt) while the block runs, so that
    temporaries are removed as on Ctrl-C; the previous handler comes back after."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    previous = signal.signal(signal.SIGTERM, raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def show_progress(quiet: bool) -> bool:
    return not quiet and sys.stderr.isatty() and os.environ.get("TERM") != "dumb"


@contextlib.contextmanager
def counter(
    total: int, description: str, quiet: bool, minimum: int = 2
) -> Iterator[Callable[[int, int], None]]:
    """A progress bar over ``total`` logs (logs done / total, samples/s) that the work advances
    by calling the yielded function with the logs just done and their samples (only when
    stderr is a terminal and there are at least ``minimum`` logs); with fewer, one log's
    samples as they stream (``samples_progress``)."""
    if not show_progress(quiet):
        yield lambda _logs, _samples: None
        return
    if total < minimum:
        with samples_progress(description):
            yield lambda _logs, _samples: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    started = time.perf_counter()
    samples = 0
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("logs  {task.fields[rate]}"),
    )
    # redrawn as logs finish, not by a refresh thread: with a thread running, a process pool
    # must start its workers from a forkserver (≈ 0.85 s) instead of forking them
    with Progress(*columns, console=stderr, transient=True, auto_refresh=False) as bar:
        task = bar.add_task(description, total=total, rate="")
        bar.refresh()

        def advance(logs: int, done_samples: int) -> None:
            nonlocal samples
            samples += done_samples
            rate = samples / max(time.perf_counter() - started, 1e-9)
            bar.update(task, advance=logs, rate=f"{rate:,.0f} samples/s", refresh=True)

        yield advance


# a progress line within a log is redrawn at most this often (s)
SAMPLES_REDRAW_S = 0.1


@contextlib.contextmanager
def samples_progress(description: str) -> Iterator[None]:
    """One log's samples as they stream through the chain, their rate and the time taken, on
    stderr (the caller checks it is a terminal); the library tells of each block
    (``twincd.prepare.progress``) when the log runs in this process."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from twincd.prepare.progress import listening

    started = time.perf_counter()
    columns = (
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TextColumn("{task.completed:,.0f} samples  {task.fields[rate]}"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=stderr, transient=True, auto_refresh=False) as bar:
        task = bar.add_task(description, total=None, rate="")
        bar.refresh()
        drawn = 0.0

        def advance(samples: int) -> None:
            nonlocal drawn
            bar.update(task, advance=samples)
            now = time.perf_counter()
            if now - drawn >= SAMPLES_REDRAW_S:
                done = bar.tasks[0].completed
                rate = done / max(now - started, 1e-9)
                bar.update(task, rate=f"{rate:,.0f} samples/s", refresh=True)
                drawn = now

        with listening(advance):
            yield


def run_options(
    quiet: bool, jobs: int = 0, scheduler: str | None = None, keep_going: bool = False
) -> RunOptions:
    """The run options of a library command: a progress bar on stderr (a terminal only), each
    failing log reported in one error line as it comes (``--keep-going``)."""

    def display(total: int, description: str) -> contextlib.AbstractContextManager[Progress]:
        return counter(total, description, quiet)

    def on_failure(failure: LogFailure) -> None:
        report_error(failure.error)

    return RunOptions(
        jobs=jobs,
        scheduler=scheduler,
        keep_going=keep_going,
        progress=display,
        on_failure=on_failure,
    )


def error_docs(run: CommandRun) -> list[dict[str, str]]:
    """``"errors": [{"path", "error"}]`` of ``--json`` (contract: Exit codes and streams)."""
    return [{"path": str(f.path), "error": error_line(f.error)} for f in run.failures]


def json_document(run: CommandRun, answer: dict[str, Any], allow_nan: bool = False) -> None:
    """One ``--json`` document on stdout: the command's answer, its errors and warnings."""
    doc = {**answer, "errors": error_docs(run), "warnings": list(run.warnings)}
    stdout.out(json.dumps(doc, allow_nan=allow_nan), highlight=False)


def finish(run: CommandRun) -> None:
    """Leave with the command's exit code when it is not 0 (contract: Exit codes)."""
    if run.exit_code:
        raise typer.Exit(run.exit_code)
