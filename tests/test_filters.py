"""twincd.signal.filters: the Butterworth low-pass applied to both efforts."""

from __future__ import annotations

import numpy as np
import pytest

from twincd.errors import DataError, UsageError
from twincd.signal.filters import DEFAULT_CUTOFF_HZ, LowPass

FS = 100.0
T = np.arange(0, 20, 1 / FS)
INNER = slice(300, -300)  # away from start-up at the ends


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
    with pytest.raises(UsageError):
        LowPass(cutoff_hz=0.0)
    with pytest.raises(UsageError, match="Nyquist"):
        LowPass(cutoff_hz=60.0).apply(T, np.sin(T))


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
    y = LowPass(cutoff_hz=1.0).apply(t, x)
    assert np.abs(y - x)[:100].max() < 0.01
    assert np.abs(y - x)[-100:].max() < 0.01
