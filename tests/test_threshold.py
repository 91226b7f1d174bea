"""twincd/calibration/threshold.py and twincd/calibration/tail.py: the threshold of a false-alarm
budget from the score's excursions (declustered peaks, a generalised Pareto tail; the depth
statistic's bulk rate and an exponential tail), their merges, the calibration's record of them, the
false alarms `threshold` counts on its own logs, and the CLI."""

from __future__ import annotations

import itertools
import json
import logging
import random
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from support.clitools import assert_one_line_error, run

from twincd.calibration import Calibration, clean_mask
from twincd.calibration.clean import BandStats
from twincd.calibration.models import model_inputs
from twincd.calibration.tail import (
    DECLUSTER_GAP_S,
    LEVELS,
    MAX_PEAKS,
    MIN_PEAKS,
    ExcursionCounter,
    Excursions,
    fit_tail,
)
from twincd.calibration.threshold import (
    LogScores,
    ScoreStats,
    budget_threshold,
    check_threshold_settings,
    threshold_from_parts,
)
from twincd.detection.events import runs
from twincd.errors import CalibrationError, UsageError
from twincd.prepare.setup import Setup


def _excursions(scores: np.ndarray, usable: np.ndarray, period_s: float, cuts=()) -> Excursions:  # type: ignore[no-untyped-def]
    counter = ExcursionCounter(period_s)
    bounds = [0, *sorted({c for c in cuts if 0 < c < len(scores)}), len(scores)]
    for a, b in itertools.pairwise(bounds):
        counter.push(scores[a:b], usable[a:b])
    return counter.excursions


def _declustered_peaks(scores: np.ndarray, usable: np.ndarray, level: float, gap: int) -> list:  # type: ignore[type-arg]
    """The reference: a plain loop over samples (an excursion ends after `gap` samples below)."""
    peaks: list[float] = []
    last = -(10**9)
    for i, (s, ok) in enumerate(zip(scores, usable, strict=True)):
        if ok and s >= level:
            if i - last > gap:
                peaks.append(s)
            else:
                peaks[-1] = max(peaks[-1], s)
            last = i
    return sorted(peaks)


def _smooth_scores(rng: np.random.Generator, n: int) -> np.ndarray:
    """Heavy-tailed scores with some memory, as a filtered residual's are."""
    raw = np.exp(rng.normal(0.0, 1.0, n))
    return np.convolve(raw, np.ones(5) / 5)[:n]


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 600),
    cuts=st.lists(st.integers(1, 599), max_size=5),
)
def test_excursions_in_any_chunking_are_the_declustered_peaks(
    seed: int, n: int, cuts: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    scores, usable = _smooth_scores(rng, n), rng.uniform(size=n) > 0.05
    got = _excursions(scores, usable, 0.01, cuts)
    assert got == _excursions(scores, usable, 0.01)  # blocks never split or merge one
    gap = round(DECLUSTER_GAP_S / 0.01)
    for j in range(0, len(LEVELS), 7):
        want = _declustered_peaks(scores, usable, LEVELS[j], gap)
        assert got.counts[j] == len(want)
        assert got.peaks[j] == (tuple(want) if len(want) <= MAX_PEAKS else None)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), logs=st.integers(1, 5), order=st.randoms())
