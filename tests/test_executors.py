"""twincd.executors: a pool changes the speed, never the answer or the error."""

from __future__ import annotations

import pickle

import pytest

from twincd.errors import LogReadError, TwincdError
from twincd.executors import POOL_MIN_BYTES, Bound, Executor


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


def test_automatic_jobs_keep_small_logs_in_this_process(tmp_path) -> None:  # type: ignore[no-untyped-def]
    logs = []
    for i in range(40):  # forty sample-sized logs: less work than starting workers
        logs.append(tmp_path / f"{i}.mcap")
        logs[-1].write_bytes(b"x" * 1000)
    assert Executor.for_logs(0, logs).workers == 1
    assert Executor.for_logs(2, logs).workers == 2  # asked for explicitly: as asked
    big = []
    for i in range(2):  # enough work to pay for a pool (sparse files: no disk used)
        big.append(tmp_path / f"big{i}.mcap")
        with open(big[-1], "wb") as f:
            f.truncate(POOL_MIN_BYTES // 2 + 1)
    assert Executor.for_logs(0, big).workers == Executor(0).workers
    assert Executor.for_logs(0, big[:1]).workers == 1  # one log: nothing to share out


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
