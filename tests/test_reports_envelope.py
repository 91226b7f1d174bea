"""The min/max-per-column downsampler that figures of long logs are drawn from."""

from __future__ import annotations

import pickle

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from twincd.reports.envelope import Envelope


def pushed(values: np.ndarray, columns: int, block: int) -> Envelope:
    env = Envelope(values.shape[1], columns)
    t = np.arange(len(values), dtype=np.int64) * 1000
    for start in range(0, len(values), block):
        env.push(t[start : start + block], values[start : start + block])
    return env


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 5000),
    columns=st.integers(1, 50),
    block=st.integers(1, 700),
    spike_at=st.floats(0, 1, exclude_max=True),
    spike=st.floats(1.0, 1e6),
)
def test_a_one_sample_spike_survives(n, columns, block, spike_at, spike):
    values = np.random.default_rng(n).uniform(-1, 1, (n, 2))
    i = int(spike_at * n)
    values[i, 1] = spike
    values[i, 0] = -spike
    env = pushed(values, columns, block)
    assert len(env.t) <= 2 * columns
    assert np.nanmax(env.high[:, 1]) == spike
    assert np.nanmin(env.low[:, 0]) == -spike
    # the spike sits in the column whose time span holds its sample
    col = np.searchsorted(env.t, i * 1000, side="right") - 1
    assert env.high[col, 1] == spike


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 3000), columns=st.integers(1, 40), block=st.integers(1, 500))
def test_blocks_do_not_change_the_envelope(n, columns, block):
    values = np.random.default_rng(0).normal(size=(n, 3))
    whole, chunked = pushed(values, columns, n), pushed(values, columns, block)
    np.testing.assert_array_equal(whole.t, chunked.t)
    np.testing.assert_array_equal(whole.low, chunked.low)
    np.testing.assert_array_equal(whole.high, chunked.high)
    # each column is the exact min/max of its samples
    span = whole.span
    for c in range(len(whole.t)):
        part = values[c * span : (c + 1) * span]
        np.testing.assert_array_equal(whole.low[c], part.min(0))
        np.testing.assert_array_equal(whole.high[c], part.max(0))


def test_bounded_memory_and_small_pickle():
    env = Envelope(16, 1000)
    t = np.arange(1_200_000, dtype=np.int64)
    for start in range(0, len(t), 100_000):
        env.push(t[start : start + 100_000], np.zeros((100_000, 16)))
    assert 1000 <= len(env.t) <= 2000
    size = len(pickle.dumps(env))
    assert size < 2000 * 16 * 2 * 8 + 20_000
    again = pickle.loads(pickle.dumps(env))
    again.push(t[:10] + len(t), np.ones((10, 16)))
    assert np.nanmax(again.high) == 1.0


def test_non_finite_values_are_ignored():
    env = Envelope(1, 4)
    env.push(np.arange(4), np.array([[np.nan], [1.0], [np.inf], [np.nan]]))
    assert np.isnan(env.low[0, 0]) and env.high[1, 0] == 1.0


def test_line_interleaves_min_and_max():
    env = Envelope(1, 2)
    env.push(np.arange(8), np.arange(8.0)[:, None])
    x, y = env.line(0)
    assert len(x) == 2 * len(env.t)
    assert y[0::2].tolist() == env.low[:, 0].tolist()
    assert y[1::2].tolist() == env.high[:, 0].tolist()
