"""Low-pass filtering of effort signals (the paper's τ̃ and τ̂̃), whole or streamed.

A Butterworth (or critically damped, ``kind="critical"``) filter as second-order sections, run
zero-phase (``scipy.signal.sosfiltfilt``'s forward-backward pass over each segment with an odd
extension of ``padlen`` samples at its ends; the default for offline logs) or causal (forward
only, started in steady state at each segment's first value: what a live detector sees).
Streams are cut at gaps (twincd.signal.stream.Segmenter) and each segment is filtered on its own;
the sampling rate is the nominal one given by the caller, never estimated from a whole log.

Edges. sosfiltfilt pivots its odd extension on the end sample itself, so that sample's raw noise
becomes an offset of the filtered value at the segment's end, where it decays over the filter's
settling time; at 1 kHz the filtered noise is far below the raw noise and that offset alone
crossed the threshold on clean logs. Here the extension pivots on the end value of a quadratic
least-squares fit through the samples it reflects (``end_value``): exact for a line or a
parabola, and with a fraction of one sample's noise. What is left — the pivot's remaining error,
the causal filter's start at rest on one sample — is noise of a known size: every sample is
judged, with the noise scale its distance from the segment's ends implies
(``twincd.signal.edges``).

``StreamingLowPass`` is the one implementation; ``LowPass.apply`` runs it on a whole log.
Streamed zero-phase filtering runs the forward pass exactly (state carried between pushes) and
the backward pass over overlapping blocks: each block's backward pass starts ``margin`` samples
beyond the samples it emits, in steady state, where ``margin`` is long enough for the start-up
transient to decay below 1e-12 (``decay_margin``); at a segment's end the true end extension is
used. So a sample is emitted ``margin`` samples late, memory stays bounded by block + margin,
and the result equals the whole-segment forward-backward pass to ~1e-12 of the signal's range.

The design and the recursion are twincd.signal.iir's (scipy.signal's results without its
import cost).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from twincd.defaults import DEFAULT_CAUSAL_CUTOFF_HZ, DEFAULT_CUTOFF_HZ, DEFAULT_ORDER
from twincd.errors import DataError, UsageError
from twincd.signal.iir import (
    butter_lowpass_sos,
    critical_lowpass_sos,
    critical_max_cutoff,
    rest_state,
    sosfilt,
)
from twincd.signal.stream import (
    DEFAULT_GAP_FACTOR,
    SegmentedStage,
    nominal_period,
    run_whole,
    seconds_to_ns,
)
from twincd.types import FloatArray, IntArray

__all__ = [
    "DECAY_TOLERANCE",
    "DEFAULT_CAUSAL_CUTOFF_HZ",
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_ORDER",
    "FILTER_KINDS",
    "PIVOT_DEGREE",
    "SETTLING_TOLERANCE",
    "LowPass",
    "StreamingLowPass",
    "decay_margin",
    "end_value",
    "settling_samples",
]

# the streamed backward pass starts where its start-up transient will have decayed below this
# (relative to the size of the state error, itself of the order of the signal's range)
DECAY_TOLERANCE = 1e-12
# a filter has settled once its step response stays within this of its final value: any start-up
# error has then shrunk below 1e-3 of itself (``settling_samples``; how far edges reach)
SETTLING_TOLERANCE = 1e-3
# the zero-phase extension's pivot: a least-squares polynomial of this degree through the samples
# the extension reflects, taken at the end sample (``end_value``)
PIVOT_DEGREE = 2
# samples emitted per backward pass when much is ready at once: cost (block + margin) / block
_BLOCK = 16384
# values (rows × channels) per call of the recursion: its temporaries stay a few MB however
# wide the input (the identified models filter hundreds of channels) or long the pass
_CHUNK_VALUES = 1 << 19


# butterworth: the flattest pass band (the default); critical: equal real poles, no overshoot,
# no ringing around a step (what a residual at the noise floor needs: the identified models)
FILTER_KINDS = ("butterworth", "critical")


@dataclass(frozen=True)
class LowPass:
    """Low-pass settings; recorded in the calibration (contract: The calibration file
    ``filter``)."""

    cutoff_hz: float = DEFAULT_CUTOFF_HZ
    order: int = DEFAULT_ORDER
    causal: bool = False
    kind: str = "butterworth"

    def __post_init__(self) -> None:
        if self.kind not in FILTER_KINDS:
            raise UsageError(
                f"unknown filter kind {self.kind!r}",
                "filter",
                f"use one of {', '.join(FILTER_KINDS)}",
                option="filter_kind",
            )
        if self.order < 1 or not self.cutoff_hz > 0:
            raise UsageError(
                "filter order must be >= 1 and cut-off > 0 Hz",
                f"order={self.order}, cutoff={self.cutoff_hz}",
                "pick a positive filter order and cut-off",
            )

    def sos(self, fs_hz: float) -> FloatArray:
        """Second-order sections of the filter at sampling rate ``fs_hz``."""
        if self.cutoff_hz >= fs_hz / 2:
            raise UsageError(
                f"cut-off {self.cutoff_hz} Hz is not below the Nyquist rate {fs_hz / 2:.3g} Hz",
                "filter settings",
                "pick a lower cut-off",
            )
        if self.kind == "critical":
            highest = critical_max_cutoff(self.order, fs_hz)
            if self.cutoff_hz > highest:
                raise UsageError(
                    f"cut-off {self.cutoff_hz:g} Hz is too high for a critically damped filter "
                    f"of order {self.order} at {fs_hz:.4g} Hz (it would ring above "
                    f"{highest:.3g} Hz)",
                    "filter settings",
                    "pick a lower cut-off, a higher order, or the butterworth kind",
                    option="cutoff",
                )
            return critical_lowpass_sos(self.order, self.cutoff_hz, fs_hz)
        return butter_lowpass_sos(self.order, self.cutoff_hz, fs_hz)

    def padlen(self, fs_hz: float) -> int:
        """Zero-phase edge pad: about one period of the cut-off (scipy's default of a few
        samples leaves start-up transients on logs that begin with the arm moving)."""
        sections = (self.order + 1) // 2
        # the tiny epsilon keeps 1/0.001 s ÷ 1 Hz at 1000 samples whatever the rounding
        return max(3 * (2 * sections + 1), math.ceil(fs_hz / self.cutoff_hz - 1e-9))

    def apply(
        self,
        t_s: ArrayLike,
        values: ArrayLike,
        source: str = "",
        period_s: float | None = None,
        gap_factor: float = DEFAULT_GAP_FACTOR,
    ) -> FloatArray:
        """Filter (N, channels) or (N,) values sampled at t_s (seconds), gap by gap: a
        ``StreamingLowPass`` fed the whole log. ``period_s`` None → ``nominal_period`` of t_s
        (times taken to whole nanoseconds, as header stamps are)."""
        x = np.asarray(values, dtype=np.float64)
        ns = seconds_to_ns(t_s)
        if len(ns) < 2:
            raise DataError("log too short to filter", source, "record at least a few seconds")
        period = nominal_period(ns, source) if period_s is None else period_s
        return run_whole(StreamingLowPass(self, period, gap_factor), ns, x)

    def describe(self) -> str:
        """For people: e.g. "critically damped order 2, 1.5 Hz, zero-phase"."""
        kind = "critically damped" if self.kind == "critical" else "Butterworth"
        how = "causal" if self.causal else "zero-phase"
        return f"{kind} order {self.order}, {self.cutoff_hz:g} Hz, {how}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["zero_phase"] = not self.causal
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LowPass:
        return cls(
            cutoff_hz=float(d["cutoff_hz"]),
            order=int(d["order"]),
            causal=bool(d["causal"]),
            kind=str(d.get("kind", "butterworth")),
        )


def settling_samples(sos: FloatArray, tolerance: float = SETTLING_TOLERANCE) -> int:
    """Samples the filter ``sos`` takes to settle: from this many samples after a step on, its
    step response (from rest at 0) stays within ``tolerance`` of its final value (the DC
    gain). A start at rest on a wrong value (the causal filter's start on one sample) is the
    same response scaled, so its error has then shrunk below ``tolerance`` of itself; so has the
    zero-phase extension's, whose pivot's influence decays faster still (checked in
    tests/test_signal_filters.py). Cached, as ``decay_margin``."""
    sos = np.ascontiguousarray(sos, dtype=np.float64)
    return _settling(sos.tobytes(), len(sos), float(tolerance))


@lru_cache(maxsize=64)
def _settling(sos_bytes: bytes, sections: int, tolerance: float) -> int:
    sos = np.frombuffer(sos_bytes, dtype=np.float64).reshape(sections, 6)
    gain = float(np.prod(sos[:, :3].sum(axis=1) / sos[:, 3:].sum(axis=1)))
    radius = _pole_radius(sos)
    # a first guess: four times the samples in which the slowest pole shrinks by e
    length = 64 if radius == 0 else max(64, 4 * math.ceil(-1.0 / math.log(radius)))
    while True:
        step, _ = sosfilt(sos, np.ones((length, 1)), rest_state(sos, np.zeros(1)))
        above = np.flatnonzero(np.abs(step[:, 0] - gain) > tolerance * abs(gain))
        last = int(above[-1]) + 1 if len(above) else 0
        if last < length * 3 // 4:  # the tail of the simulation is well within: settled
            return last
        length *= 2


def _pole_radius(sos: FloatArray) -> float:
    """The largest pole magnitude of ``sos`` (UsageError when it is not below 1)."""
    poles = np.concatenate([np.roots(section[3:]) for section in sos])
    radius = float(np.abs(poles).max()) if len(poles) else 0.0
    if radius >= 1:
        raise UsageError("the filter is unstable", "filter settings", "pick another cut-off")
    return radius


def end_value(x: FloatArray, degree: int = PIVOT_DEGREE) -> FloatArray:
    """The value at ``x[0]`` (rows: a segment's samples from one end inwards, (n, channels)) of
    the least-squares polynomial of ``degree`` (at most n − 1) through all of them, per channel:
    a robust estimate of the segment's end value, where ``x[0]`` alone carries one sample's
    noise. Each channel's value depends on its own column alone, to the bit."""
    weights = _end_weights(len(x), min(degree, len(x) - 1))
    # row by row in a fixed order: the same bits whatever the number of channels
    acc: FloatArray = weights[0] * x[0]
    for w, row in zip(weights[1:], x[1:], strict=True):
        acc = acc + w * row
    return acc


@lru_cache(maxsize=64)
def _end_weights(count: int, degree: int) -> FloatArray:
    """Weights of ``count`` samples (from the end inwards) giving the least-squares polynomial
    of ``degree`` at the end sample: row 0 of the pseudo-inverse of its Vandermonde matrix."""
    if count < 1:
        raise ValueError("no sample to take an end value from")
    u = np.arange(count, dtype=np.float64) / max(count - 1, 1)  # [0, 1]: well conditioned
    weights: FloatArray = np.linalg.pinv(np.polynomial.polynomial.polyvander(u, degree))[0]
    weights.setflags(write=False)
    return weights


def decay_margin(sos: FloatArray, tolerance: float = DECAY_TOLERANCE) -> int:
    """Samples after which any start-up transient of ``sos`` stays below ``tolerance`` × the
    initial state error: the last sample where the summed |zero-input response| to a unit error
    in each value of the filter's history exceeds it, plus one. Sized by the slowest pole,
    checked by simulation (cached: a fleet of logs at one rate asks for it once per log, and the
    simulation was 40 % of a 100 Hz sample log's work)."""
    sos = np.ascontiguousarray(sos, dtype=np.float64)
    return _decay_margin(sos.tobytes(), len(sos), float(tolerance))


@lru_cache(maxsize=64)
def _decay_margin(sos_bytes: bytes, sections: int, tolerance: float) -> int:
    sos = np.frombuffer(sos_bytes, dtype=np.float64).reshape(sections, 6)
    radius = _pole_radius(sos)
    if radius == 0:
        return len(sos) * 2
    states = 4 * len(sos)
    history = np.zeros((len(sos), 4, states))
    for j in range(states):
        history[j // 4, j % 4, j] = 1.0
    length = math.ceil(math.log(tolerance) / math.log(radius)) + 64
    while True:
        h, _ = sosfilt(sos, np.zeros((length, states)), history)
        above = np.flatnonzero(np.abs(h).sum(axis=1) > tolerance)
        last = int(above[-1]) + 1 if len(above) else 0
        if last < length * 3 // 4:  # the tail of the simulation is well below: settled
            return last
        length *= 2


class StreamingLowPass(SegmentedStage):
    """The low-pass filter, pushed in chunks of any size (mode from ``lowpass.causal``).

    ``push(stamp_ns, values)`` takes int64 ns stamps (n,) and values (n,) or (n, channels) and
    returns the filtered values of the oldest samples not emitted yet, in order; ``finish()``
    returns the rest.

    Causal: every sample is emitted at once and chunked runs equal one run exactly (the final
    state of a push is the initial state of the next), but for a segment's first ``warmup``
    samples: the filter starts at rest on the sample after them (what feeds it before is not
    trusted: a causal derivative's first samples have no window), they wait for it and come out
    as that rest value (``lookahead`` = ``warmup``). Zero-phase:
    ``lookahead`` = ``margin`` samples; a sample is emitted once ``margin`` later samples of its
    segment are known, or its segment has ended; the result equals the forward-backward pass
    over each segment with ``padlen`` samples of odd extension pivoted on ``end_value`` at both
    ends, to ~1e-12 of the signal's range.
    ``buffered`` never exceeds ``margin`` + 1 samples.
    """

    def __init__(
        self,
        lowpass: LowPass,
        period_s: float,
        gap_factor: float = DEFAULT_GAP_FACTOR,
        warmup: int = 0,
    ) -> None:
        super().__init__(period_s, gap_factor)
        self.lowpass = lowpass
        self.causal = lowpass.causal
        # causal: the segment's first ``warmup`` samples wait for the one the filter starts on
        self.warmup = int(warmup) if self.causal else 0
        fs = 1.0 / self.period_s
        self.sos = lowpass.sos(fs)
        self.padlen = lowpass.padlen(fs)
        self.margin = 0 if self.causal else max(decay_margin(self.sos), self.padlen)
        self.lookahead = self.margin or self.warmup
        self._block = max(_BLOCK, self.margin)
        self._reset()

    def _reset(self) -> None:
        self._n = 0  # samples of the current segment seen
        self._base = 0  # segment index of the buffers' first sample
        self._next = 0  # segment index of the next sample to emit
        self._x = np.zeros((0, max(self._width, 1)))  # raw values (zero-phase)
        self._yf: FloatArray | None = None  # forward-pass output, aligned with _x
        self._zf: FloatArray | None = None  # forward history after the last sample seen
        self._pad = 0  # the segment's pad length, once known

    @property
    def buffered(self) -> int:
        """Samples held in the internal buffers (at most ``margin`` + 1)."""
        return len(self._x) if self._yf is None else len(self._yf)

    def _steady(self, value: FloatArray) -> FloatArray:
        """Filter state at rest on ``value`` (one per channel)."""
        return rest_state(self.sos, value)

    def _filter(self, x: FloatArray, state: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The recursion over ``x`` in row chunks (the same bits as one call, see ``sosfilt``)."""
        rows = self._chunk_rows(x)
        if len(x) <= rows:
            return sosfilt(self.sos, x, state)
        out = np.empty(x.shape)
        for c in range(0, len(x), rows):
            out[c : c + rows], state = sosfilt(self.sos, x[c : c + rows], state)
        return out, state

    def _settle(self, x: FloatArray, state: FloatArray) -> FloatArray:
        """The state after filtering ``x``, without keeping its output."""
        rows = self._chunk_rows(x)
        for c in range(0, len(x), rows):
            _, state = sosfilt(self.sos, x[c : c + rows], state)
        return state

    @staticmethod
    def _chunk_rows(x: FloatArray) -> int:
        return max(1024, _CHUNK_VALUES // max(1, x.shape[1] if x.ndim > 1 else 1))

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        if self.causal:
            self._n += len(y)
            if self._zf is not None:
                out, self._zf = self._filter(y, self._zf)
                return out
            # the warm-up: samples wait for the one the filter starts at rest on
            self._x = np.concatenate((self._x, y)) if len(self._x) else y.copy()
            if self._n <= self.warmup:
                return np.zeros((0, y.shape[1]))
            return self._start_causal(self.warmup)
        # a copy either way: the buffer must not alias the caller's array; once the forward
        # pass runs, only the last padlen + 1 raw values are kept (the end extension's)
        tail = y if self._zf is None else y[-(self.padlen + 1) :]
        self._x = np.concatenate((self._x, tail)) if self._n else tail.copy()
        self._n += len(y)
        if self._zf is None:
            if self._n > self.padlen:  # the segment is long enough for the full pad
                self._start_forward(self.padlen)
        else:
            assert self._yf is not None
            yf, self._zf = self._filter(y, self._zf)
            self._yf = np.concatenate((self._yf, yf))
        out = self._emit_ready()
        self._trim()
        return out

    def _start_forward(self, pad: int) -> None:
        """Forward pass from the odd extension before the segment's start, as sosfiltfilt but
        pivoted on ``end_value`` of the samples it reflects."""
        assert self._base == 0
        x = self._x
        self._pad = pad
        left = 2 * end_value(x[: pad + 1]) - x[pad:0:-1]
        _, zf = self._filter(left, self._steady(left[0]))
        self._yf, self._zf = self._filter(x, zf)

    def _emit_ready(self) -> FloatArray:
        """Samples with ``margin`` later samples known, by backward passes over blocks."""
        if self._zf is None:
            return np.zeros((0, self._x.shape[1]))
        stop = self._n - self.margin
        parts = []
        while self._next < stop:
            end = min(self._next + self._block, stop)
            parts.append(self._backward(self._next, end, end - 1 + self.margin))
            self._next = end
        return np.concatenate(parts) if parts else np.zeros((0, self._x.shape[1]))

    def _backward(self, a: int, b: int, start: int) -> FloatArray:
        """Backward pass from segment sample ``start`` (in steady state) down to ``a``; the
        outputs for [a, b) are those at least ``margin`` samples from the start."""
        assert self._yf is not None
        seg = self._yf[a - self._base : start + 1 - self._base]
        kept = b - a  # the run-in over the rest only settles the state: its output is dropped
        state = self._settle(seg[: kept - 1 : -1], self._steady(seg[-1]))
        yb, _ = self._filter(seg[kept - 1 :: -1], state)
        out: FloatArray = yb[::-1]
        return out

    def _trim(self) -> None:
        if self._zf is None:
            return  # everything is needed until the forward pass starts (≤ padlen samples)
        keep = max(self._base, min(self._next, self._n - (self.padlen + 1)))
        assert self._yf is not None
        # copies: the buffers must not alias the caller's arrays; of the raw values only the
        # end extension's are needed once the forward pass has started
        self._x = self._x[-(self.padlen + 1) :].copy()
        self._yf = self._yf[keep - self._base :].copy()
        self._base = keep

    def _start_causal(self, at: int) -> FloatArray:
        """Start at rest on buffered sample ``at``: the samples before it come out as the rest
        value (what the filter holds before its start), the rest filtered from there."""
        x = self._x
        self._zf = self._steady(x[at])
        head = np.repeat(self._filter(x[at : at + 1], self._zf)[0], at, axis=0)
        out, self._zf = self._filter(x[at:], self._zf)
        self._x = np.zeros((0, x.shape[1]))
        return np.concatenate((head, out))

    def _end_segment(self) -> FloatArray:
        width = self._x.shape[1]
        if self.causal and self._zf is None and len(self._x):  # ended during the warm-up
            warm = self._start_causal(len(self._x) - 1)
            self._reset()
            return warm
        if self.causal or self._n == 0:
            self._reset()
            return np.zeros((0, max(self._width, 1)))
        if self._zf is None:
            if self._n == 1:  # nothing to filter
                lone: FloatArray = self._x.copy()
                self._reset()
                return lone
            self._start_forward(min(self.padlen, self._n - 1))
        assert self._yf is not None and self._zf is not None
        # the true end extension (pivoted on end_value), then the backward pass from its end
        x, pad = self._x, self._pad
        right = 2 * end_value(x[: -(pad + 2) : -1]) - x[-2 : -(pad + 2) : -1]
        yr, _ = self._filter(right, self._zf)
        tail = np.concatenate((self._yf[self._next - self._base :], yr))
        yb, _ = self._filter(tail[::-1], self._steady(tail[-1]))
        out: FloatArray = yb[::-1][: self._n - self._next]
        self._reset()
        return out if len(out) else np.zeros((0, width))
