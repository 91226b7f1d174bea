"""twincd.signal.iir: Butterworth and critically damped designs and the section recursion,
against scipy.signal."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from twincd.signal.filters import LowPass
from twincd.signal.iir import butter_lowpass_sos, critical_lowpass_sos, rest_state, sosfilt


@pytest.mark.parametrize("order", range(1, 11))
@pytest.mark.parametrize("cutoff", [0.05, 0.3, 1.0, 3.0, 10.0, 100.0, 250.0, 400.0, 499.0])
def test_design_is_scipys_butter(order, cutoff):
    ours = butter_lowpass_sos(order, cutoff, 1000.0)
    theirs = signal.butter(order, cutoff, fs=1000.0, output="sos")
    assert ours.shape == theirs.shape
    # the same recipe and pairing: equal to the last bit or so
    np.testing.assert_allclose(ours, theirs, rtol=1e-15, atol=1e-15 * np.abs(theirs).max())


@pytest.mark.parametrize("order", range(1, 7))
@pytest.mark.parametrize("cutoff", [0.3, 1.0, 3.0, 10.0])
def test_critical_design_is_scipys_bilinear_of_equal_real_poles(order, cutoff):
    fs = 1000.0
    pole = 2 * fs * np.tan(np.pi * cutoff / fs) / np.sqrt(2 ** (1 / order) - 1)
    z, p, k = signal.bilinear_zpk([], [-pole] * order, pole**order, fs)
    ours = critical_lowpass_sos(order, cutoff, fs)
    _, theirs = signal.freqz_zpk(z, p, k, worN=256, fs=fs)
    _, mine = signal.sosfreqz(ours, worN=256, fs=fs)
    np.testing.assert_allclose(mine, theirs, atol=1e-12)
    _, at_cutoff = signal.sosfreqz(ours, worN=[0.0, cutoff], fs=fs)
    assert abs(at_cutoff[0]) == pytest.approx(1.0, abs=1e-9)  # unit gain at 0 Hz
    assert abs(at_cutoff[1]) ** 2 == pytest.approx(0.5, rel=1e-9)  # 3 dB down at the cut-off


@pytest.mark.parametrize("kind, rings", [("butterworth", True), ("critical", False)])
def test_only_the_critical_filter_is_free_of_ringing_around_a_step(kind, rings):
    # what a push does to the residual: a step, zero-phase filtered; Butterworth swings below
    # before it and above after it (the lobes that crossed the identified models' threshold)
    t = np.arange(2000) * 0.01
    step = (t >= 10.0).astype(float)
    out = LowPass(1.0, 4, kind=kind).apply(t, step)
    swing = max(-out[t < 10.0].min(), out[t >= 10.0].max() - 1.0)
    assert (swing > 0.01) == rings, swing
    if not rings:
        assert swing < 1e-9 and np.all(np.diff(out) >= -1e-12)  # monotonic


@pytest.mark.parametrize("bad", [(0, 1.0), (2, 0.0), (2, 500.0), (2, -1.0)])
def test_design_refuses_impossible_settings(bad):
    with pytest.raises(ValueError):
        butter_lowpass_sos(bad[0], bad[1], 1000.0)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_filtering_is_scipys_sosfilt_from_rest(order):
    rng = np.random.default_rng(order)
    x = 50 + rng.standard_normal((30_000, 5)).cumsum(axis=0)
    sos = signal.butter(order, 1.0, fs=1000.0, output="sos")
    zi = signal.sosfilt_zi(sos)[:, :, None] * x[0][None, None, :]
    theirs, _ = signal.sosfilt(sos, x, axis=0, zi=zi)
    ours, _ = sosfilt(sos, x, rest_state(sos, x[0]))
    assert np.abs(ours - theirs).max() <= 1e-11 * np.ptp(x)


def test_direct_form_one_is_closer_to_long_double_than_scipy():
    # the reason the recursion is direct form I: measured against a long-double reference
    rng = np.random.default_rng(1)
    t = np.arange(20_000) / 1000.0
    x = (10 + 5 * np.sin(2 * np.pi * 0.3 * t) + 0.5 * rng.standard_normal(t.size))[:, None]
    sos = signal.butter(2, 1.0, fs=1000.0, output="sos")
    b0, b1, b2, _, a1, a2 = sos[0].astype(np.longdouble)
    xl = x[:, 0].astype(np.longdouble)
    ref = np.zeros_like(xl)
    z0 = z1 = np.longdouble(0)
    for k, v in enumerate(xl):
        out = b0 * v + z0
        z0, z1 = b1 * v - a1 * out + z1, b2 * v - a2 * out
        ref[k] = out
    ours, _ = sosfilt(sos, x, rest_state(sos, np.zeros(1)))
    theirs = signal.sosfilt(sos, x, axis=0)
    assert np.abs(ours[:, 0] - ref).max() < np.abs(theirs[:, 0] - ref).max()


def test_a_constant_stays_put_from_rest():
    sos = butter_lowpass_sos(4, 1.0, 1000.0)
    x = np.full((5000, 3), [7.25, -120.0, 0.0])
    y, _ = sosfilt(sos, x, rest_state(sos, x[0]))
    np.testing.assert_allclose(y, x, rtol=1e-10, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    order=st.integers(1, 4),
    cuts=st.lists(st.integers(0, 600), max_size=12),
    seed=st.integers(0, 2**32 - 1),
)
def test_any_chunking_gives_the_same_bits(order, cuts, seed):
    rng = np.random.default_rng(seed)
    x = 50 + rng.standard_normal((600, 3)).cumsum(axis=0)
    sos = butter_lowpass_sos(order, 2.0, 1000.0)
    start = rest_state(sos, x[0])
    whole, end = sosfilt(sos, x, start)
    parts, state = [], start
    for a, b in zip([0, *sorted(cuts)], [*sorted(cuts), 600], strict=True):
        y, state = sosfilt(sos, x[a:b], state)
        parts.append(y)
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    np.testing.assert_array_equal(state, end)


def test_scipy_signal_is_not_imported_to_filter():
    code = (
        "import sys, numpy as np; from twincd.signal import LowPass; "
        "LowPass(1.0).apply(np.arange(3000) / 1000, np.sin(np.arange(3000) / 100)); "
        "assert 'scipy.signal' not in sys.modules, 'imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_critical_filter_that_would_ring_is_refused():
    from twincd.errors import UsageError
    from twincd.signal.iir import critical_max_cutoff

    highest = critical_max_cutoff(2, 100.0)  # ≈ 18 Hz: poles at 0 there
    assert critical_lowpass_sos(2, highest * 0.99, 100.0)[0, 4] < 0  # a − 2p < 0: p > 0
    with pytest.raises(ValueError, match="overshoots"):
        critical_lowpass_sos(2, highest * 1.01, 100.0)
    with pytest.raises(UsageError, match="too high for a critically damped"):
        LowPass(20.0, 2, kind="critical").sos(100.0)
