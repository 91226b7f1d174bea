"""Running per-log work over many logs: serially, on a pool of local processes, or (in
twincd.cluster) on a Dask cluster.

Every command is one shape: a pure per-log function of (path, settings) that returns a small
picklable result (fit statistics, score statistics, a detection summary), and a merge that does
not depend on the order of the results. So a pool changes the speed, never the answer; results
come back in the order of the logs given.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import logging
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

if TYPE_CHECKING:
    from concurrent.futures import Future

from twincd.errors import InternalError, TwincdError
from twincd.twin.dynamics import default_threads
from twincd.twin.openmp import prefer_passive_wait

T = TypeVar("T")
# logs just finished, and the samples they held: what a progress display shows
Progress = Callable[[int, int], None]
# below this, an automatic run stays serial: per-log work runs at about 30 ms per MB of MCAP,
# and a pool whose workers are forked starts in milliseconds but pays the imports a serial run
# would pay later (benchmarks/bench_fleet.py, 2 cores: -j 2 even with -j 1 on 10 sample logs,
# 3.8 MB; 1.1–1.2× on 40, 15 MB); one that starts a forkserver costs ≈ 0.85 s more (40 logs:
# -j 2 took 1.85 s where -j 1 took 1.30 s), so then two workers only pay past ≈ 45 MB of logs
POOL_MIN_BYTES = {"fork": 10_000_000, "forkserver": 50_000_000, "spawn": 50_000_000}
# what a worker needs for any command; importing them starts no OpenMP thread
PRELOAD = (
    "numpy",
    "scipy.linalg.lapack",
    "pinocchio",
    "twincd.pipeline",
    "twincd.outputs",
    "twincd.threshold",
    "twincd.io.stream",
    "mcap.reader",  # and the decompressors it loads
    "lz4.frame",
    "zstandard",
)
R = TypeVar("R")


@dataclass(frozen=True)
class Executor:
    """How to run per-log work: ``jobs`` local processes (1: in this process)."""

    jobs: int = 0  # 0: every core this process may use

    @property
    def workers(self) -> int:
        return self.jobs if self.jobs > 0 else default_threads()

    @classmethod
    def for_logs(cls, jobs: int, paths: Sequence[Path]) -> Executor:
        """``jobs`` processes; with 0 (every core), a run whose logs are too small to pay for
        starting workers stays in this process (``POOL_MIN_BYTES``)."""
        if jobs == 0 and (len(paths) < 2 or _size(paths) < POOL_MIN_BYTES[start_method()]):
            return cls(1)
        return cls(jobs)

    def map(
        self,
        func: Callable[[T], R],
        items: Sequence[T],
        progress: Progress | None = None,
    ) -> list[R]:
        """``[func(item) for item in items]``, in that order; the first error is raised once the
        work already running has stopped (no output of a failed run is left half-written: each
        writer renames its file into place only when done)."""
        workers = min(self.workers, len(items))
        if workers <= 1:
            out = []
            for item in items:
                out.append(func(item))
                if progress:
                    progress(1, samples_in(out[-1]))
            return out
        return list(_pooled(func, items, workers, progress))


def _pooled(
    func: Callable[[T], R],
    items: Sequence[T],
    workers: int,
    progress: Progress | None,
) -> Iterator[R]:
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    prefer_passive_wait()  # before a worker or this process loads Pinocchio's OpenMP
    method = start_method()
    context = multiprocessing.get_context(method)
    if method == "fork":
        # the workers inherit what this process imported: import it once, here
        for module in PRELOAD:
            with contextlib.suppress(ImportError):  # as a forkserver's preload does
                importlib.import_module(module)
    elif method == "forkserver":
        # import the heavy modules once in the server, not once per worker (≈ 1 s each)
        context.set_forkserver_preload(list(PRELOAD))
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_init) as pool:
        # the objects alive now are the children's too: out of the collector's sight, so that
        # collecting in a child does not copy every page they sit on (copy-on-write)
        gc.freeze()
        try:
            futures: list[Future[R]] = [pool.submit(func, item) for item in items]
        finally:
            gc.unfreeze()
        pending = set(futures)
        try:
            while pending:
                done, pending = wait(
                    pending, return_when=FIRST_COMPLETED
                )  # progress as logs finish
                failed = [f for f in done if f.exception() is not None]
                if progress:
                    progress(
                        len(done), sum(samples_in(f.result()) for f in done if f not in failed)
                    )
                if failed:
                    for f in pending:
                        f.cancel()
                    wait(pending)
                    raise failed[0].exception()  # type: ignore[misc]
        except KeyboardInterrupt:
            _stop_workers(pool)  # Ctrl-C or SIGTERM: the workers remove their temporaries
            raise
        for f in futures:
            yield f.result()


def start_method() -> str:
    """How a pool starts its workers: ``fork`` when this process is in a state a child can
    inherit, as a command's process is before it has done any work (workers then start in
    milliseconds, where a forkserver costs ≈ 0.5 s of imports before the first log); otherwise
    ``forkserver`` (children from a clean process), or ``spawn`` where there is neither.

    Not fork once an OpenMP team has run here (Pinocchio's batched RNEA on several threads, or
    torch, loaded by the learned baselines): a forked child of such a process hangs at its own
    first parallel region. Nor with other Python threads running (a lock one of them holds
    stays held in the child forever)."""
    import threading

    from twincd.twin.dynamics import openmp_team_started

    methods = multiprocessing.get_all_start_methods()
    safe = not openmp_team_started() and "torch" not in sys.modules
    # only on Linux: macOS system libraries are not fork-safe (Python's default there is spawn)
    linux = sys.platform.startswith("linux")
    if linux and "fork" in methods and safe and threading.active_count() == 1:
        return "fork"
    return "forkserver" if "forkserver" in methods else "spawn"


def _stop_workers(pool: Any) -> None:
    """SIGTERM to every worker (each raises ``Terminated`` and cleans up), then no waiting for
    work that would only be thrown away."""
    for process in list(getattr(pool, "_processes", {}).values()):
        with contextlib.suppress(Exception):
            process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def _size(paths: Sequence[Path]) -> int:
    """Bytes of the logs (a folder: its files)."""
    total = 0
    for path in paths:
        files = [path] if path.is_file() else [f for f in path.rglob("*") if f.is_file()]
        total += sum(f.stat().st_size for f in files)
    return total


def _worker_init() -> None:
    """Each worker is one core's worth of work: the twin must not start threads of its own;
    SIGTERM cleans up like in the main process."""
    from twincd.errors import raise_terminated

    os.environ["TWINCD_TWIN_THREADS"] = "1"
    signal.signal(signal.SIGTERM, raise_terminated)


@dataclass(frozen=True)
class Outcome(Generic[R]):
    """What one log's work came to: its result or its error (a ``TwincdError``), and the
    warnings logged while it ran (one line each), whichever executor ran it."""

    value: R | None
    error: TwincdError | None
    warnings: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.error is None


class Captured(Generic[T, R]):
    """``func(item)`` as an ``Outcome`` (picklable, for any executor): twincd's warnings are
    gathered instead of printed; with ``keep_going`` a ``TwincdError`` becomes the outcome's
    error, and any other exception (a defect) an ``InternalError`` naming the log (exit 3);
    otherwise it is raised and stops the run."""

    def __init__(self, func: Callable[[T], R], keep_going: bool = False) -> None:
        self.func = func
        self.keep_going = keep_going

    def __call__(self, item: T) -> Outcome[R]:
        with captured_warnings() as warnings:
            try:
                value = self.func(item)
            except Exception as exc:
                if not self.keep_going:
                    raise
                error = exc if isinstance(exc, TwincdError) else defect(exc, item)
                return Outcome(None, error, tuple(warnings))
        return Outcome(value, None, tuple(warnings))


def log_path(item: object) -> Path | None:
    """The log a per-log item stands for: the item itself, or the first part of a tuple."""
    if isinstance(item, tuple) and item:
        item = item[0]
    return item if isinstance(item, Path) else None


def defect(exc: BaseException, item: object) -> InternalError:
    """An unexpected exception of one log's work, as the error that names the log."""
    path = log_path(item)
    return InternalError.from_exception(exc, "" if path is None else str(path))


