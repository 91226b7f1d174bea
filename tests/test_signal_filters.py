"""twincd.signal.filters: the low-pass filter applied to both efforts, whole or streamed, and
its edges (the extension's pivot, the settling time left out)."""

from __future__ import annotations

import itertools
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import signal
from support.streaming import T0_NS, chunked, jittered_stamps, random_walk, split_points

from twincd.defaults import DEFAULT_CUTOFF_HZ
from twincd.errors import DataError, UsageError
from twincd.signal import (
    LowPass,
    StreamingLowPass,
    decay_margin,
    nominal_period,
    settling_samples,
)
from twincd.signal.bands import slow_band
from twincd.signal.edges import EdgeFactors, edge_profile
from twincd.signal.filters import PIVOT_DEGREE, end_value
from twincd.signal.iir import critical_max_cutoff, rest_state, sosfilt

FS = 100.0
T = np.arange(0, 20, 1 / FS)
INNER = slice(300, -300)  # away from start-up at the ends


def make_values(rng: np.random.Generator, n: int, channels: int) -> np.ndarray:
    """Random walk plus big steps plus an offset; channels 0 → (n,)."""
    return random_walk(rng, n, channels, step=30, step_rate=0.005, offset=50)


def pivot(x: np.ndarray) -> np.ndarray:
    """numpy's least-squares polynomial through the samples ``x`` (from the end inwards), at the
    end: what the odd extension pivots on."""
    u = np.arange(len(x)) / max(len(x) - 1, 1)
    return np.polynomial.polynomial.polyfit(u, x, min(PIVOT_DEGREE, len(x) - 1))[0]


def reference(lp: LowPass, stamps, values, period_s: float) -> np.ndarray:
    """scipy on each gap-free segment: sosfiltfilt over the segment with its odd pads pivoted
    on the least-squares end values, or sosfilt from rest."""
    fs = 1.0 / period_s
    sos = lp.sos(fs)
    pad = lp.padlen(fs)
    out = np.array(values, dtype=np.float64)
    cuts = [0, *(np.flatnonzero(np.diff(stamps) > 5 * period_s * 1e9) + 1).tolist(), len(stamps)]
    for a, b in itertools.pairwise(cuts):
        x = out[a:b]
        if b - a < 2:
            continue
        if lp.causal:
            zi = signal.sosfilt_zi(sos)
            zi = zi[:, :, None] * x[0] if x.ndim == 2 else zi * x[0]
            out[a:b] = signal.sosfilt(sos, x, axis=0, zi=zi)[0]
        else:
            p = min(pad, b - a - 1)
            left = 2 * pivot(x[: p + 1]) - x[p:0:-1]
            right = 2 * pivot(x[::-1][: p + 1]) - x[-2 : -(p + 2) : -1]
            extended = np.concatenate((left, x, right))
            out[a:b] = signal.sosfiltfilt(sos, extended, axis=0, padtype=None)[p : p + b - a]
    return out


# ----------------------------------------------------------------------- the filter itself


@pytest.mark.parametrize("causal", [False, True])
def test_sine_above_cutoff_is_removed_and_below_kept(causal):
    lp = LowPass(cutoff_hz=2.0, order=4, causal=causal)
    slow = np.sin(2 * np.pi * 0.2 * T)
    fast = np.sin(2 * np.pi * 20.0 * T)
    assert np.abs(lp.apply(T, fast)[INNER]).max() < 0.01
    kept = lp.apply(T, slow)[INNER]
    assert np.abs(kept).max() == pytest.approx(1.0, abs=0.02)
    if not causal:  # zero-phase: no lag at all
        assert np.abs(kept - slow[INNER]).max() < 0.01


def test_zero_phase_has_no_lag_and_causal_lags():
    x = np.sin(2 * np.pi * 0.5 * T)
    zero = LowPass(2.0).apply(T, x)
    causal = LowPass(2.0, causal=True).apply(T, x)
    lag = lambda y: np.argmax(np.correlate(y[INNER], x[INNER], "full")) - (len(x[INNER]) - 1)  # noqa: E731
    assert lag(zero) == 0
    assert lag(causal) > 0


