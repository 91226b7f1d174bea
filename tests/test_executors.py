"""twincd.executors.local: a pool changes the speed, never the answer or the error."""

from __future__ import annotations

import pickle
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from twincd.errors import LogReadError, TwincdError
from twincd.executors.local import POOL_MIN_BYTES, Bound, Executor, start_method


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
    for i in range(8):  # a few small logs: less work than starting workers
        logs.append(tmp_path / f"{i}.mcap")
        logs[-1].write_bytes(b"x" * 1000)
    assert Executor.for_logs(0, logs).workers == 1
    assert Executor.for_logs(2, logs).workers == 2  # asked for explicitly: as asked
    big = []
    for i in range(2):  # enough work to pay for a pool (sparse files: no disk used)
        big.append(tmp_path / f"big{i}.mcap")
        with open(big[-1], "wb") as f:
            f.truncate(POOL_MIN_BYTES[start_method()] // 2 + 1)
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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is used on Linux only")
def test_workers_are_forked_only_while_that_is_safe(monkeypatch: pytest.MonkeyPatch) -> None:
    import twincd.twin.dynamics as dynamics

    monkeypatch.setattr(dynamics, "_team_started", False)
    monkeypatch.delitem(sys.modules, "torch", raising=False)
    monkeypatch.setattr(threading, "active_count", lambda: 1)  # other tests may leave threads
    assert start_method() == "fork"
    monkeypatch.setattr(dynamics, "_team_started", True)  # the batched RNEA ran on 2 threads
    assert start_method() == "forkserver"
    monkeypatch.setattr(dynamics, "_team_started", False)
    monkeypatch.setitem(sys.modules, "torch", object())  # the learned baselines' OpenMP
    assert start_method() == "forkserver"
    monkeypatch.delitem(sys.modules, "torch")
    # another Python thread: a lock it holds would stay held in the child forever
    monkeypatch.setattr(threading, "active_count", lambda: 2)
    assert start_method() == "forkserver"


def _twin_torque(n: int) -> float:
    from twincd.prepare.robots import robot_for
    from twincd.twin.dynamics import inverse_dynamics

    robot = robot_for("xarm7", tuple(f"joint{i}" for i in range(1, 8)))
    q = np.full((n, robot.dof), 0.1)
    return float(inverse_dynamics(robot, q, q, q, threads=2).sum())


def test_a_pool_after_the_twin_ran_on_threads_in_this_process_does_not_hang() -> None:
    """The deadlock fork would bring: OpenMP threads have run here, then a pool's workers run
    OpenMP again. Run in a child process, so that this one stays fork-safe for other tests."""
    code = (
        "from tests.test_executors import _twin_torque\n"
        "from twincd.executors.local import Executor, start_method\n"
        "_twin_torque(64)\n"
        "assert start_method() != 'fork', start_method()\n"
        "print(Executor(2).map(_twin_torque, [64, 64, 64]))\n"
    )
    root = Path(__file__).resolve().parent.parent
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.count(",") == 2


def test_the_progress_bar_leaves_a_pool_free_to_fork(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a terminal the fleet's progress bar is drawn as logs finish, by no thread of its
    own: a thread would make every pool start from a forkserver (≈ 0.85 s)."""
    import io

    import twincd_cli.common as common
    from rich.console import Console

    monkeypatch.setattr(common, "show_progress", lambda quiet: True)
    screen = io.StringIO()
    monkeypatch.setattr(common, "stderr", Console(file=screen, force_terminal=True, width=80))
    threads = threading.active_count()
    with common.counter(3, "detect", quiet=False) as advance:
        assert threading.active_count() == threads
        advance(2, 500)
    assert "2/3" in screen.getvalue()