def test_any_order_and_split_of_the_logs_give_the_same_threshold(
    seed: int, logs: int, order: random.Random
) -> None:
    rng = np.random.default_rng(seed)
    parts = []
    for i in range(logs):
        scores = _smooth_scores(rng, int(rng.integers(500, 4000)))
        usable = np.ones(len(scores), dtype=bool)
        band = BandStats(ScoreStats.from_scores(scores), _excursions(scores, usable, 0.01))
        parts.append(LogScores(f"log{i}", (band,), len(scores)))
    cal = _calibration()
    first = threshold_from_parts(parts, cal, false_alarms_per_hour=1.0).require_threshold()
    shuffled = parts[:]
    order.shuffle(shuffled)
    assert (
        threshold_from_parts(shuffled, cal, false_alarms_per_hour=1.0).require_threshold() == first
    )
    # a worker that merged some logs' excursions first (any grouping) gives the same merge
    cut = order.randint(0, logs)
    grouped = sum((p.excursions for p in shuffled[:cut]), Excursions())  # type: ignore[misc]
    rest = sum((p.excursions for p in shuffled[cut:]), Excursions())  # type: ignore[misc]
    assert grouped + rest == sum((p.excursions for p in parts), Excursions())  # type: ignore[misc]
    assert first.tail is not None and first.value == pytest.approx(first.tail.estimate)


def _calibration() -> Calibration:
    from twincd.calibration.models import make_model
    from twincd.signal.filters import LowPass

    model = make_model("affine").with_coefficients({"a": np.ones(1), "b": np.zeros(1)})
    return Calibration(("j1",), model, LowPass(2, 1.0))


