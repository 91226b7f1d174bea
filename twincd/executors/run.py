"""Running one per-log function over many logs: in this process, on local processes or on a Dask
cluster; with ``keep_going`` a failing log is skipped (said in a warning) and the others go on;
outputs of a run that fails are removed again.

>>> from twincd import Setup, run_logs
>>> from twincd.calibration import fit_log
>>> from twincd.executors.local import Bound
>>> run = run_logs(Bound(fit_log, Setup()), paths, jobs=2, keep_going=True)  # doctest: +SKIP
>>> run.results, run.failures, run.exit_code  # doctest: +SKIP

The function must be picklable to run on processes or a cluster (a module-level function, or
``twincd.executors.local.Bound`` for one with settings); results come back in the order of the
items, whatever the executor.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar, cast

from twincd.errors import TwincdError

if TYPE_CHECKING:
    from twincd.executors.local import MapExecutor, Progress

T = TypeVar("T")
R = TypeVar("R")
log = logging.getLogger("twincd")
# maps a per-log function over logs (func, paths, what it does): the results of the logs that
# worked, in the order of the paths (``Running.mapper``; what fit's cross-fitting, threshold's
# and evaluate's per-log work is given)
Each = Callable[[Callable[[Path], Any], Sequence[Path], str], list[Any]]


@dataclass(frozen=True)
class LogFailure:
    """A log whose work failed (with ``keep_going``): the log and its error."""

    path: Path | None
    error: TwincdError


@dataclass(frozen=True)
class LogRun(Generic[R]):
    """A run over many logs: the results of the logs that worked (in the order given) and the
    failures (with ``keep_going``; without it the first failure is raised)."""

    results: list[R] = field(default_factory=list)
    failures: list[LogFailure] = field(default_factory=list)

    @property
    def exit_code(self) -> int:
        """0 when every log worked; else 3 if a failure was a defect in twincd, 2 otherwise."""
        return max((f.error.exit_code for f in self.failures), default=0)


def warn_failure(failure: LogFailure) -> None:
    """The default report of a skipped log: one warning."""
    log.warning("log skipped: %s", failure.error.message)


# opens a progress display for (number of logs, what is being done) and gives the function the
# work calls as logs finish: (logs just done, their samples)
ProgressDisplay = Callable[[int, str], contextlib.AbstractContextManager["Progress"]]


class LogsFailed(TwincdError):
    """Every log of a run failed (with ``keep_going``): nothing to go on with. Each failure was
    reported as it happened (``on_failure``)."""

    def __init__(self, failures: Sequence[LogFailure]) -> None:
        first = failures[0]
        super().__init__(
            f"every log failed ({len(failures)}); the first: {first.error.what}",
            first.error.where,
            first.error.hint,
            option=first.error.option,
        )
        self.failures = list(failures)
        self.exit_code = max(f.error.exit_code for f in failures)

    def __reduce__(self) -> tuple[type[LogsFailed], tuple[list[LogFailure]]]:  # type: ignore[override]
        return (type(self), (self.failures,))


@contextlib.contextmanager
def _no_display(_logs: int, _what: str) -> Iterator[Progress]:
    yield lambda _done, _samples: None


@dataclass(frozen=True)
class Running:
    """How a command runs its per-log work (see ``twincd.run_logs``)."""

    jobs: int = 0
    scheduler: str | None = None
    keep_going: bool = False
    progress: ProgressDisplay | None = None
    on_failure: Callable[[LogFailure], None] = warn_failure

    def each(
        self,
        func: Callable[[T], Any],
        items: Sequence[T],
        what: str,
        *,
        executor: MapExecutor | None = None,
    ) -> LogRun[Any]:
        """``func`` over ``items`` on this run's executor (or ``executor``, which the caller
        holds); a run of its own in which every log failed raises ``LogsFailed``."""
        display = self.progress or _no_display
        with display(len(items), what) as advance:
            run = run_logs(
                func,
                items,
                jobs=self.jobs,
                scheduler=self.scheduler,
                executor=executor,
                keep_going=self.keep_going,
                progress=advance,
                on_failure=self.on_failure,
            )
        if executor is None and run.failures and not run.results:
            raise LogsFailed(run.failures)
        return run

    def mapper(
        self, failed: list[LogFailure], executor: MapExecutor | None = None, doing: str = ""
    ) -> Each:
        """This run as an ``Each`` (``each`` on ``executor``, each description after
        ``doing``): the logs that fail (with ``keep_going``: reported, the others go on) are
        added to ``failed``, each log once however many times it is mapped over."""

        def each(func: Callable[[Path], Any], paths: Sequence[Path], what: str) -> list[Any]:
            if not paths:
                return []
            done = self.each(func, paths, f"{doing}{what}", executor=executor)
            seen = {f.path for f in failed}
            for failure in done.failures:
                if failure.path not in seen:
                    seen.add(failure.path)
                    failed.append(failure)
            return list(done.results)

        return each


# the keyword arguments that say how a command runs (``twincd.commands.RunOptions``)
RUN_FIELDS = tuple(f.name for f in fields(Running))


def run_logs(
    func: Callable[[T], R],
    items: Sequence[T],
    *,
    jobs: int = 0,
    scheduler: str | None = None,
    executor: MapExecutor | None = None,
    keep_going: bool = False,
    progress: Progress | None = None,
    on_failure: Callable[[LogFailure], None] = warn_failure,
    outputs: Sequence[Path] = (),
) -> LogRun[R]:
    """``func`` over ``items`` (a log path each, or a tuple whose first part is the log path).

    Runs on ``executor`` when given, else on the Dask cluster at ``scheduler`` (an address, or
    ``"local"`` for a LocalCluster of ``jobs`` workers), else on ``jobs`` local processes (0:
    every core, in this process when the logs are too small to pay for workers). Each log's
    warnings are logged here once it is done. With ``keep_going`` a failing log becomes a
    ``LogFailure`` (passed to ``on_failure``: by default a warning) and the others go on; without
    it the first error is raised once the work running has stopped. ``outputs``: files the run
    writes, removed again if it fails (see ``all_or_nothing``). ``progress(logs, samples)`` is
    called as logs finish."""
    with all_or_nothing() as written:
        written.extend(outputs)
        if executor is not None:
            return _run_on(executor, func, items, keep_going, progress, on_failure)
        from twincd.executors.cluster import open_executor

        with open_executor(jobs, scheduler, _paths(items)) as opened:
            return _run_on(opened, func, items, keep_going, progress, on_failure)


def _run_on(
    executor: MapExecutor,
    func: Callable[[T], R],
    items: Sequence[T],
    keep_going: bool,
    progress: Progress | None,
    on_failure: Callable[[LogFailure], None],
) -> LogRun[R]:
    from twincd.executors.local import Captured, log_path

    run: LogRun[R] = LogRun()
    for item, outcome in zip(items, executor.map(Captured(func, keep_going), items, progress)):
        for line in outcome.warnings:
            log.warning("%s", line)
        if outcome.error is not None:
            failure = LogFailure(log_path(item), outcome.error)
            on_failure(failure)
            run.failures.append(failure)
        else:
            run.results.append(cast(R, outcome.value))
    return run


def _paths(items: Sequence[object]) -> list[Path]:
    from twincd.executors.local import log_path

    return [p for p in map(log_path, items) if p is not None]


@contextlib.contextmanager
def all_or_nothing() -> Iterator[list[Path]]:
    """Collects the files a run over many logs may write; if the run fails, those it wrote are
    removed again (files older than the run are left alone), so a failed run leaves nothing
    behind, not even the temporaries of a worker killed mid-write."""
    from twincd.io.atomic import remove_stale_temporaries

    started = time.time_ns()
    written: list[Path] = []
    try:
        yield written
    except BaseException:
        for path in written:
            with contextlib.suppress(OSError):
                if path.stat().st_mtime_ns >= started:
                    path.unlink()
        raise
    finally:
        # what a worker killed mid-write left (its log was then written again elsewhere)
        for folder in {path.parent for path in written}:
            remove_stale_temporaries(folder, say=False)
