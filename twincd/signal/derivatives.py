"""Time derivatives of irregularly sampled signals.

A Savitzky–Golay differentiator on real time: around every sample, a polynomial of degree
``polyorder`` is fitted by least squares to ``window`` neighbouring samples using their true time
offsets, and its slope at the sample is the derivative. Jittered stamps therefore do not turn into
spikes the way a fixed-step difference would. The signal is cut into segments at gaps longer than
``gap_factor`` × the median period, and each segment is differentiated on its own (the window is
shifted, never stretched, across a segment's ends).

Hand-written because scipy.signal.savgol_filter assumes uniform sampling. The work is vectorised:
one batched (polyorder+1)² solve per sample over all channels.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

DEFAULT_WINDOW = 9
DEFAULT_POLYORDER = 3
DEFAULT_GAP_FACTOR = 5.0
_BLOCK = 65536


def segment_bounds(
    t_s: FloatArray, gap_factor: float = DEFAULT_GAP_FACTOR
) -> list[tuple[int, int]]:
    """[start, stop) index ranges of runs without a gap longer than gap_factor × median period."""
    n = len(t_s)
    if n < 2:
        return [(0, n)] if n else []
    dt = np.diff(t_s)
    median = float(np.median(dt))
    cuts = np.flatnonzero(dt > gap_factor * median) + 1 if median > 0 else np.array([], int)
    edges = [0, *cuts.tolist(), n]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def _segment_derivative(t: FloatArray, y: FloatArray, window: int, polyorder: int) -> FloatArray:
    n = len(t)
    if n == 1:
        return np.zeros_like(y)
    window = min(window, n)
    order = min(polyorder, window - 1)
    half = window // 2
    # window start per sample: centred where possible, shifted to stay inside the segment
    start = np.clip(np.arange(n) - half, 0, n - window)
    scale = float(np.median(np.diff(t))) or 1.0  # time unit for a well-conditioned fit
    out = np.empty_like(y)
    # blocks bound the (block, window, order) temporaries on hour-long logs
    for b0 in range(0, n, _BLOCK):
        rows = np.arange(b0, min(b0 + _BLOCK, n))
        idx = start[rows, None] + np.arange(window)[None, :]  # (rows, window)
        d = (t[idx] - t[rows, None]) / scale  # time offsets from the sample itself
        powers = d[:, :, None] ** np.arange(order + 1)[None, None, :]
        gram = np.einsum("nwi,nwj->nij", powers, powers)
        rhs = np.einsum("nwi,nwc->nic", powers, y[idx])
        out[rows] = np.linalg.solve(gram, rhs)[:, 1, :] / scale
    return out


def differentiate(
    t_s: FloatArray,
    values: FloatArray,
    window: int = DEFAULT_WINDOW,
    polyorder: int = DEFAULT_POLYORDER,
    gap_factor: float = DEFAULT_GAP_FACTOR,
) -> FloatArray:
    """d(values)/dt for values of shape (N,) or (N, channels) sampled at times t_s (seconds)."""
    if window < 2 or polyorder < 1:
        raise ValueError("the differentiator needs window >= 2 and polyorder >= 1")
    y = np.asarray(values, dtype=np.float64)
    flat = y.ndim == 1
    y2 = y[:, None] if flat else y
    out = np.zeros_like(y2)
    for a, b in segment_bounds(t_s, gap_factor):
        out[a:b] = _segment_derivative(t_s[a:b], y2[a:b], window, polyorder)
    return out[:, 0] if flat else out