class _Keep(logging.Filter):
    """Keeps the message of each of twincd's warnings (one line each); ``passes``: the warning
    goes on to the logger's handlers as well, else it stops here."""

    def __init__(self, into: list[str], passes: bool) -> None:
        super().__init__()
        self.into = into
        self.passes = passes

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        self.into.append(" ".join(record.getMessage().splitlines()))
        return self.passes


@contextlib.contextmanager
def _kept(passes: bool) -> Iterator[list[str]]:
    # a filter on the ``twincd`` logger, first in line (the innermost block decides): the
    # logger's handlers, the user's logging set-up, stay as they are
    logger = logging.getLogger("twincd")
    found: list[str] = []
    keep = _Keep(found, passes)
    logger.filters.insert(0, keep)
    try:
        yield found
    finally:
        logger.removeFilter(keep)


def captured_warnings() -> contextlib.AbstractContextManager[list[str]]:
    """The messages of twincd's warnings logged inside the block, held back (not printed):
    a log's work gives them to whoever runs it, who logs them once the log is done."""
    return _kept(passes=False)


def gathered_warnings() -> contextlib.AbstractContextManager[list[str]]:
    """The messages of twincd's warnings logged inside the block (one line each), which go on
    to the logger's handlers as usual: a command's warnings as data."""
    return _kept(passes=True)


class Bound(Generic[T, R]):
    """A picklable ``func(item, *args)`` (a lambda or closure cannot cross to a process)."""

    def __init__(self, func: Callable[..., R], *args: Any) -> None:
        self.func = func
        self.args = args

    def __call__(self, item: T) -> R:
        return self.func(item, *self.args)


# ------------------------------------------------------------------ one interface, two backends


class MapExecutor(Protocol):
    """What every backend offers (local processes here, a Dask cluster in twincd.cluster)."""

    def map(
        self, func: Callable[[T], R], items: Sequence[T], progress: Progress | None = None
    ) -> list[R]: ...


def samples_in(result: object) -> int:
    """The samples a per-log result covers (its ``samples``), for progress in samples/s."""
    if isinstance(result, Outcome):  # a result wrapped with its warnings (Captured)
        result = result.value
    samples = getattr(result, "samples", 0)
    return samples if isinstance(samples, int) else 0