def _spikes(seed: int, shape: float, hours: float = 1.0) -> tuple[np.ndarray, float]:
    """Scores at 100 Hz of lone spikes (one every 2 s, over a floor of 1) whose heights above
    10 follow a known GPD (shape, scale 1); the true threshold of 1 spike per hour over x."""
    rng = np.random.default_rng(seed)
    n = round(hours * 360_000)
    scores = np.ones(n)
    heights = 10.0 + stats.genpareto.rvs(shape, scale=1.0, size=n // 200, random_state=rng)
    scores[100::200] = heights[: len(scores[100::200])]
    rate = len(scores[100::200]) / hours
    return scores, float(stats.genpareto.isf(1.0 / rate, shape, scale=1.0) + 10.0)


@pytest.mark.parametrize("shape", [0.0, 0.2])
def test_the_tail_fit_recovers_a_known_gpd_quantile_within_its_interval(shape: float) -> None:
    inside = 0
    for seed in range(5):
        scores, truth = _spikes(seed, shape)
        excursions = _excursions(scores, np.ones(len(scores), dtype=bool), 0.01)
        tail = fit_tail(excursions, 1.0)
        assert tail is not None and tail.method == "pot-gpd" and tail.peaks >= 50
        assert tail.low <= tail.estimate and (tail.high is None or tail.estimate <= tail.high)
        inside += tail.low <= truth <= (np.inf if tail.high is None else tail.high)
    assert inside >= 4  # a 90 % interval: the truth in at least 4 of 5 draws


def test_the_budget_threshold_is_mu_plus_k_sigma_and_records_its_tail(
    caplog: pytest.LogCaptureFixture,
) -> None:
    scores, _ = _spikes(0, 0.1)
    usable = np.ones(len(scores), dtype=bool)
    stats_ = ScoreStats.from_scores(scores)
    with caplog.at_level(logging.WARNING, logger="twincd"):
        th = budget_threshold(_excursions(scores, usable, 0.01), stats_, 2.0)
    assert not caplog.text  # an hour of data: no warning
    assert th.tail is not None and th.budget_per_hour == 2.0
    assert th.value == pytest.approx(th.tail.estimate) and th.k_sigma > 0
    assert th.value == pytest.approx(stats_.mu + th.k_sigma * stats_.sigma)
    # the clean time judged; the false alarms are counted later, as detect's events
    assert th.judged_s == pytest.approx(3600.0) and th.false_alarms is None
    # a larger budget, a lower threshold
    lower = budget_threshold(_excursions(scores, usable, 0.01), stats_, 20.0)
    assert lower.value < th.value


def test_too_few_peaks_take_an_exponential_tail_and_say_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    scores, _ = _spikes(1, 0.1, hours=8 / 1800)  # eight spikes
    usable = np.ones(len(scores), dtype=bool)
    with caplog.at_level(logging.WARNING, logger="twincd"):
        th = budget_threshold(
            _excursions(scores, usable, 0.01), ScoreStats.from_scores(scores), 1.0
        )
    assert len(caplog.records) == 1 and "exponential tail" in caplog.text
    assert th.tail is not None and th.tail.method == "pot-exponential" and th.tail.shape == 0.0
    assert th.tail.peaks < MIN_PEAKS and th.tail.low < th.value < (th.tail.high or np.inf)
    assert th.value > scores.max()  # 8 spikes in 16 s: a threshold for 1/h is above them all


def test_a_score_without_a_tail_takes_mu_plus_4_sigma_and_says_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    scores = np.ones(100_000)
    scores[::100] = 5.0  # a thousand equal spikes: every level between is one excursion each
    usable = np.ones(len(scores), dtype=bool)
    stats_ = ScoreStats.from_scores(scores)
    with caplog.at_level(logging.WARNING, logger="twincd"):
        th = budget_threshold(_excursions(scores, usable, 0.01), stats_, 1.0)
    assert len(caplog.records) == 1 and "μ + 4σ instead" in caplog.text
    assert th.tail is None and th.k_sigma == 4.0 and th.budget_per_hour is None


@pytest.mark.parametrize(
    "k, budget", [(float("inf"), None), (4.0, float("inf")), (4.0, -1.0), (4.0, 0.0)]
)
def test_settings_that_cannot_make_a_threshold_are_refused(k: float, budget: float | None) -> None:
    with pytest.raises(UsageError, match="finite number"):
        check_threshold_settings(k, budget)


def test_cli_threshold_default_k_and_budget(
    twin_calibration: Path, twin_dataset: Path, tmp_path
) -> None:  # type: ignore[no-untyped-def]
    val = twin_dataset / "val"
    out = tmp_path / "cal.json"
    result = run(
        "threshold", val, "-c", twin_calibration, "-o", out, "--false-alarms-per-hour", "1"
    )
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("threshold ")
    assert "budget 1 false alarm/h" in result.stdout and "90 % interval" in result.stdout
    th = json.loads(out.read_text())["threshold"]
    budget = th["false_alarm_budget"]
    assert budget["per_hour"] == 1.0 and budget["method"] == "pot-gpd"
    low, high = budget["interval"]
    assert low <= th["value"] <= high and th["value"] == pytest.approx(budget["estimate"])
    assert th["value"] == pytest.approx(th["mu"] + th["k_sigma"] * th["sigma"])
    cal = Calibration.load(out)
    assert Calibration.from_dict(cal.to_dict()).threshold == cal.threshold
    # the threshold clears every clean score: detect finds nothing on the val logs
    for log in sorted(val.glob("*.mcap")):
        assert run("detect", log, "-c", out).exit_code == 0
    # -k keeps the paper's μ + kσ (mean and standard deviation), and no budget; no option at
    # all is μ + 4σ too, with the median and MAD for a model scored by the depth statistic
    whitened = Calibration.load(twin_calibration).model.statistic == "depth"
    for k, estimator in ((["-k", "4"], "mean-sd"), ([], "median-mad" if whitened else "mean-sd")):
        k4 = run("threshold", val, "-c", twin_calibration, "-o", tmp_path / "k4.json", *k)
        assert k4.exit_code == 0 and k4.stdout.startswith("threshold ")
        assert "(μ + 4σ, " in k4.stdout
        th4 = json.loads((tmp_path / "k4.json").read_text())["threshold"]
        assert th4["k_sigma"] == 4.0 and "false_alarm_budget" not in th4
        assert th4["estimator"] == estimator
        if estimator == "mean-sd":
            assert th4["mu"] == th["mu"] and th4["sigma"] == th["sigma"]
        else:  # the median and MAD of the clean scores, to the histogram's step
            cal4 = Calibration.load(tmp_path / "k4.json")
            setup = Setup.from_calibration(cal4)
            clean = [
                cal4.model.scores(model_inputs(lg))[clean_mask(lg)]
                for lg in (setup.prepare(p) for p in sorted(val.glob("*.mcap")))
            ]
            scores = np.concatenate(clean)
            median = float(np.median(scores))
            mad = float(np.median(np.abs(scores - median)))
            assert th4["mu"] == pytest.approx(median, abs=0.011)
            assert th4["sigma"] == pytest.approx(1.4826 * mad, abs=0.02)
    # a larger budget, a lower threshold
    lavish = run(
        "threshold", val, "-c", twin_calibration, "-o", tmp_path / "b.json",
        "--false-alarms-per-hour", "100",
    )  # fmt: skip
    assert lavish.exit_code == 0 and "budget 100 false alarm/h" in lavish.stdout
    assert json.loads((tmp_path / "b.json").read_text())["threshold"]["value"] < th["value"]
    both = run(
        "threshold", val, "-c", twin_calibration, "-o", tmp_path / "x.json",
        "-k", "4", "--false-alarms-per-hour", "1",
    )  # fmt: skip
    assert_one_line_error(both, "--false-alarms-per-hour")
    for bad in (
        ["--false-alarms-per-hour", "inf"],
        ["--false-alarms-per-hour", "0"],
        ["-k", "inf"],
    ):
        result = run("threshold", val, "-c", twin_calibration, "-o", out, *bad)
        assert_one_line_error(result, "finite number")


def test_cli_threshold_warns_once_with_too_few_peaks(
    twin_calibration: Path, tmp_path: Path
) -> None:
    from conftest import build_twin_log

    short = build_twin_log(tmp_path / "short.mcap", seed=300, seconds=7.0)
    out = tmp_path / "cal.json"
    result = run(
        "threshold", short, "-c", twin_calibration, "-o", out, "--false-alarms-per-hour", "1"
    )
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "exponential tail" in warnings[0], result.stderr
    assert result.stdout.startswith("threshold ")
    budget = json.loads(out.read_text())["threshold"]["false_alarm_budget"]
    assert budget["method"] == "pot-exponential"


@pytest.mark.parametrize(
    "key, value",
    [
        ("shape", float("nan")),
        ("scale", float("inf")),
        ("level_u", "12"),
        ("rate_per_hour", -1.0),
        ("peaks", 12.5),
        ("interval", [1.0]),
        ("interval", ["a", None]),
        ("estimate", 1e9),
        ("method", "magic"),
    ],
)
def test_a_tail_that_is_not_numbers_is_refused_on_load(  # type: ignore[no-untyped-def]
    twin_calibration: Path, twin_dataset: Path, tmp_path, key: str, value: object
) -> None:
    budget = tmp_path / "budget.json"
    val = twin_dataset / "val"
    assert run("threshold", val, "-c", twin_calibration, "-o", budget, "-q",
               "--false-alarms-per-hour", "1").exit_code == 0  # fmt: skip
    data = json.loads(budget.read_text())
    assert data["threshold"]["false_alarm_budget"]["method"] == "pot-gpd"
    data["threshold"]["false_alarm_budget"][key] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))  # NaN and inf as JSON's NaN and Infinity
    with pytest.raises(CalibrationError, match="false_alarm_budget"):
        Calibration.load(bad)
    result = run("detect", sorted((twin_dataset / "test").glob("*.mcap"))[0], "-c", bad)
    assert_one_line_error(result, "false_alarm_budget")