def test_columns_are_filtered_independently():
    x = np.column_stack([np.sin(2 * np.pi * 0.2 * T), np.sin(2 * np.pi * 25 * T)])
    y = LowPass(2.0).apply(T, x)
    assert y.shape == x.shape
    assert np.abs(y[INNER, 1]).max() < 0.01 < np.abs(y[INNER, 0]).max()


def test_too_short_and_bad_settings_are_clear_errors():
    with pytest.raises(DataError, match="too short"):
        LowPass().apply(np.array([0.0]), np.array([1.0]), "one.mcap")
    with pytest.raises(UsageError) as err:
        LowPass(cutoff_hz=0.0)
    assert "--" not in str(err.value)  # the library never names a CLI flag
    with pytest.raises(UsageError, match="Nyquist") as err:
        LowPass(cutoff_hz=60.0).apply(T, np.sin(T))
    assert "--" not in str(err.value)
    with pytest.raises(UsageError, match="period"):
        StreamingLowPass(LowPass(), period_s=-1.0)


def test_round_trip_through_dict():
    lp = LowPass(cutoff_hz=3.5, order=3, causal=True)
    d = lp.to_dict()
    assert d["zero_phase"] is False and d["cutoff_hz"] == 3.5
    assert LowPass.from_dict(d) == lp
    assert LowPass().cutoff_hz == DEFAULT_CUTOFF_HZ


def test_zero_phase_edges_follow_a_signal_that_starts_moving():
    # a log that starts mid-motion: slow trend plus a slow sine, well below the cut-off
    t = np.arange(0, 10, 0.01)
    x = 1 + 0.5 * t + np.sin(2 * np.pi * 0.2 * t)
    lp = LowPass(cutoff_hz=1.0)
    y = lp.apply(t, x)
    # the pivot's quadratic fit misses only the sine's higher terms over the pad (1 s)
    assert np.abs(y - x)[:100].max() < 0.015
    assert np.abs(y - x)[-100:].max() < 0.015
    # beyond the settling time, as in the middle
    span = settling_samples(lp.sos(100.0))
    assert np.abs(y - x)[span:-span].max() < 0.002


