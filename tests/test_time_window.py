"""``--start`` / ``--end``: the stretch of each log a run judges. Samples before the window
warm the filters (and, zero-phase, those after it finish the backward pass), so a sample in
the window scores as in the whole log; only the window is judged; the window is the run's,
never recorded in a calibration; the library takes it as the CLI does."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from support.clitools import assert_one_line_error, run

import twincd

SAMPLES = Path(__file__).resolve().parent.parent / "sample_logs"
CALIBRATION = SAMPLES / "calibration.json"
TEST = SAMPLES / "test" / "test_000.mcap"
NS = 1_000_000_000


def scores(path: Path) -> dict[int, float]:
    with path.open() as f:
        return {int(row["stamp_ns"]): float(row["score"]) for row in csv.DictReader(f)}


def detect_json(*args: Any) -> dict[str, Any]:
    result = run("detect", TEST, "-c", CALIBRATION, "--json", *args)
    assert result.exit_code in (0, 1), result.output
    log: dict[str, Any] = json.loads(result.stdout)["logs"][0]
    return log


def test_a_window_scores_its_samples_as_the_whole_log_does(tmp_path: Path) -> None:
    whole, part = tmp_path / "whole.csv", tmp_path / "part.csv"
    assert run("detect", TEST, "-c", CALIBRATION, "-o", whole).exit_code == 1
    result = run("detect", TEST, "-c", CALIBRATION, "-o", part, "--start", "5", "--end", "12")
    assert result.exit_code == 1, result.output
    all_scores, window = scores(whole), scores(part)
    first = min(all_scores)
    inside = {t: s for t, s in all_scores.items() if 5 * NS <= t - first <= 12 * NS}
    assert set(window) == set(inside) and len(window) == 701
    assert max(abs(window[t] - inside[t]) for t in window) < 1e-9


def first_stamp() -> int:
    from twincd.prepare.setup import read_log

    return int(read_log(TEST).stamp_ns[0])


def test_only_the_window_is_judged() -> None:
    whole = detect_json()
    part = detect_json("--start", "5", "--end", "12")
    assert part["samples"] == 701 and whole["samples"] == 2849
    starts = [e["start_ns"] for e in part["events"]]
    first = first_stamp()
    assert len(starts) == 2  # the presses at ≈ 6.8 s and ≈ 9.4 s; not those at 1.7 s or 14.9 s
    assert all(5 * NS <= s - first <= 12 * NS for s in starts)
    kept = [e for e in whole["events"] if e["start_ns"] in starts]
    assert [e["peak_score"] for e in kept] == [e["peak_score"] for e in part["events"]]


def test_an_absolute_bound_is_a_header_stamp_time() -> None:
    assert detect_json("--end", "1")["samples"] == 101
    at = first_stamp() + 5 * NS  # written to the nanosecond: more digits than a float holds
    absolute = detect_json("--start", f"@{at // NS}.{at % NS:09d}", "--end", "12")
    relative = detect_json("--start", "5", "--end", "12")
    assert absolute == relative


def test_a_window_is_never_recorded_in_a_calibration(tmp_path: Path) -> None:
    cal = tmp_path / "cal.json"
    logs = sorted((SAMPLES / "train").glob("*.mcap"))[:3]
    result = run("fit", *logs, "-o", cal, "--start", "2", "--end", "20")
    assert result.exit_code == 0, result.output
    text = cal.read_text()
    assert '"start"' not in text and '"end"' not in text and "window" not in text
    whole = tmp_path / "whole.json"
    assert run("fit", *logs, "-o", whole).exit_code == 0
    assert json.loads(text)["fit"]["samples"] < json.loads(whole.read_text())["fit"]["samples"]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--start", "soon"], "is not a time in seconds"),
        (["--start", "-3"], "is not a time in seconds"),
        (["--start", "12", "--end", "5"], "the window ends (5 s) before it starts (12 s)"),
        (["--start", "500"], "no sample of the log lies in the window [500 s, the end]"),
    ],
)
def test_a_window_that_cannot_be_is_one_line(args: list[str], match: str) -> None:
    assert_one_line_error(run("detect", TEST, "-c", CALIBRATION, *args), match)


def test_the_library_takes_the_window_as_the_cli_does() -> None:
    summary = twincd.detect_file(TEST, CALIBRATION, start=5, end="12", step_summary=False)
    assert summary.to_dict() | {"path": None} == detect_json("--start", "5", "--end", "12") | {
        "path": None
    }


def test_evaluate_judges_the_window() -> None:
    result = run("evaluate", TEST, "-c", CALIBRATION, "--json", "--start", "5", "--end", "12")
    assert result.exit_code == 0, result.output
    method = json.loads(result.stdout)["methods"][0]
    assert method["events_total"] == 2 and method["units"] == 701