def test_older_thresholds_keep_loading(twin_calibration: Path, tmp_path: Path) -> None:
    data = json.loads(twin_calibration.read_text())
    data["threshold"]["false_alarm_budget"] = {"per_hour": 1.0, "false_alarms": 0, "hours": 0.5}
    older = tmp_path / "older.json"
    older.write_text(json.dumps(data))
    th = Calibration.load(older).require_threshold()
    assert th.tail is None and th.budget_per_hour == 1.0 and th.judged_s == 1800.0
    del data["threshold"]["false_alarm_budget"]
    older.write_text(json.dumps(data))
    assert Calibration.load(older).require_threshold().budget_per_hour is None


def _laplace_process(rng: np.random.Generator, hours: float) -> np.ndarray:
    """A smooth score at 100 Hz whose excursions above its bulk fall exponentially (what the
    depth statistic's do on fresh clean logs): the exponential of a smooth Gaussian's square
    root, shifted and scaled."""
    from scipy import signal

    sos = signal.butter(2, 1.0, fs=100.0, output="sos")
    x = signal.sosfilt(sos, rng.standard_normal(int(hours * 360_000)))
    x = np.abs(x / x.std())
    return 1.0 + 1.0 * x**1.5  # heavier than a Gaussian: exp(−c·z^(4/3)) tails


