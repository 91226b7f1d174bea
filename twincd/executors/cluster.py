"""Per-log work on a Dask cluster: the same ``map`` as the local executor (twincd.executors.local),
run by ``dask.distributed`` (the optional extra ``twincd[dask]``).

- ``address`` is a running scheduler's (``tcp://host:8786``), or ``"local"``: a LocalCluster of
  one-thread worker processes on this machine, started for the run and shut down after it.
- Workers read logs, and write per-log outputs, by path: every path must be visible to every
  worker under the same name (shared storage). A worker that cannot see a log says which.
- A worker that dies is replaced and its logs are run again (Dask's own bookkeeping, up to the
  scheduler's ``allowed-failures``); a log that kills workers that often is one clear error.
- Outputs are written where the work runs, to a temporary file renamed into place when done,
  and only the small per-log results travel back. After a failure no work of the run is left
  running (the remaining logs are skipped), so nothing is renamed into place behind the error.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from twincd.errors import ClusterError, LogReadError, UsageError
from twincd.executors.local import Executor, MapExecutor, Progress, log_path, samples_in

T = TypeVar("T")
R = TypeVar("R")

LOCAL = "local"
CONNECT_TIMEOUT_S = 10.0
INSTALL_HINT = "install the Dask extra: pip install 'twincd[dask]'"


class Skipped(Exception):
    """A log not run because the run had already failed (never reaches the user)."""


@dataclass(frozen=True)
class Settled(Generic[R]):
    """How one log's future settled: its result, or the error it raised (``skipped``: never
    started); the local executors' ``Outcome`` is what the caller gets."""

    index: int
    result: R | None = None
    error: BaseException | None = None
    skipped: bool = False


def _require_dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise UsageError(
            "running on a Dask cluster needs dask.distributed, which is not installed",
            "scheduler",
            INSTALL_HINT,
            option="scheduler",
        ) from None
    return distributed


