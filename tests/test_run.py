"""The library's run over many logs (``twincd.run_logs``): results in order, keep-going, the
exit code of the failures, warnings passed on, and outputs removed when a run fails."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

import twincd
from twincd.errors import InternalError, LogReadError
from twincd.executors.run import LogFailure, all_or_nothing, run_logs


def _work(path: Path) -> int:
    """Fails for a log named bad*, is a defect for one named defect*, warns for warn*."""
    if path.name.startswith("bad"):
        raise LogReadError("cannot read the log", str(path), "give another")
    if path.name.startswith("defect"):
        raise ValueError("a bug")
    if path.name.startswith("warn"):
        logging.getLogger("twincd").warning("odd log %s", path.name)
    return len(path.name)


def _write_then_fail(path: Path) -> int:
    if path.name.startswith("bad"):
        raise LogReadError("cannot read the log", str(path), "give another")
    path.with_suffix(".out").write_text("done")
    return 1


def _logs(tmp_path: Path, *names: str) -> list[Path]:
    paths = [tmp_path / name for name in names]
    for path in paths:
        path.write_bytes(b"")
    return paths


def test_results_come_in_the_order_given_on_any_executor(tmp_path: Path) -> None:
    paths = _logs(tmp_path, "a", "bbbb", "cc")
    serial = run_logs(_work, paths, jobs=1)
    pooled = run_logs(_work, paths, jobs=2)
    assert serial.results == pooled.results == [1, 4, 2]
    assert serial.failures == [] and serial.exit_code == 0


def test_the_first_failure_is_raised_without_keep_going(tmp_path: Path) -> None:
    paths = _logs(tmp_path, "a", "bad", "cc")
    with pytest.raises(LogReadError, match="cannot read the log"):
        run_logs(_work, paths, jobs=1)


@pytest.mark.parametrize("jobs", [1, 2])
def test_keep_going_skips_failing_logs_and_says_why(
    tmp_path: Path, jobs: int, caplog: pytest.LogCaptureFixture
) -> None:
    paths = _logs(tmp_path, "a", "bad", "warn", "cc")
    seen: list[LogFailure] = []
    done = run_logs(_work, paths, jobs=jobs, keep_going=True, on_failure=seen.append)
    assert done.results == [1, 4, 2]
    assert [f.path for f in done.failures] == [paths[1]] and seen == done.failures
    assert done.exit_code == 2
    assert "odd log warn" in caplog.text  # a worker's warning reaches this process


def test_a_skipped_log_is_a_warning_by_default(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    paths = _logs(tmp_path, "bad", "a")
    done = run_logs(_work, paths, jobs=1, keep_going=True)
    assert done.results == [1]
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "log skipped: cannot read the log" in warned[0].getMessage()


def test_a_defect_is_an_internal_error_naming_the_log(tmp_path: Path) -> None:
    paths = _logs(tmp_path, "bad", "defect", "a")
    done = run_logs(_work, paths, jobs=1, keep_going=True, on_failure=lambda f: None)
    error = done.failures[1].error
    assert isinstance(error, InternalError) and str(paths[1]) in error.message
    assert done.exit_code == 3  # a defect outranks a bad log


def test_a_failed_run_removes_the_outputs_it_wrote(tmp_path: Path) -> None:
    paths = _logs(tmp_path, "a", "bad")
    older = tmp_path / "bad.out"
    older.write_text("from an earlier run")
    os.utime(older, ns=(0, 0))
    outputs = [p.with_suffix(".out") for p in paths]
    with pytest.raises(LogReadError):
        run_logs(_write_then_fail, paths, jobs=1, outputs=outputs)
    assert not outputs[0].exists()  # written by this run: removed
    assert older.read_text() == "from an earlier run"  # older than the run: left alone


def test_all_or_nothing_keeps_what_a_run_that_worked_wrote(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    with all_or_nothing() as written:
        written.append(target)
        target.write_text("x")
    assert target.read_text() == "x"


def test_the_run_api_is_public() -> None:
    assert twincd.run_logs is run_logs


def test_a_run_as_a_mapper_gathers_each_failed_log_once(tmp_path: Path) -> None:
    """``Running.mapper``: what fit's cross-fitting and evaluate's per-log work are given — the
    results of the logs that worked in order, each failing log recorded once however often it
    is mapped over, the description after what the run is doing."""
    import contextlib
    from collections.abc import Iterator

    from twincd.executors.run import LogsFailed, Running

    shown: list[tuple[int, str]] = []

    @contextlib.contextmanager
    def display(logs: int, what: str) -> Iterator[object]:
        shown.append((logs, what))
        yield lambda _done, _samples: None

    paths = _logs(tmp_path, "a", "bad", "cc")
    failed: list[LogFailure] = []
    each = Running(jobs=1, keep_going=True, progress=display, on_failure=lambda f: None).mapper(
        failed, doing="reading "
    )
    assert each(_work, paths, "test logs") == [1, 2]
    assert each(_work, [paths[1], *paths[1:]], "val logs") == [2]  # bad twice, then cc
    assert [f.path for f in failed] == [paths[1]]  # once, not once per mapping or per item
    assert shown == [(3, "reading test logs"), (3, "reading val logs")]
    assert each(_work, [], "nothing") == [] and len(shown) == 2  # nothing to map: no display
    with pytest.raises(LogsFailed):  # a run of its own in which every log failed
        Running(jobs=1, keep_going=True, on_failure=lambda f: None).mapper([])(
            _work, paths[1:2], "bad only"
        )