def _rate_above(scores: np.ndarray, level: float, hours: float) -> float:
    above = runs(scores >= level)
    # declustered as the budget counts: a run within 0.2 s of the previous one continues it
    starts = [a for i, (a, _) in enumerate(above) if i == 0 or a - above[i - 1][1] > 20]
    return len(starts) / hours


def test_the_depth_budget_assumes_an_exponential_tail_above_the_bulk() -> None:
    from twincd.calibration.tail import (
        BULK_LEVEL_SIGMA,
        BULK_TAIL_SCALE,
        LEVELS,
        MISFIT_STUDIED,
        fit_bulk_tail,
    )

    rng = np.random.default_rng(3)
    short = _laplace_process(rng, 2 / 60)  # two minutes
    counter = ExcursionCounter(0.01)
    counter.push(short, np.ones(len(short), bool))
    median = float(np.median(short))
    sigma = 1.4826 * float(np.median(np.abs(short - median)))
    noise_median = median - 0.5  # a residual half a unit of score above its noise
    tail = fit_bulk_tail(counter.excursions, 1.0, median, sigma, noise_median)
    assert tail is not None and tail.method == "bulk-exponential"
    # u the grid level at or below μ + 2σ, λ(u) its excursions per hour, β = (s₀ + s₁(μ − μ₀))σ
    j = int(np.searchsorted(LEVELS, median + BULK_LEVEL_SIGMA * sigma, side="right")) - 1
    assert tail.level == LEVELS[j] and tail.peaks == counter.excursions.counts[j] > 0
    assert tail.rate_per_hour == pytest.approx(tail.peaks / (2 / 60))
    noise, misfit = BULK_TAIL_SCALE
    assert tail.scale == pytest.approx((noise + misfit * 0.5) * sigma)
    # a score at its noise-only median (or below) takes the noise part alone
    at_noise = fit_bulk_tail(counter.excursions, 1.0, median, sigma, median + 1.0)
    assert at_noise is not None and at_noise.scale == pytest.approx(noise * sigma)
    # far above it: held at the most the study saw
    far = fit_bulk_tail(counter.excursions, 1.0, median, sigma, median - 50.0)
    assert far is not None
    assert far.scale == pytest.approx((noise + misfit * MISFIT_STUDIED) * sigma)
    want = tail.level + tail.scale * np.log(tail.rate_per_hour / 1.0)
    assert tail.estimate == pytest.approx(want)
    assert tail.low <= tail.estimate <= (tail.high or np.inf)
    # two minutes cannot measure the tail: how much clean data would is said
    assert tail.firm_after_minutes is not None and tail.firm_after_minutes > 2.0
    # a budget twice as large: one scale lower by ln 2
    half = fit_bulk_tail(counter.excursions, 2.0, median, sigma, noise_median)
    assert half is not None
    assert tail.estimate - half.estimate == pytest.approx(tail.scale * np.log(2.0))


