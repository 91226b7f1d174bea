"""twincd.executors.cluster and the executors end to end: -j 1, -j 2, ``--scheduler local`` and a
real ``dask scheduler`` with two ``dask worker`` processes (loopback only) give the same
calibration, threshold, events and metrics on shuffled log orders; a worker killed mid-run is
survived, or the run fails with one line and leaves no file behind."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.clitools import assert_one_line_error, run
from support.needs import need

from twincd.errors import ClusterError, LogReadError, TwincdError, UsageError
from twincd.executors.cluster import DaskExecutor
from twincd.executors.local import Bound

need("distributed")

TESTS = Path(__file__).parent
START_TIMEOUT_S = 60
TIMING_KEYS = ("train_s", "test_s", "train_s_std", "test_s_std")


def _square_or_fail(x: int, bad: int) -> int:
    if x == bad:
        raise LogReadError("log is damaged", f"log {x}", "record it again")
    return x * x


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for proc in procs:  # each in its own session: the group holds the nanny's worker too
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
    for proc in procs:
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=15)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """A ``dask scheduler`` and two one-thread ``dask worker`` processes on 127.0.0.1 (free
    ports), torn down at the end. The scheduler gives up on a log after one worker death
    beyond the first (allowed-failures 1); workers die on demand (tests/support/dask_preload.py)."""
    from distributed import Client

    root = tmp_path_factory.mktemp("cluster")
    kill_dir = root / "kill"
    kill_dir.mkdir()
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
        TWINCD_TEST_KILL_DIR=str(kill_dir),
        DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="1",
    )
    dask = [sys.executable, "-m", "dask"]
    scheduler_file = root / "scheduler.json"
    procs: list[subprocess.Popen[bytes]] = []
    log = (root / "cluster.log").open("wb")
    try:
        procs.append(
            subprocess.Popen(
                [
                    *dask,
                    "scheduler",
                    *("--host", "127.0.0.1", "--port", "0"),
                    *("--no-dashboard", "--dashboard-address", "127.0.0.1:0"),
                    *("--scheduler-file", str(scheduler_file)),
                ],
                env=env,
                stdout=log,
                stderr=log,
                start_new_session=True,
            )
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [
                        *(*dask, "worker", address, "--host", "127.0.0.1", "--nthreads", "1"),
                        *("--no-dashboard", "--dashboard-address", "127.0.0.1:0"),
                        *("--preload", "support.dask_preload"),
                    ],
                    env=env,
                    stdout=log,
                    stderr=log,
                    start_new_session=True,
                )
            )
        with Client(address, timeout=START_TIMEOUT_S) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
        yield {"address": address, "kill_dir": kill_dir}
    finally:
        _stop(procs[::-1])
        log.close()


# ------------------------------------------------------------------ the executor itself


def test_results_come_back_in_input_order_and_errors_as_themselves(cluster):
    items = list(range(11, -1, -1))
    with DaskExecutor(cluster["address"]) as executor:
        assert executor.map(Bound(_square_or_fail, -1), items) == [x * x for x in items]
        with pytest.raises(LogReadError, match="log 3"):
            executor.map(Bound(_square_or_fail, 3), items)
        # the executor is still usable after a failed run
        assert executor.map(Bound(_square_or_fail, -1), [2]) == [4]


def test_outcomes_give_every_log_its_result_or_error(cluster):
    with DaskExecutor(cluster["address"]) as executor:
        outcomes = list(executor.outcomes(Bound(_square_or_fail, 2), [0, 1, 2, 3]))
    by_index = {o.index: o for o in outcomes}
    assert sorted(by_index) == [0, 1, 2, 3]
    assert [by_index[i].result for i in (0, 1, 3)] == [0, 1, 9]
    assert isinstance(by_index[2].error, LogReadError)


def test_a_log_the_workers_cannot_see_is_named(cluster, tmp_path):
    missing = tmp_path / "elsewhere" / "run.mcap"
    with DaskExecutor(cluster["address"]) as executor, pytest.raises(LogReadError) as err:
        executor.map(Bound(_square_or_fail, -1), [missing])
    assert str(missing) in err.value.message and "every worker" in err.value.message


def test_an_unreachable_scheduler_is_one_clear_error():
    import socket

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    unreachable = DaskExecutor(f"tcp://127.0.0.1:{port}", connect_timeout=1)
    with pytest.raises(ClusterError, match="cannot reach the Dask scheduler") as err:
        unreachable.__enter__()
    assert err.value.option == "scheduler"


def test_without_dask_the_error_says_how_to_install_it(monkeypatch, twin_dataset):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import fails as if not installed
    with pytest.raises(UsageError, match=r"pip install 'twincd\[dask\]'"):
        DaskExecutor("local").__enter__()
    result = run("fit", twin_dataset / "train", "--scheduler", "local", "-o", "x.json")
    assert_one_line_error(result, match="twincd[dask]")
    assert "--scheduler" in result.stderr


def test_workers_of_a_running_cluster_are_not_set_by_jobs(cluster):
    with pytest.raises(TwincdError, match="workers are set where they are started"):
        DaskExecutor(cluster["address"], workers=2).__enter__()


# ------------------------------------------------------------------ every executor, one answer


def _pipeline(data: Path, out: Path, executor: list[str], seed: int) -> dict[str, Any]:
    """fit → threshold → detect (-o folder) → evaluate on one executor, logs shuffled."""
    rng = random.Random(seed)

    def shuffled(split: str) -> list[Path]:
        logs = sorted((data / split).glob("*.mcap"))
        rng.shuffle(logs)
        return logs

    out.mkdir()
    cal = out / "cal.json"
    steps = [
        ("fit", *shuffled("train"), "-o", cal),
        ("threshold", *shuffled("val"), "-c", cal),
        ("detect", *shuffled("test"), "-c", cal, "-o", out / "detected", "--json"),
    ]
    results = [run(*step, *executor) for step in steps]
    assert [r.exit_code for r in results] == [0, 0, 1], [r.stderr for r in results]
    train = [a for p in shuffled("train") for a in ("--train", p)]
    val = [a for p in shuffled("val") for a in ("--val", p)]
    evaluated = run("evaluate", *shuffled("test"), "-c", cal, *train, *val, "--json", *executor)
    assert evaluated.exit_code == 0, evaluated.stderr
    methods = json.loads(evaluated.stdout)["methods"]
    for method in methods:
        for key in TIMING_KEYS:
            method.pop(key, None)
    detected = json.loads(results[2].stdout)
    return {
        "calibration": json.loads(cal.read_text()),
        "events": {d["path"]: d for d in detected["logs"]},
        "methods": methods,
        "outputs": {p.name: p.read_bytes() for p in sorted((out / "detected").iterdir())},
    }


@pytest.fixture(scope="module")
def runs(cluster, twin_dataset, tmp_path_factory) -> dict[str, dict[str, Any]]:
    root = tmp_path_factory.mktemp("runs")
    executors = {
        "-j 1": ["-j", "1"],
        "-j 2": ["-j", "2"],
        "local cluster": ["--scheduler", "local", "-j", "2"],
        "running cluster": ["--scheduler", cluster["address"]],
    }
    return {
        name: _pipeline(twin_dataset, root / f"run{i}", args, seed=i)
        for i, (name, args) in enumerate(executors.items())
    }


@pytest.mark.parametrize("name", ["-j 2", "local cluster", "running cluster"])
def test_every_executor_and_log_order_gives_the_same_results(runs, name):
    serial, other = runs["-j 1"], runs[name]
    want_joints, got_joints = (
        serial["calibration"]["model"]["joints"],
        other["calibration"]["model"]["joints"],
    )
    assert list(got_joints) == list(want_joints) == ["j1", "j2", "j3"]
    for key in ("a", "b"):
        got = np.array([j[key] for j in got_joints.values()])
        want = np.array([j[key] for j in want_joints.values()])
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    for key in ("mu", "sigma", "value"):
        got, want = other["calibration"]["threshold"][key], serial["calibration"]["threshold"][key]
        assert got == pytest.approx(want, rel=1e-12, abs=0)
    assert other["events"] == serial["events"]
    assert other["methods"] == serial["methods"]
    assert other["outputs"] == serial["outputs"]  # written on the workers, byte for byte


def test_fit_logs_given_in_any_order_are_recorded_in_one_order(runs):
    recorded = {name: r["calibration"]["fit"]["logs"] for name, r in runs.items()}
    assert len({tuple(logs) for logs in recorded.values()}) == 1


# ------------------------------------------------------------------ workers that die


def _arm(kill_dir: Path, times: int) -> None:
    for i in range(times):
        (kill_dir / f"arm-{time.monotonic_ns()}-{i}").touch()


def test_a_worker_killed_mid_write_is_survived(cluster, runs, twin_dataset, tmp_path):
    """One worker dies with a detect output half-written; Dask runs its log again on a
    worker alive, and the run ends with every output whole and nothing else in the folder."""
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(runs["-j 1"]["calibration"]))
    out = tmp_path / "detected"
    _arm(cluster["kill_dir"], 1)
    result = run(
        "detect", twin_dataset / "test", "-c", cal, "-o", out, "--scheduler", cluster["address"]
    )
    assert result.exit_code == 1, result.stderr
    assert not list(cluster["kill_dir"].glob("arm-*"))  # a worker did die
    files = {p.name: p.read_bytes() for p in sorted(out.iterdir())}  # hidden ones too
    assert files == runs["-j 1"]["outputs"]


def test_a_log_that_keeps_killing_workers_fails_in_one_line_leaving_nothing(
    cluster, runs, twin_dataset, tmp_path
):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(runs["-j 1"]["calibration"]))
    out = tmp_path / "detected"
    log = twin_dataset / "test" / "test_0.mcap"
    _arm(cluster["kill_dir"], 2)  # one death more than the scheduler allows
    result = run("detect", log, "-c", cal, "-o", out, "--scheduler", cluster["address"])
    assert_one_line_error(result, match="workers died while processing the log")
    assert str(log) in result.stderr
    assert list(out.iterdir()) == []


def test_simulate_on_a_running_cluster_writes_what_one_process_writes(cluster, tmp_path):
    logs = sorted((TESTS.parent / "sample_logs" / "test").glob("*.mcap"))[:2]
    outputs = {}
    for name, executor in (
        ("serial", ["-j", "1"]),
        ("cluster", ["--scheduler", cluster["address"]]),
    ):
        out = tmp_path / name
        out.mkdir()
        result = run("simulate", *logs[::-1], "-o", out, *executor)
        assert result.exit_code == 0, result.stderr
        outputs[name] = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    assert len(outputs["serial"]) == 2 and outputs["cluster"] == outputs["serial"]


def test_progress_shows_logs_done_and_samples_per_second(monkeypatch):
    import io

    from rich.console import Console
    from twincd_cli import common

    sink = io.StringIO()
    monkeypatch.setattr(common, "show_progress", lambda quiet: True)
    monkeypatch.setattr(common, "stderr", Console(file=sink, force_terminal=True, width=100))
    with common.counter(3, "fitting", quiet=False) as advance:
        advance(1, 3000)
        advance(2, 6000)
    shown = sink.getvalue()
    assert "3/3" in shown and "samples/s" in shown
