"""twincd.executors: a pool changes the speed, never the answer or the error."""

from __future__ import annotations

import pickle

import pytest

from twincd.errors import LogReadError, TwincdError
from twincd.executors import Bound, Executor


def _square_or_fail(x: int, bad: int) -> int:
    if x == bad:
        raise LogReadError("log is damaged", f"log {x}", "record it again")
    return x * x


def test_errors_survive_pickling_with_their_parts() -> None:
    err = pickle.loads(pickle.dumps(LogReadError("what", "where", "hint")))
    assert isinstance(err, LogReadError) and err.message == "what (where) — hint"


@pytest.mark.parametrize("jobs", [1, 2])
def test_results_come_back_in_input_order(jobs: int) -> None:
    items = list(range(9, -1, -1))
    assert Executor(jobs).map(Bound(_square_or_fail, -1), items) == [x * x for x in items]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_worker_error_is_raised_as_itself(jobs: int) -> None:
    with pytest.raises(TwincdError, match="log 3"):
        Executor(jobs).map(Bound(_square_or_fail, 3), list(range(8)))


def test_automatic_jobs_keep_a_few_small_logs_in_this_process(tmp_path) -> None:  # type: ignore[no-untyped-def]
    logs = []
    for i in range(3):
        logs.append(tmp_path / f"{i}.mcap")
        logs[-1].write_bytes(b"x" * 1000)
    assert Executor.for_logs(0, logs).workers == 1
    assert Executor.for_logs(2, logs).workers == 2  # asked for explicitly: as asked
    many = logs * 3  # nine logs: worth a pool
    assert Executor.for_logs(0, many).workers == Executor(0).workers


class _Counted:
    def __init__(self, samples: int) -> None:
        self.samples = samples


def _counted(n: int) -> _Counted:
    return _Counted(n)


@pytest.mark.parametrize("jobs", [1, 2])
def test_progress_counts_logs_and_their_samples(jobs: int) -> None:
    calls: list[tuple[int, int]] = []
    results = Executor(jobs).map(_counted, [10, 20, 30], lambda logs, n: calls.append((logs, n)))
    assert [r.samples for r in results] == [10, 20, 30]
    assert sum(c[0] for c in calls) == 3 and sum(c[1] for c in calls) == 60
