"""twincd.signal.derivatives and .stream: the real-time Savitzky–Golay derivative, streamed."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.streaming import T0_NS, chunked, jittered_stamps, random_walk, split_points

from twincd.errors import DataError, UsageError
from twincd.signal import (
    Segmenter,
    StreamingDerivative,
    differentiate,
    nominal_period,
    segment_bounds,
)

PERIOD_NS = 1_000_000
PERIOD_S = PERIOD_NS * 1e-9


def make_signal(
    rng: np.random.Generator, n: int, channels: int, gaps: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` stamps ±15 % around 1 ms with ``gaps``, and a random walk plus steps on them: a
    signal with all kinds of features; channels 0 → (n,)."""
    stamps = jittered_stamps(rng, n, PERIOD_NS, gaps)
    return stamps, random_walk(rng, n, channels, step=20, step_rate=0.01)


def reference_derivative(
    stamps: np.ndarray, y: np.ndarray, causal: bool, window: int = 9, order: int = 3
) -> np.ndarray:
    """Sample-by-sample lstsq with the documented window placement, segment by segment."""
    t = (stamps - stamps[0]).astype(np.float64) * 1e-9
    out = np.zeros_like(y)
    cuts = [0, *(np.flatnonzero(np.diff(stamps) > 5 * PERIOD_NS) + 1).tolist(), len(t)]
    for a, b in itertools.pairwise(cuts):
        n = b - a
        for i in range(n):
            if causal:
                w = min(window, i + 1)
                lo = i - w + 1
            else:
                w = min(window, n)
                lo = int(np.clip(i - window // 2, 0, n - w))
            if w < 2:
                continue
            k = min(order, max(1, (w - 1) // 2))  # a short window fits twice the points it needs
            d = (t[a + lo : a + lo + w] - t[a + i]) / PERIOD_S
            coef = np.linalg.lstsq(np.vander(d, k + 1, increasing=True), y[a + lo : a + lo + w])
            out[a + i] = coef[0][1] / PERIOD_S
    return out


# ----------------------------------------------------------------------- period and segments


def test_nominal_period_is_the_median_of_the_first_positive_intervals():
    rng = np.random.default_rng(0)
    stamps = jittered_stamps(rng, 800, PERIOD_NS, gaps=5)
    stamps = np.insert(stamps, 10, stamps[10])  # a duplicate is not an interval
    assert nominal_period(stamps) == pytest.approx(PERIOD_S, rel=0.03)
    # only the first 1000 positive intervals count: a rate change later does not move it
    later = stamps[-1] + np.cumsum(np.full(5000, 4 * PERIOD_NS))
    both = np.concatenate((stamps, later))
    dt = np.diff(both)
    assert nominal_period(both) == np.median(dt[dt > 0][:1000]) * 1e-9
    assert nominal_period(both) < 1.1 * PERIOD_S < nominal_period(both[700:])
    # duplicates at the head do not hide the positive intervals behind them
    head = np.concatenate((np.full(3000, T0_NS), T0_NS + PERIOD_NS * np.arange(1, 50)))
    assert nominal_period(head) == PERIOD_S


@pytest.mark.parametrize("stamps", [[T0_NS], [T0_NS, T0_NS], []])
def test_nominal_period_needs_two_distinct_stamps(stamps):
    with pytest.raises(DataError, match="sampling period"):
        nominal_period(np.array(stamps, dtype=np.int64), "one.mcap")


def test_a_gap_is_an_interval_longer_than_gap_factor_periods():
    seg = Segmenter(PERIOD_S, gap_factor=5.0)
    stamps = T0_NS + np.cumsum([0, 1, 5, 1, 6, 1]) * PERIOD_NS  # 5 periods: no gap; 6: gap
    np.testing.assert_array_equal(seg.starts(stamps), [0, 4])
    # the next chunk continues the stream: no new segment unless its first interval is a gap
    assert seg.starts(stamps[-1:] + PERIOD_NS).tolist() == []
    assert seg.starts(stamps[-1:] + 20 * PERIOD_NS).tolist() == [0]
    seg.reset()
    assert seg.starts(stamps[:1]).tolist() == [0]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 300), gaps=st.integers(0, 6))
def test_segment_cuts_do_not_depend_on_chunking(seed, n, gaps):
    rng = np.random.default_rng(seed)
    stamps = jittered_stamps(rng, n, PERIOD_NS, gaps)
    whole = Segmenter(PERIOD_S).starts(stamps).tolist()
    seg = Segmenter(PERIOD_S)
    cuts = split_points(n, "random", rng)
    edges = [0, *cuts, n]
    pieces = [(a + seg.starts(stamps[a:b])).tolist() for a, b in itertools.pairwise(edges)]
    assert [c for piece in pieces for c in piece] == whole
    # segment_bounds (seconds, whole log) follows the same rule
    t_s = (stamps - stamps[0]) * 1e-9
    bounds = segment_bounds(t_s, period_s=PERIOD_S)
    assert [a for a, _ in bounds] == whole and bounds[-1][1] == n


# ----------------------------------------------------------------------- chunked = whole


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 250),
    gaps=st.integers(0, 5),
    channels=st.sampled_from([0, 1, 3]),  # 0: a 1-D signal
    causal=st.booleans(),
    how=st.sampled_from([1, 7, 1000, "whole", "random"]),
)
def test_chunked_equals_one_push(seed, n, gaps, channels, causal, how):
    rng = np.random.default_rng(seed)
    stamps, y = make_signal(rng, n, channels, gaps)
    whole = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [])
    got = chunked(
        StreamingDerivative(period_s=PERIOD_S, causal=causal),
        stamps,
        y,
        split_points(n, how, rng),
    )
    assert got.shape == y.shape
    span = float(np.ptp(whole)) if n else 0.0
    assert np.abs(got - whole).max(initial=0.0) <= 1e-9 * span
    # and the whole run is the documented least-squares fit, window by window
    ref = reference_derivative(stamps, y if channels else y[:, None], causal)
    ref = ref if channels else ref[:, 0]
    assert np.abs(whole - ref).max(initial=0.0) <= 1e-8 * max(span, 1.0)


