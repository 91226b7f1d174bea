"""Time derivatives of irregularly sampled signals, whole or streamed.

A Savitzky–Golay differentiator on real time: a polynomial of degree ``polyorder`` is fitted by
least squares to ``window`` neighbouring samples at their true time offsets, and its slope at the
sample is the derivative, so jittered stamps do not turn into spikes the way a fixed-step
difference would. The stream is cut into segments at gaps (an interval longer than
``gap_factor`` × the nominal period) and each segment is differentiated on its own.

``StreamingDerivative`` is the one implementation; ``differentiate`` runs it on a whole log.
Centred (default): the window is centred on the sample, shifted — never stretched — to stay
inside its segment; a sample is emitted once its window is complete (4 samples of lookahead for
a window of 9) or its segment has ended. Causal: the window is the last
``window`` samples of the segment up to the sample (fewer at a segment start) and the slope is
taken at the newest one; every sample is emitted at once (what a live detector uses).

Hand-written because scipy.signal.savgol_filter assumes uniform sampling. The fit is vectorised
over samples with elementwise numpy only (power sums, a small elimination per sample), so each
output depends on its own window alone and chunked runs equal one run exactly.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike

from twincd.errors import UsageError
from twincd.signal.stream import (
    DEFAULT_GAP_FACTOR,
    SegmentedStage,
    nominal_period,
    run_whole,
    seconds_to_ns,
    segment_bounds,
)
from twincd.types import FloatArray, IntArray

__all__ = [
    "DEFAULT_GAP_FACTOR",
    "DEFAULT_POLYORDER",
    "DEFAULT_WINDOW",
    "StreamingDerivative",
    "differentiate",
    "nominal_period",
    "segment_bounds",
]

DEFAULT_WINDOW = 9
DEFAULT_POLYORDER = 3
# rows per vectorised step: bounds the temporaries on hour-long pushes
_BLOCK = 16384


class SettingsError(UsageError, ValueError):
    """Differentiator settings that cannot work (also a ValueError, as it always was)."""


def _check_settings(window: int, polyorder: int) -> None:
    if window < 2 or polyorder < 1:
        raise SettingsError(
            f"the differentiator needs a window of at least 2 samples and a polynomial degree "
            f"of at least 1 (got {window} and {polyorder})",
            "differentiator settings",
            "use the defaults (9 samples, degree 3)",
        )


def _solve(a: FloatArray, v: FloatArray) -> FloatArray:
    """Solve a[:, :, i] x[:, i] = v[:, i] for a stack of small symmetric positive definite
    systems (a: (k, k, m), v: (k, m)).

    Gaussian elimination without pivoting (fine for SPD), written with elementwise numpy only
    (no reductions, whose summation order may depend on the array's shape), so the result for
    one sample never depends on the other samples of the batch.
    """
    k = len(v)
    a = a.copy()
    v = v.copy()
    for c in range(k - 1):
        f = a[c + 1 :, c] / a[c, c]
        a[c + 1 :, c + 1 :] -= f[:, None] * a[c, c + 1 :][None]
        v[c + 1 :] -= f * v[c]
    x = np.empty_like(v)
    for r in range(k - 1, -1, -1):
        acc = v[r].copy()
        for q in range(r + 1, k):
            acc -= a[r, q] * x[q]
        x[r] = acc / a[r, r]
    return x


def _slopes(
    t: IntArray,
    y: FloatArray,
    rows: tuple[int, int],
    window: int,
    at: int,
    order: int,
    scale_ns: float,
) -> FloatArray:
    """Slope at buffer rows [r0, r1) of the degree-``order`` least-squares polynomial through
    the ``window`` samples starting ``at`` samples before each row."""
    r0, r1 = rows
    out = np.zeros((r1 - r0, y.shape[1]))
    if window < 2:
        return out  # a lone sample has no slope
    k = order + 1
    mid = window // 2  # offsets from the window's middle keep the normal equations well scaled
    hankel = np.add.outer(np.arange(k), np.arange(k))
    for b0 in range(r0, r1, _BLOCK):
        m = min(b0 + _BLOCK, r1) - b0
        lo = b0 - at  # window start of the block's first row
        tw = sliding_window_view(t[lo : lo + m + window - 1], window)  # (m, window)
        # integer ns differences first: independent of where the stream or a chunk began
        d = (tw - tw[:, mid : mid + 1]).T / scale_ns  # (window, m), in periods
        # d^1 … d^(2·order), then their sums over the window in window order: the normal
        # equations' Hankel matrix (explicit loops: no reduction whose order could vary)
        pw = np.empty((window, 2 * order, m))
        pw[:, 0] = d
        for e in range(1, 2 * order):
            pw[:, e] = pw[:, e - 1] * d
        sums = np.empty((2 * order + 1, m))
        sums[0] = window
        sums[1:] = pw[0]
        for j in range(1, window):
            sums[1:] += pw[j]
        # d/dt of Σ c_e d^e at the evaluated sample (offset s): Σ e c_e s^(e−1)
        s = d[at]
        v = np.zeros((k, m))
        v[1] = 1.0
        power = np.ones(m)
        for e in range(2, k):
            power = power * s
            v[e] = e * power
        g = _solve(sums[hankel], v)
        h = np.empty((window, m))  # weights of the window's samples, by Horner
        h[:] = g[k - 1]
        for e in range(k - 2, -1, -1):
            h *= d
            h += g[e]
        acc = h[0][:, None] * y[lo : lo + m]
        for j in range(1, window):
            acc += h[j][:, None] * y[lo + j : lo + j + m]
        out[b0 - r0 : b0 - r0 + m] = acc / (scale_ns * 1e-9)
    return out


class StreamingDerivative(SegmentedStage):
    """Savitzky–Golay derivative on real time, pushed in chunks of any size.

    ``push(stamp_ns, values)`` takes int64 ns stamps (n,) and values (n,) or (n, channels) and
    returns d(values)/dt (per second) for the oldest samples not emitted yet, in order;
    ``finish()`` returns the rest. Whatever the chunking, the outputs are identical.

    Centred (default): ``lookahead`` = window − 1 − window // 2 samples (4 for 9); the first
    samples of a segment wait for its first full window, and the last ones for the segment's
    end (a gap or ``finish()``). Causal: ``lookahead`` = 0, every sample is emitted at once.
    ``buffered`` never exceeds ``window`` samples.
    """

    def __init__(
        self,
        window: int = DEFAULT_WINDOW,
        polyorder: int = DEFAULT_POLYORDER,
        *,
        period_s: float,
        gap_factor: float = DEFAULT_GAP_FACTOR,
        causal: bool = False,
    ) -> None:
        _check_settings(window, polyorder)
        super().__init__(period_s, gap_factor)
        self.window = int(window)
        self.polyorder = int(polyorder)
        self.causal = bool(causal)
        self._half = self.window // 2
        self.lookahead = 0 if self.causal else self.window - 1 - self._half
        self._scale_ns = self.period_s * 1e9  # fit in units of the period: well conditioned
        self._t = np.zeros(0, dtype=np.int64)
        self._y = np.zeros((0, 1))
        self._n = 0  # samples of the current segment seen
        self._base = 0  # segment index of the buffer's first sample
        self._next = 0  # segment index of the next sample to emit

    @property
    def buffered(self) -> int:
        """Samples held in the internal buffer (at most ``window``)."""
        return len(self._t)

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        if self._n:
            self._t = np.concatenate((self._t, t))
            self._y = np.concatenate((self._y, y))
        else:
            self._t, self._y, self._base, self._next = t, y, 0, 0
        self._n += len(t)
        if self.causal:
            stop = self._n
        elif self._n >= self.window:  # windows are complete up to window − 1 − half from the end
            stop = max(self._next, self._n - self.window + self._half + 1)
        else:  # even the first window is not complete yet
            stop = self._next
        out = self._emit(stop, final=False)
        if self.causal:
            keep = self._n - (self.window - 1)
        else:
            keep = min(self._next - self._half, self._n - self.window)
        keep = max(keep, self._base)
        # copies: the buffer must not alias the caller's arrays
        self._t = self._t[keep - self._base :].copy()
        self._y = self._y[keep - self._base :].copy()
        self._base = keep
        return out

    def _end_segment(self) -> FloatArray:
        if not self._n:
            return np.zeros((0, max(self._width, 1)))
        out = self._emit(self._n, final=True)
        self._t = np.zeros(0, dtype=np.int64)
        self._y = np.zeros((0, self._y.shape[1]))
        self._n = self._base = self._next = 0
        return out

    def _emit(self, stop: int, final: bool) -> FloatArray:
        """Derivatives of segment samples [next, stop); ``final``: the segment has ended."""
        i = np.arange(self._next, stop)
        if not len(i):
            return np.zeros((0, self._y.shape[1]))
        w = self.window
        if self.causal:
            width = np.minimum(w, i + 1)
            at = width - 1
        else:
            n_known = self._n if final else None
            w_eff = min(w, n_known) if n_known is not None else w
            width = np.full(len(i), w_eff)
            start = np.maximum(i - self._half, 0)
            if n_known is not None:  # shifted, never stretched, at the segment's end
                start = np.minimum(start, n_known - w_eff)
            at = i - start
        # rows sharing a window length and position are one vectorised step
        change = np.flatnonzero((np.diff(width) != 0) | (np.diff(at) != 0)) + 1
        parts = []
        for a, b in zip([0, *change.tolist()], [*change.tolist(), len(i)]):
            wa, ata = int(width[a]), int(at[a])
            order = _order(self.polyorder, wa)
            rows = (int(i[a]) - self._base, int(i[b - 1]) + 1 - self._base)
            parts.append(_slopes(self._t, self._y, rows, wa, ata, order, self._scale_ns))
        self._next = stop
        return np.concatenate(parts)


def _order(polyorder: int, width: int) -> int:
    """The polynomial degree over ``width`` samples: ``polyorder``, but never more than half the
    samples' count allows (at least a slope), so a window cut short at a segment's start (causal)
    or by a short segment fits with twice the samples it needs, and a cubic through four noisy
    samples does not amplify their noise into a spike of acceleration (and of the twin's effort)
    at every segment's start."""
    return min(polyorder, max(1, (width - 1) // 2))


def differentiate(
    t_s: ArrayLike,
    values: ArrayLike,
    window: int = DEFAULT_WINDOW,
    polyorder: int = DEFAULT_POLYORDER,
    gap_factor: float = DEFAULT_GAP_FACTOR,
) -> FloatArray:
    """d(values)/dt for values (N,) or (N, channels) at times t_s (seconds), centred, the period
    being ``nominal_period`` of these times: a ``StreamingDerivative`` fed the whole log.

    Times are taken to whole nanoseconds (as header stamps are) relative to the first one.
    """
    _check_settings(window, polyorder)
    y = np.asarray(values, dtype=np.float64)
    ns = seconds_to_ns(t_s)
    if len(ns) < 2:
        return np.zeros_like(y)
    stage = StreamingDerivative(
        window, polyorder, period_s=nominal_period(ns), gap_factor=gap_factor
    )
    return run_whole(stage, ns, y)