class DaskExecutor:
    """Per-log work on a ``dask.distributed`` cluster; a context manager (connects on enter,
    and shuts down a LocalCluster it started on exit).

    ``workers``: the LocalCluster's worker processes (0: one per core); a running cluster's
    workers are set where they are started.
    """

    def __init__(
        self, address: str, workers: int = 0, connect_timeout: float = CONNECT_TIMEOUT_S
    ) -> None:
        self.address = address
        self.workers = workers
        self.connect_timeout = connect_timeout
        self._client: Any = None
        self._cluster: Any = None

    def __enter__(self) -> DaskExecutor:
        distributed = _require_dask()
        if self.address == LOCAL:
            from twincd.twin.dynamics import default_threads

            try:
                # loopback only, no dashboard: a run opens no port another machine could reach
                self._cluster = distributed.LocalCluster(
                    n_workers=self.workers or default_threads(),
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address=None,
                    # the scheduler's HTTP routes still listen: on a free loopback port, so a
                    # second cluster on the machine brings no "port 8787 in use" warning
                    scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                    # a log's error reaches the user once, as twincd's line, not as worker logs
                    silence_logs=logging.CRITICAL,
                )
            except Exception as exc:
                raise ClusterError(
                    "cannot start a local Dask cluster",
                    " ".join(str(exc).split())[:120] or type(exc).__name__,
                    "run on local processes instead, or check the Dask installation",
                    option="scheduler",
                ) from exc
            address = self._cluster.scheduler_address
        else:
            if self.workers:
                raise UsageError(
                    "a running cluster's workers are set where they are started",
                    self.address,
                    "drop the number of jobs, or start the workers with the size wanted",
                    option="jobs",
                )
            address = self.address
        try:
            self._client = distributed.Client(
                address, timeout=self.connect_timeout, set_as_default=False
            )
        except (OSError, TimeoutError, ValueError) as exc:
            self.__exit__(None, None, None)
            reason = " ".join(str(exc).split())[:120]
            raise ClusterError(
                "cannot reach the Dask scheduler",
                f"{self.address}: {reason}" if reason else self.address,
                "start one with `dask scheduler` (and workers with `dask worker ADDRESS`), "
                "or check the address",
                option="scheduler",
            ) from None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._client is not None:
            with contextlib.suppress(Exception):
                self._client.close()
            self._client = None
        if self._cluster is not None:
            with contextlib.suppress(Exception):
                self._cluster.close()
            self._cluster = None

    def map(
        self, func: Callable[[T], R], items: Sequence[T], progress: Progress | None = None
    ) -> list[R]:
        """``[func(item) for item in items]`` on the cluster, in that order; the first error
        is raised once no work of the run is running any more."""
        results: list[Any] = [None] * len(items)
        for outcome in self.outcomes(func, items, progress, stop_on_error=True):
            if outcome.error is not None:
                raise outcome.error
            results[outcome.index] = outcome.result
        return results

    def outcomes(
        self,
        func: Callable[[T], R],
        items: Sequence[T],
        progress: Progress | None = None,
        stop_on_error: bool = False,
    ) -> Iterator[Settled[R]]:
        """Every log's outcome, as they finish. With ``stop_on_error`` the logs not yet started
        after a failure are skipped, and the failure comes last, once the run has drained."""
        if self._client is None:
            with self:
                yield from self.outcomes(func, items, progress, stop_on_error)
            return
        distributed = _require_dask()
        run = f"twincd-{uuid.uuid4().hex}"
        # set on a failure (with stop_on_error) or an interruption: logs not started are skipped
        stop = distributed.Event(f"{run}-stop", client=self._client)
        futures = self._client.map(
            _on_worker,
            items,
            work=func,
            stop=stop.name,
            key=[f"{run}-{i}" for i in range(len(items))],
            pure=False,
        )
        index = {f.key: i for i, f in enumerate(futures)}
        first_error: Settled[R] | None = None
        try:
            for future in distributed.as_completed(futures, loop=self._client.loop):
                outcome = self._settled(future, index[future.key], items)
                if progress and outcome.error is None and not outcome.skipped:
                    progress(1, samples_in(outcome.result))
                if outcome.error is not None and stop_on_error:
                    if first_error is None:
                        first_error = outcome
                        stop.set()
                    continue
                yield outcome
        except BaseException:  # interrupted (Ctrl-C, SIGTERM): start nothing more
            with contextlib.suppress(Exception):
                stop.set()
                self._client.cancel(futures)
            raise
        if first_error is not None:
            yield first_error

    def _settled(self, future: Any, index: int, items: Sequence[Any]) -> Settled[Any]:
        from distributed import KilledWorker

        try:
            return Settled(index, result=future.result())
        except Skipped:
            return Settled(index, skipped=True)
        except KilledWorker:
            return Settled(
                index,
                error=ClusterError(
                    "workers died while processing the log, more often than the scheduler allows",
                    str(log_path(items[index]) or f"log #{index}"),
                    "check the workers' memory and logs; the rest of the run was stopped",
                ),
            )
        except Exception as exc:
            return Settled(index, error=exc)


def _on_worker(item: T, work: Callable[[T], R], stop: str) -> R:
    """One log on a worker: skipped once the run has failed or was interrupted; a log this
    worker cannot see is an error naming it and the worker's host."""
    if _require_dask().Event(stop).is_set():
        raise Skipped
    # one core's worth of work per task: the twin must not start threads of its own
    os.environ["TWINCD_TWIN_THREADS"] = "1"
    path = log_path(item)
    if path is not None and not path.exists():
        raise LogReadError(
            "a Dask worker cannot see the log",
            f"{path} on {socket.gethostname()}",
            "put the logs on storage every worker mounts under the same path",
        )
    return work(item)


@contextlib.contextmanager
def open_executor(jobs: int, scheduler: str | None, paths: Sequence[Path]) -> Iterator[MapExecutor]:
    """The executor a run asks for: ``scheduler`` (a Dask scheduler's address, or ``"local"``
    for a LocalCluster of ``jobs`` workers) when given, else ``jobs`` local processes; a
    cluster started here is shut down when the block ends."""
    if scheduler is None:
        yield Executor.for_logs(jobs, paths)
        return
    with DaskExecutor(scheduler, workers=jobs) as executor:
        yield executor