def test_the_depth_statistics_noise_only_median() -> None:
    from twincd.calibration.models import depth_noise_median, depth_score

    rng = np.random.default_rng(11)
    for joints in (3, 6, 7):
        scores = depth_score(rng.standard_normal((200_000, joints)))
        assert depth_noise_median(joints) == pytest.approx(np.median(scores), abs=0.01)
    assert depth_noise_median(7) == depth_noise_median(7)  # the same in every run


def test_the_depth_budget_without_excursions_is_bounded_and_cautious() -> None:
    from twincd.calibration.tail import fit_bulk_tail

    flat = 0.9 + 0.1 * (np.arange(6000) % 3)  # a spread, and nothing above μ + 2σ
    counter = ExcursionCounter(0.01)
    counter.push(flat, np.ones(len(flat), bool))
    median, sigma = ScoreStats.from_scores(flat).robust()
    assert sigma > 0
    tail = fit_bulk_tail(counter.excursions, 1.0, median, sigma, 0.69)
    assert tail is not None and tail.peaks == 0
    # the rate at the upper end of the Poisson interval of zero counts: finite, above the bulk
    assert np.isfinite(tail.estimate) and tail.estimate > median + 2 * sigma
    assert tail.high == pytest.approx(tail.estimate)


def test_the_depth_budget_measures_the_tail_once_the_data_allow() -> None:
    from twincd.calibration.tail import TARGET_PEAKS, fit_bulk_tail

    rng = np.random.default_rng(5)
    long = _laplace_process(rng, 3.0)
    counter = ExcursionCounter(0.01)
    counter.push(long, np.ones(len(long), bool))
    median = float(np.median(long))
    sigma = 1.4826 * float(np.median(np.abs(long - median)))
    tail = fit_bulk_tail(counter.excursions, 1.0, median, sigma, 0.69)
    assert tail is not None and tail.method == "pot-gpd" and tail.peaks >= TARGET_PEAKS
    assert tail.level >= median + 3 * sigma and tail.firm_after_minutes is None
    # and it keeps the budget on ten fresh hours of the same process (10 expected)
    fresh = _laplace_process(rng, 10.0)
    assert 2 <= _rate_above(fresh, tail.estimate, 10.0) * 10 <= 25


def test_threshold_counts_its_own_false_alarms_as_detect_events(
    twin_calibration: Path, twin_dataset: Path, tmp_path: Path
) -> None:
    # a lavish budget puts the threshold low enough for the validation logs to raise events:
    # the count recorded is detect's events on those logs (one definition of a false alarm),
    # and a count above what the budget allows for their length is warned about, once
    val = twin_dataset / "val"
    out = tmp_path / "cal.json"
    result = run(
        "threshold", val, "-c", twin_calibration, "-o", out, "--false-alarms-per-hour", "3000"
    )
    assert result.exit_code == 0, result.output
    th = json.loads(out.read_text())["threshold"]
    budget = th["false_alarm_budget"]
    detected = json.loads(run("detect", val, "-c", out, "--json", "-q").stdout)
    events = sum(len(lg["events"]) for lg in detected["logs"])
    assert events > 0 and budget["false_alarms"] == events
    hours = budget["hours"]
    allowed = int(stats.poisson.ppf(0.95, 3000 * hours))
    warned = [line for line in result.stderr.splitlines() if "false alarm(s) on its own" in line]
    assert len(warned) == (1 if events > allowed else 0), result.stderr
    # at a budget of 1/h: no event on its own logs, and nothing to warn about
    quiet = run(
        "threshold", val, "-c", twin_calibration, "-o", tmp_path / "d.json",
        "--false-alarms-per-hour", "1",
    )  # fmt: skip
    assert quiet.exit_code == 0 and "false alarm(s) on its own" not in quiet.stderr
    assert json.loads((tmp_path / "d.json").read_text())["threshold"]["false_alarm_budget"][
        "false_alarms"
    ] == sum(
        len(lg["events"])
        for lg in json.loads(run("detect", val, "-c", tmp_path / "d.json", "--json").stdout)["logs"]
    )