def test_chunked_runs_are_bit_identical():
    # elementwise arithmetic only: a sample's output depends on its window alone
    rng = np.random.default_rng(1)
    stamps, y = make_signal(rng, 5000, 7, gaps=4)
    for causal in (False, True):
        whole = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [])
        for how in (1, 7, 1000, "random"):
            stage = StreamingDerivative(period_s=PERIOD_S, causal=causal)
            cuts = split_points(5000 if how != 1 else 600, how, rng)
            np.testing.assert_array_equal(chunked(stage, stamps, y, cuts), whole)


def test_results_do_not_depend_on_the_epoch():
    rng = np.random.default_rng(2)
    stamps, y = make_signal(rng, 400, 2, gaps=2)
    for causal in (False, True):
        a = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [])
        b = chunked(
            StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps - T0_NS + 12345, y, []
        )
        np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------- behaviour


@pytest.mark.parametrize("causal", [False, True])
def test_exact_for_cubics_on_irregular_times(causal):
    rng = np.random.default_rng(6)
    stamps = jittered_stamps(rng, 3000, PERIOD_NS, gaps=3)
    t = (stamps - stamps[0]) * 1e-9
    y = np.column_stack([1 + 2 * t - 3 * t**2 + 0.5 * t**3, -4 * t**3 + t])
    dy = np.column_stack([2 - 6 * t + 1.5 * t**2, -12 * t**2 + 1])
    got = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [1234])
    exact = np.ones(len(t), dtype=bool)
    if causal:  # a segment's first 6 samples fit a lower degree (twice the points it needs)
        starts = Segmenter(PERIOD_S).starts(stamps)
        for s in starts:
            exact[s : s + 6] = False
    err = np.abs(got - dy)[exact].max()
    assert err < 1e-9 * np.abs(dy).max()
    assert exact.sum() > len(t) - 25


@pytest.mark.parametrize("causal", [False, True])
def test_a_step_across_a_gap_does_not_leak(causal):
    stamps = T0_NS + PERIOD_NS * np.concatenate((np.arange(50), np.arange(60, 110)))
    y = np.where(np.arange(100) < 50, 3.0, -7.0)
    got = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [48, 52])
    assert np.abs(got).max() < 1e-9  # each side is constant: zero slope everywhere
    # and a linear ramp with a jump across the gap has its own slope on each side
    ramp = np.where(np.arange(100) < 50, 2.0, -5.0) * (stamps - T0_NS) * 1e-9 + 100 * (y < 0)
    got = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, ramp, [])
    expect = np.where(np.arange(100) < 50, 2.0, -5.0)
    first = [0, 50]
    mask = np.ones(100, dtype=bool)
    if causal:
        mask[first] = False  # one sample alone has no slope
    np.testing.assert_allclose(got[mask], expect[mask], atol=1e-8)


def test_lookahead_centred_four_samples_causal_none():
    rng = np.random.default_rng(3)
    stamps, y = make_signal(rng, 40, 1)
    centred = StreamingDerivative(period_s=PERIOD_S)
    causal = StreamingDerivative(period_s=PERIOD_S, causal=True)
    assert (centred.lookahead, causal.lookahead) == (4, 0)
    for k in range(40):
        assert len(causal.push(stamps[k : k + 1], y[k : k + 1])) == 1
        centred.push(stamps[k : k + 1], y[k : k + 1])
        # the first window (9 samples) must be complete, then 4 samples of lookahead
        assert centred.emitted == (k + 1 - 4 if k + 1 >= 9 else 0)
        assert centred.buffered <= centred.window and causal.buffered < causal.window
    assert len(centred.finish()) == 4 and len(causal.finish()) == 0


