"""What every command shares: the settings it takes by name, how it runs its logs (local
processes or Dask, keep-going, a progress display), the reports it checks before any work, and
what it hands back (its warnings as data, the logs that failed)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict, TypeVar

from twincd.executors.run import RUN_FIELDS, LogFailure, ProgressDisplay, Running

if TYPE_CHECKING:
    from twincd.prepare.settings import SetupOptions
    from twincd.signal.filters import LowPass

T = TypeVar("T")


class Settings(TypedDict, total=False):
    """How to read logs, by name (``twincd.SetupOptions``' fields): the keyword arguments of
    every command. With a calibration, what it learned (the filter; the joints after the map
    and the robot's dynamics, checked as logs are read) may not be contradicted; how a
    recording is read (topics, joint names, the URDF's path) overrides its defaults."""

    robot: str | None  # example-robot-data name or URDF path
    topic: str | None
    label_topic: str | None
    sim_topic: str | None
    link_topic: str | None
    joint_map: Mapping[str, str] | None  # log joint name → model joint name
    joint_prefix: str | None  # taken off log joint names that start with it
    cutoff_hz: float | None
    filter_order: int | None
    filter_kind: str | None
    causal: bool | None
    fast_cutoff_hz: float | None  # fit: the fast band's upper cut-off (0: none)
    strict: bool  # refuse a truncated log instead of reading up to the damage
    allow_urdf_change: bool  # accept a robot model whose dynamics differ from the calibration's
    start: float | str | None  # the window judged: seconds from a log's first sample, or "@" and
    end: float | str | None  # seconds since the epoch (twincd.io.window)


class RunOptions(TypedDict, total=False):
    """How a command runs its logs (``twincd.run_logs``): ``jobs`` local processes (0: every
    core, none for logs too small to pay for them), or the Dask cluster at ``scheduler``
    (``"local"``: a LocalCluster); with ``keep_going`` a failing log is reported to
    ``on_failure`` (by default a warning) and the others go on; ``progress`` opens a display
    the run advances as logs finish."""

    jobs: int
    scheduler: str | None
    keep_going: bool
    progress: ProgressDisplay | None
    on_failure: Callable[[LogFailure], None]


class Options(Settings, RunOptions, total=False):
    """The keyword arguments every command that runs many logs takes."""


def split_options(options: Options) -> tuple[Running, SetupOptions]:
    """The one run object (``Running``) and the one settings object (``SetupOptions``) of a
    command's keyword arguments: every command goes on with these two alone, each option's
    default written once, in its dataclass (an unknown keyword is a ``TypeError``, as any
    function's)."""
    from twincd.prepare.settings import SetupOptions

    given: dict[str, Any] = dict(options)
    run = {name: given.pop(name) for name in RUN_FIELDS if name in given}
    return Running(**run), SetupOptions(**given)


def filter_settings(lowpass: LowPass) -> Settings:
    """The settings that ask for ``lowpass`` (e.g. to fit with a filter built elsewhere)."""
    return Settings(
        cutoff_hz=lowpass.cutoff_hz,
        filter_order=lowpass.order,
        causal=lowpass.causal,
        filter_kind=lowpass.kind,
    )


@dataclass(frozen=True, kw_only=True)
class CommandRun:
    """What every command hands back besides its answer: the warnings it gave (one line each,
    in order; also logged on the ``twincd`` logger as they came) and, with ``keep_going``, the
    logs that failed."""

    warnings: tuple[str, ...] = ()
    failures: tuple[LogFailure, ...] = field(default=())

    @property
    def exit_code(self) -> int:
        """The command's exit code (contract: Exit codes): 0, or 2 when a log failed (3 when a
        failure was a defect in twincd)."""
        return max((f.error.exit_code for f in self.failures), default=0)


def check_reports(
    report: str | Path | None,
    junit: str | Path | None,
    *,
    force: bool = False,
    inputs: Sequence[Path] = (),
) -> tuple[Path | None, Path | None]:
    """The report's and the JUnit file's paths; fails before any work when one cannot be
    written, or would replace something that is not twincd's own report of that kind (unless
    ``force``)."""
    from twincd.io.atomic import check_target
    from twincd.reports import check_report_kind

    report, junit = as_path(report), as_path(junit)
    if report is not None:
        check_report_kind(report)
        check_target(report, "report", force=force, inputs=inputs)
        if report.suffix.lower() == ".html":
            from twincd.reports.figures import pyplot

            pyplot()  # a missing plot extra is an error now, not after the work
    if junit is not None:
        check_target(junit, "junit", force=force, inputs=inputs)
    return report, junit


def as_path(path: str | Path | None) -> Path | None:
    return None if path is None else Path(path)


def input_files(given: Iterable[object]) -> list[Path]:
    """The files among ``given`` (a calibration in memory, or none, is no file)."""
    return [Path(g) for g in given if isinstance(g, str | Path)]
