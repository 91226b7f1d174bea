"""twincd/threshold.py: the threshold of a false-alarm budget (runs counted at every threshold of a
grid in one pass, merged by addition) and its CLI."""

from __future__ import annotations

import itertools
import json
import logging
from pathlib import Path

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from hypothesis import given, settings
from hypothesis import strategies as st

from twincd.calibration import Calibration
from twincd.detection.events import runs
from twincd.errors import UsageError
from twincd.threshold import (
    ALARM_GRID,
    AlarmCounter,
    AlarmCounts,
    ScoreStats,
    budget_threshold,
    check_threshold_settings,
)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 400),
    cuts=st.lists(st.integers(1, 399), max_size=5),
)
def test_runs_at_every_threshold_in_any_chunking(seed: int, n: int, cuts: list[int]) -> None:
    rng = np.random.default_rng(seed)
    scores = np.exp(rng.normal(0.0, 2.0, n))  # heavy-tailed, as scores are
    usable = rng.uniform(size=n) > 0.1  # left-out samples end runs
    counter = AlarmCounter(period_s=0.01)
    bounds = [0, *sorted({c for c in cuts if c < n}), n]
    for a, b in itertools.pairwise(bounds):
        counter.push(scores[a:b], usable[a:b])
    got = counter.counts
    assert got.seconds == pytest.approx(0.01 * usable.sum())
    for g in range(0, len(ALARM_GRID), 37):
        want = len(runs((scores >= ALARM_GRID[g]) & usable))
        assert got.runs[g] == want, (g, ALARM_GRID[g])


def _counts(scores: np.ndarray, period_s: float) -> tuple[AlarmCounts, ScoreStats]:
    counter = AlarmCounter(period_s)
    counter.push(scores, np.ones(len(scores), dtype=bool))
    return counter.counts, ScoreStats.from_scores(scores)


def test_the_budget_picks_the_lowest_threshold_that_keeps_it() -> None:
    # two hours at 10 Hz of scores near 1, with five lone spikes of 10, 20, 30, 40, 50
    scores = np.ones(72_000)
    scores[np.arange(5) * 10_000 + 5_000] = [10.0, 20.0, 30.0, 40.0, 50.0]
    counts, stats = _counts(scores, 0.1)
    for per_hour, above in ((0.0, 50.0), (0.5, 40.0), (1.0, 30.0), (2.0, 10.0)):
        th = budget_threshold(counts, stats, per_hour)
        assert above < th.value <= above * 1.04  # the next grid value (3.7 % apart)
        assert th.false_alarms == int((scores >= th.value).sum())
        assert th.false_alarms <= per_hour * 2
        assert th.value == pytest.approx(stats.mu + th.k_sigma * stats.sigma)
    # a budget every score keeps: never below μ, and the alarms counted are those at the value
    lavish = budget_threshold(counts, stats, 1e6)
    assert stats.mu <= lavish.value <= stats.mu * 1.04 and lavish.k_sigma >= 0
    assert lavish.false_alarms == len(runs(scores >= lavish.value))


@pytest.mark.parametrize("per_hour", [0.0, 1.0])
def test_a_budget_on_too_little_data_says_so(
    caplog: pytest.LogCaptureFixture, per_hour: float
) -> None:
    counts, stats = _counts(np.linspace(1.0, 2.0, 6000), 0.01)  # one minute
    with caplog.at_level(logging.WARNING, logger="twincd"):
        th = budget_threshold(counts, stats, per_hour)
    assert "1 min of collision-free data" in caplog.text and "1 h or more" in caplog.text
    assert th.value > 2.0 and th.false_alarms == 0


@pytest.mark.parametrize("k, budget", [(float("inf"), None), (4.0, float("inf")), (4.0, -1.0)])
def test_settings_that_cannot_make_a_threshold_are_refused(k: float, budget: float | None) -> None:
    counts, stats = _counts(np.ones(100), 0.01)
    with pytest.raises(UsageError, match="finite number"):
        check_threshold_settings(k, budget)
    if budget is not None:
        with pytest.raises(UsageError):
            budget_threshold(counts, stats, budget)


def test_cli_threshold_for_a_budget(twin_calibration: Path, twin_dataset: Path, tmp_path) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "cal.json"
    result = run(
        "threshold", twin_dataset / "val", "-c", twin_calibration, "-o", out,
        "--false-alarms-per-hour", "1",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "false alarm(s) in" in result.stdout and "budget 1/h" in result.stdout
    th = json.loads(out.read_text())["threshold"]
    assert th["false_alarm_budget"]["per_hour"] == 1.0
    assert th["false_alarm_budget"]["false_alarms"] == 0  # 32 s of data: none allowed
    cal = Calibration.load(out)
    assert cal.threshold is not None and cal.threshold.budget_per_hour == 1.0
    assert Calibration.from_dict(cal.to_dict()).threshold == cal.threshold
    # the threshold then clears every clean score: detect finds nothing on the val logs
    for log in sorted((twin_dataset / "val").glob("*.mcap")):
        assert run("detect", log, "-c", out).exit_code == 0
    both = run(
        "threshold", twin_dataset / "val", "-c", twin_calibration, "-o", tmp_path / "x.json",
        "-k", "4", "--false-alarms-per-hour", "1",
    )  # fmt: skip
    assert_one_line_error(both, "--false-alarms-per-hour")
    for bad in (["--false-alarms-per-hour", "inf"], ["-k", "inf"]):
        result = run("threshold", twin_dataset / "val", "-c", twin_calibration, "-o", out, *bad)
        assert_one_line_error(result, "finite number")