def test_buffers_stay_bounded_on_long_streams():
    rng = np.random.default_rng(4)
    stamps, y = make_signal(rng, 200_000, 3, gaps=20)
    for causal in (False, True):
        stage = StreamingDerivative(period_s=PERIOD_S, causal=causal)
        held = []
        for a in range(0, 200_000, 9973):
            stage.push(stamps[a : a + 9973], y[a : a + 9973])
            held.append(stage.buffered)
            assert stage.pending <= stage.window
        assert max(held) <= stage.window
        stage.finish()
        assert stage.buffered == 0 and stage.pending == 0


def test_short_segments_and_a_lone_sample():
    # segments of 1, 2, 3 and 12 samples: the fit shrinks with the segment, a lone sample is 0
    lengths = [1, 2, 3, 12]
    stamps = np.concatenate(
        [T0_NS + 10**9 * k + PERIOD_NS * np.arange(n) for k, n in enumerate(lengths)]
    )
    t = (stamps - T0_NS) * 1e-9
    y = 4.0 * t - 1.0
    for causal in (False, True):
        got = chunked(StreamingDerivative(period_s=PERIOD_S, causal=causal), stamps, y, [2, 5])
        lone = np.cumsum([0, *lengths])[:-1]
        assert got[0] == 0.0
        slope = np.delete(got, [0] if not causal else lone)
        np.testing.assert_allclose(slope, 4.0, rtol=1e-9)


def test_whole_log_wrapper_matches_the_stream_and_the_old_uses():
    rng = np.random.default_rng(5)
    stamps, y = make_signal(rng, 3000, 2, gaps=3)
    t_s = (stamps - stamps[0]) * 1e-9
    stream = chunked(StreamingDerivative(period_s=nominal_period(stamps)), stamps, y, [])
    np.testing.assert_array_equal(differentiate(t_s, y), stream)
    np.testing.assert_array_equal(differentiate(t_s, y[:, 0]), stream[:, 0])
    assert differentiate(np.array([0.0]), np.array([2.0])).tolist() == [0.0]
    assert differentiate(np.zeros(0), np.zeros(0)).shape == (0,)


def test_bad_settings_and_inputs_are_clear_errors():
    with pytest.raises(UsageError, match="window") as err:
        differentiate(np.arange(5.0), np.arange(5.0), window=1)
    assert isinstance(err.value, ValueError)  # what callers caught before
    with pytest.raises(UsageError, match="period"):
        StreamingDerivative(period_s=0.0)
    stage = StreamingDerivative(period_s=PERIOD_S)
    with pytest.raises(UsageError, match="integer nanoseconds"):
        stage.push(np.array([0.1, 0.2]), np.zeros(2))
    with pytest.raises(UsageError, match="one row per stamp"):
        stage.push(np.array([1, 2]), np.zeros(3))
    stage.push(np.array([1, 2]), np.zeros((2, 3)))
    with pytest.raises(UsageError, match="changed shape") as err:
        stage.push(np.array([3]), np.zeros((1, 2)))
    assert "--" not in str(err.value)


def test_a_finished_stage_takes_a_new_stream():
    rng = np.random.default_rng(7)
    stamps, y = make_signal(rng, 100, 1)
    stage = StreamingDerivative(period_s=PERIOD_S)
    first = chunked(stage, stamps, y, [50])
    second = chunked(stage, stamps, y, [])  # its stamps go back in time: a new stream anyway
    np.testing.assert_array_equal(first, second)


def test_the_stage_keeps_no_reference_to_pushed_arrays():
    rng = np.random.default_rng(8)
    stamps, y = make_signal(rng, 200, 2)
    expect = chunked(StreamingDerivative(period_s=PERIOD_S), stamps, y, [])
    stage = StreamingDerivative(period_s=PERIOD_S)
    out = []
    for a in range(0, 200, 3):
        piece = y[a : a + 3].copy()
        out.append(stage.push(stamps[a : a + 3], piece))
        piece[:] = np.nan  # the caller reuses its buffer
    out.append(stage.finish())
    np.testing.assert_array_equal(np.concatenate(out), expect)


def test_a_causal_start_never_amplifies_noise_into_a_spike():
    """At a segment's start the causal window holds a few samples only: a cubic through four
    noisy samples made the acceleration (and the twin's effort) spike at every start; a fit of
    half the points' degree keeps the first derivatives' noise near the window's own."""
    rng = np.random.default_rng(7)
    n, runs = 40, 2000
    stamps = T0_NS + np.arange(n, dtype=np.int64) * PERIOD_NS
    noise = rng.standard_normal((n, runs))
    got = chunked(StreamingDerivative(period_s=PERIOD_S, causal=True), stamps, noise, [])
    spread = np.sqrt(np.mean(got**2, axis=1))
    settled = spread[20:].mean()
    # the old fit (a cubic through 4 points, a parabola through 3) was 2.4× and 3.5× there
    assert np.all(spread[1:8] < 1.5 * settled)