@pytest.mark.parametrize("rate_hz", [50, 1000])
def test_a_segment_end_carries_a_fraction_of_one_samples_noise(rate_hz):
    """The extension pivots on a least-squares fit, not on the end sample: the filtered value at
    a segment's end is the pivot, so its error is the fit's, about 3/√pad of the raw noise
    (sosfiltfilt's, pivoted on the one sample, carries all of it)."""
    rng = np.random.default_rng(5)
    lp = LowPass(1.5, 2, kind="critical")
    n, runs = 6 * rate_hz, 200
    x = rng.standard_normal((n, runs))  # 200 noisy constants (0), one per channel
    stamps = T0_NS + np.arange(n) * round(1e9 / rate_hz)
    y = lp.apply((stamps - T0_NS) * 1e-9, x)
    pad = lp.padlen(rate_hz)
    ends = np.sqrt(np.mean(np.concatenate((y[0], y[-1])) ** 2))
    assert ends < 1.3 * 3 / np.sqrt(pad)  # the fit's end value: ~0.12 of the raw noise at 1 kHz
    old = signal.sosfiltfilt(lp.sos(rate_hz), x, axis=0, padlen=pad)
    assert np.sqrt(np.mean(np.concatenate((old[0], old[-1])) ** 2)) > 0.8
    # past the settling time, the filtered noise of the middle
    span = settling_samples(lp.sos(float(rate_hz)))
    middle = np.sqrt(np.mean(y[n // 2 - 50 : n // 2 + 50] ** 2))
    for at in (span, -span - 1):
        assert np.sqrt(np.mean(y[at] ** 2)) < 1.3 * middle


def test_the_end_value_is_the_least_squares_polynomials_and_exact_for_a_parabola():
    rng = np.random.default_rng(6)
    u = np.arange(300.0)
    parabola = np.stack([3 - 0.2 * u + 1e-3 * u**2, -7 + 0.01 * u], axis=1)
    np.testing.assert_allclose(end_value(parabola), [3.0, -7.0], rtol=1e-12)
    x = rng.standard_normal((300, 4))
    np.testing.assert_allclose(end_value(x), pivot(x), rtol=1e-10, atol=1e-12)
    # fewer samples than the degree needs: the polynomial through them all, i.e. the end sample
    for few in (1, 2, 3):
        np.testing.assert_allclose(end_value(x[:few]), x[0], rtol=1e-12)
    # each channel alone gives the same bits as among many
    assert np.array_equal(end_value(x)[[1]], end_value(x[:, [1]]))


@pytest.mark.parametrize("causal", [False, True])
def test_a_constant_passes_unchanged_without_a_start_up_transient(causal):
    stamps = T0_NS + 1_000_000 * np.arange(20_000)
    x = np.full((20_000, 2), [3.5, -120.0])
    stage = StreamingLowPass(LowPass(1.0, causal=causal), period_s=1e-3)
    first = stage.push(stamps[:10], x[:10])
    # 1e-10: the rounded coefficients' DC gain (b ≈ 1e-5 at 1 Hz / 1 kHz), as in scipy itself;
    # a start-up transient would be of the order of the value
    if causal:  # started at rest on the first value: right from the first sample
        np.testing.assert_allclose(first, x[:10], rtol=1e-10)
    y = np.concatenate((first, stage.push(stamps[10:], x[10:]), stage.finish()))
    np.testing.assert_allclose(y, x, rtol=1e-10)


def test_scipy_is_not_imported_with_the_module():
    code = "import sys, twincd.signal; assert 'scipy.signal' not in sys.modules, 'imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


# ----------------------------------------------------------------------- streamed = whole


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 2500),
    gaps=st.integers(0, 4),
    channels=st.sampled_from([0, 1, 3]),
    causal=st.booleans(),
    cutoff=st.sampled_from([2.0, 5.0, 15.0, 25.0]),  # 25 Hz, order 1: margin = padlen
    order=st.integers(1, 4),
    how=st.sampled_from([1, 7, 1000, "whole", "random"]),
    kind=st.sampled_from(["butterworth", "critical"]),
)
def test_streamed_equals_scipy_on_each_segment(
    seed, n, gaps, channels, causal, cutoff, order, how, kind
):
    rng = np.random.default_rng(seed)
    period_ns = 10_000_000  # 100 Hz: margins of 100–900 samples, so long segments exceed them
    stamps = jittered_stamps(rng, n, period_ns, gaps)
    x = make_values(rng, n, channels)
    # a critically damped filter is refused where it would ring (test below)
    assume(kind == "butterworth" or cutoff <= critical_max_cutoff(order, 100.0))
    lp = LowPass(cutoff, order, causal=causal, kind=kind)
    if how == 1:  # one push per sample costs a backward pass each: keep those runs short
        stamps, x = stamps[:400], x[:400]
    whole = chunked(StreamingLowPass(lp, period_ns * 1e-9), stamps, x, [])
    stage = StreamingLowPass(lp, period_ns * 1e-9)
    got = chunked(stage, stamps, x, split_points(len(stamps), how, rng))
    assert got.shape == x.shape
    span = max(float(np.ptp(x)), 1.0)
    if causal:  # carried state: exactly one pass
        np.testing.assert_array_equal(got, whole)
    else:
        assert np.abs(got - whole).max(initial=0.0) <= 1e-9 * span
    ref = reference(lp, stamps, x, period_ns * 1e-9)
    assert np.abs(whole - ref).max(initial=0.0) <= 1e-9 * span
    assert np.abs(got - ref).max(initial=0.0) <= 1e-9 * span


def test_default_filter_at_1khz_streams_like_sosfiltfilt_in_bounded_memory():
    rng = np.random.default_rng(0)
    n = 60_000
    stamps = jittered_stamps(rng, n, 1_000_000, gaps=3)
    x = make_values(rng, n, 4)
    period = nominal_period(stamps)
    lp = LowPass()
    stage = StreamingLowPass(lp, period)
    # the margin is set by the slowest pole (|p| ≈ 0.9956 at 1 Hz / 1 kHz), not the pad
    assert 6000 < stage.margin < 9000 and stage.margin >= stage.padlen == 992
    out, held = [], []
    for a in range(0, n, 1000):
        out.append(stage.push(stamps[a : a + 1000], x[a : a + 1000]))
        held.append(stage.buffered)
        assert stage.pending <= stage.margin + 1000
    out.append(stage.finish())
    got = np.concatenate(out)
    ref = reference(lp, stamps, x, period)
    assert np.abs(got - ref).max() <= 1e-9 * np.ptp(x)
    # buffers never hold more than margin + 1 samples, however long the log
    assert max(held) <= stage.margin + 1
    assert stage.buffered == 0


def test_zero_phase_emits_a_sample_once_margin_later_samples_are_known():
    lp = LowPass(5.0, 2)
    stage = StreamingLowPass(lp, period_s=0.01)
    m = stage.lookahead
    assert m == stage.margin > 0
    rng = np.random.default_rng(1)
    n = m + 50
    stamps = jittered_stamps(rng, n, 10_000_000)
    x = make_values(rng, n, 1)
    for k in range(n):
        stage.push(stamps[k : k + 1], x[k : k + 1])
        assert stage.emitted == max(0, k + 1 - m)
    # a gap ends the segment: everything before it comes out at once
    tail = stage.push(stamps[-1:] + 10**9, x[-1:])
    assert len(tail) == m and stage.emitted == n
    assert StreamingLowPass(LowPass(5.0, causal=True), period_s=0.01).lookahead == 0


def test_the_margin_lets_any_start_up_transient_decay():
    lp = LowPass(1.0, 2)
    sos = lp.sos(1000.0)
    m = decay_margin(sos)
    # zero input, a unit error in each value of the history: below 1e-12 from m on
    states = 4 * len(sos)
    history = np.zeros((len(sos), 4, states))
    for j in range(states):
        history[j // 4, j % 4, j] = 1.0
    h, _ = sosfilt(sos, np.zeros((3 * m, states)), history)
    envelope = np.abs(h).sum(axis=1)
    assert envelope[m:].max() <= 1e-12 < envelope[m - 1]


@pytest.mark.parametrize("causal", [False, True])
def test_a_step_across_a_gap_does_not_leak(causal):
    stamps = T0_NS + 10_000_000 * np.concatenate((np.arange(2000), np.arange(2100, 4000)))
    x = np.where(np.arange(len(stamps)) < 2000, 1.0, 9.0)
    got = chunked(StreamingLowPass(LowPass(2.0, causal=causal), 0.01), stamps, x, [1999, 2001])
    np.testing.assert_allclose(got, x, rtol=1e-12)


def test_short_segments_use_a_shorter_pad():
    lengths = [1, 2, 5, 40, 3]
    stamps = np.concatenate(
        [T0_NS + 10**10 * k + 10_000_000 * np.arange(n) for k, n in enumerate(lengths)]
    )
    rng = np.random.default_rng(2)
    x = make_values(rng, len(stamps), 2)
    lp = LowPass(2.0, 3)
    got = chunked(StreamingLowPass(lp, 0.01), stamps, x, [1, 4, 30])
    np.testing.assert_allclose(got, reference(lp, stamps, x, 0.01), rtol=0, atol=1e-12)
    assert got[0].tolist() == x[0].tolist()  # a lone sample comes back as it is


def test_apply_is_one_push_with_the_nominal_or_given_period():
    rng = np.random.default_rng(3)
    stamps = jittered_stamps(rng, 5000, 10_000_000, gaps=2)
    x = make_values(rng, 5000, 2)
    t_s = (stamps - stamps[0]) * 1e-9
    lp = LowPass(2.0)
    period = nominal_period(stamps)
    whole = chunked(StreamingLowPass(lp, period), stamps, x, [])
    np.testing.assert_array_equal(lp.apply(t_s, x), whole)
    given_period = chunked(StreamingLowPass(lp, 0.0095), stamps, x, [])
    np.testing.assert_array_equal(lp.apply(t_s, x, period_s=0.0095), given_period)
    assert lp.apply(t_s, x[:, 0]).shape == (5000,)


@pytest.mark.parametrize("causal", [False, True])
def test_stages_keep_no_reference_to_pushed_arrays(causal):
    rng = np.random.default_rng(4)
    stamps = jittered_stamps(rng, 3000, 10_000_000)
    x = make_values(rng, 3000, 2)
    lp = LowPass(2.0, causal=causal)
    expect = chunked(StreamingLowPass(lp, 0.01), stamps, x, [])
    stage = StreamingLowPass(lp, 0.01)
    out = []
    for a in (0, 5, 40, 1500):  # a few samples (before the pad is full), then more
        piece = x[a : {0: 5, 5: 40, 40: 1500, 1500: 3000}[a]].copy()
        out.append(stage.push(stamps[a : a + len(piece)], piece))
        piece[:] = np.nan  # the caller reuses its buffer
    out.append(stage.finish())
    # zero-phase: other backward-pass starts, so equal within 1e-9 of the range, not bit for bit
    np.testing.assert_allclose(np.concatenate(out), expect, rtol=0, atol=1e-9 * np.ptp(x))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    n=st.integers(1, 300),
    how=st.sampled_from(["whole", "random", 1, 7]),
)
def test_edge_factors_follow_each_segments_ends_in_any_chunking(seed, n, how):
    rng = np.random.default_rng(seed)
    steps = np.where(rng.random(n) < 0.02, 1_000_000_000, 10_000_000)  # a few gaps
    stamps = np.cumsum(steps).astype(np.int64)
    starts = [0, *np.flatnonzero(np.diff(stamps) > 50_000_000) + 1, n]
    for lowpass in (LowPass(1.5, 2, kind="critical"), LowPass(3.0, 2, causal=True)):
        profile = edge_profile(slow_band(lowpass), 0.01)
        stage = EdgeFactors([profile], 0.01)
        got = chunked(stage, stamps, np.zeros((n, 1)), split_points(n, how, rng))
        want = np.ones(n)
        for a, b in itertools.pairwise(starts):
            k = np.arange(b - a)
            since, until = k * 0.01, (b - a - 1 - k) * 0.01
            want[a:b] = profile.factors(since, until)
        np.testing.assert_allclose(got[:, 0], want, rtol=1e-12)
        if lowpass.causal:  # a causal filter's end is like its middle
            assert len(profile.end) == 0 and profile.factors(np.array([9.9]), np.zeros(1)) == 1.0


@pytest.mark.parametrize(
    "lowpass", [LowPass(1.5, 2, kind="critical"), LowPass(1.0), LowPass(3.0, 2, causal=True)]
)
def test_the_edge_factor_is_the_noise_the_filter_leaves_near_each_end(lowpass):
    """White noise filtered many times over: its spread at each distance from a segment's ends,
    over its spread in the middle, is the profile's factor (the filter is linear: exact but for
    the sampling error of 4000 runs, ≈ 2 %)."""
    rng = np.random.default_rng(11)
    n, runs = 600, 4000
    x = rng.standard_normal((n, runs))
    stamps = T0_NS + np.arange(n, dtype=np.int64) * 10_000_000
    y = lowpass.apply((stamps - T0_NS) * 1e-9, x, period_s=0.01)
    spread = np.sqrt(np.mean(y * y, axis=1))
    measured = spread / spread[n // 2]
    profile = edge_profile(slow_band(lowpass), 0.01)
    k = np.arange(n) * 0.01
    expected = profile.factors(k, None if lowpass.causal else k[::-1])
    near = expected > 1.05
    assert near[0] and near.sum() < n // 3
    np.testing.assert_allclose(measured[near], expected[near], rtol=0.06)
    assert np.all(measured[~near] < 1.08)


# the default filter's settling time (step within 1e-3), in samples, at 50 Hz … 1 kHz: the
# docs' table (models-and-results.md, "Filter edges never flag")
SETTLING = {50: 31, 100: 63, 200: 126, 500: 315, 1000: 631}


def test_the_settling_time_is_that_of_the_step_response():
    default = LowPass(1.5, 2, kind="critical")
    for rate, samples in SETTLING.items():
        assert settling_samples(default.sos(float(rate))) == samples
        assert settling_samples(replace(default, causal=True).sos(float(rate))) == samples
    for lp in (default, LowPass(1.0), LowPass(3.0, 2, causal=True), LowPass(2.0, 4)):
        for rate in (50.0, 1000.0):
            sos = lp.sos(rate)
            span = settling_samples(sos)
            step, _ = sosfilt(sos, np.ones((20 * span, 1)), rest_state(sos, np.zeros(1)))
            error = np.abs(step[:, 0] - 1.0)
            assert error[span:].max() <= 1e-3 < error[span - 1]


@pytest.mark.parametrize("kind", ["butterworth", "critical"])
@pytest.mark.parametrize("order", [1, 2, 4])
def test_the_pivots_error_is_gone_within_the_settling_time(kind, order):
    """Zero-phase, an error e in the extension's pivot moves the filtered values near the end;
    by the settling time it has shrunk below 1e-3 e (and the causal filter's start at rest on a
    wrong value, by definition of the step response)."""
    for cutoff, rate in ((1.5, 50.0), (1.0, 1000.0), (5.0, 100.0)):
        lp = LowPass(cutoff, order, kind=kind)
        if kind == "critical" and cutoff > critical_max_cutoff(order, rate):
            continue
        sos, pad = lp.sos(rate), lp.padlen(rate)
        span = settling_samples(sos)
        n = 4 * span
        left = np.full((pad, 1), 2.0)  # the signal is 0, the pivot 1
        _, state = sosfilt(sos, left, rest_state(sos, left[0]))
        forward, state = sosfilt(sos, np.zeros((n, 1)), state)
        tail = np.concatenate((forward, sosfilt(sos, np.zeros((pad, 1)), state)[0]))
        moved = sosfilt(sos, tail[::-1], rest_state(sos, tail[-1]))[0][::-1][:n, 0]
        assert np.abs(moved[span:]).max() <= 1e-3 < abs(moved[0])


def test_a_wide_input_filters_to_the_bits_of_each_channel_alone() -> None:
    """Hundreds of channels (the identified models' regressor) go through the recursion in row
    chunks, with only the end extension's raw values kept: the same bits as one narrow run."""
    rng = np.random.default_rng(4)
    n, width = 9000, 700  # wide enough that every pass is cut into row chunks
    stamps = jittered_stamps(rng, n, 1_000_000, gaps=1)
    values = make_values(rng, n, width)
    picked = [0, 333, width - 1]
    cuts = list(itertools.pairwise([0, 1500, 5000, n]))

    def run(stage: StreamingLowPass, x: np.ndarray) -> np.ndarray:
        out = [stage.push(stamps[a:b], x[a:b]) for a, b in cuts]
        return np.concatenate([*out, stage.finish()])

    for causal in (False, True):
        lowpass = LowPass(cutoff_hz=2.0, causal=causal)
        wide = StreamingLowPass(lowpass, period_s=0.001)
        got = run(wide, values)
        assert wide.buffered == 0 and got.shape == values.shape
        alone = run(StreamingLowPass(lowpass, period_s=0.001), values[:, picked])
        assert np.array_equal(got[:, picked], alone)


def test_a_filter_describes_itself_as_recorded() -> None:
    assert LowPass(3.0, 2, causal=True).describe() == "Butterworth order 2, 3 Hz, causal"
    critical = LowPass(1.5, 2, kind="critical")
    assert critical.describe() == "critically damped order 2, 1.5 Hz, zero-phase"
