"""A segment's ends are judged like its middle, with the noise their filtering leaves there.

A filter started at a segment's first sample (causal: at rest on it; zero-phase: from the odd
extension pivoted on ``end_value``, and the backward pass likewise at the segment's end) sees
one side of the data only near an end: its output there is a noisier estimate than in the middle
of the segment. Leaving those samples out (the rule before this one: the filter's settling time
at each end, 1.6 s of a 3.7 s segment at the paper's 1 Hz) blinds short logs; judging them with
the middle's noise scale raises alarms at every end. So each sample is judged with its own
noise scale: the middle's times the **edge factor** f(k) ≥ 1 of its distance k from the
segment's start and end.

The filters are linear, so f is exact for white noise and computed once per filter and rate:
unit impulses at every position of a segment long enough that its two ends do not interact go
through the very stage that filters the logs (``StreamingLowPass``), and f(k)² is the output's
energy at position k over the energy in the middle (for a band, the difference of two low-passes,
the impulses go through both). Near a zero-phase end f is about 2.3 at the end sample and within
``FACTOR_TOLERANCE`` of 1 after the filter's settling time; a causal start at rest on its first
sample gives about 3.7 (3 Hz) for as long. Where both ends of a short segment are near, their
excess variances add. Computed at the period the filter runs at (the grid's, on a coarse grid)
and applied by time, so a 1 kHz sample gets the factor of its time from the ends.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from twincd.signal.bands import Band
from twincd.signal.filters import decay_margin, settling_samples
from twincd.signal.stream import DEFAULT_GAP_FACTOR, SegmentedStage
from twincd.types import FloatArray, IntArray

__all__ = ["FACTOR_TOLERANCE", "EdgeFactors", "EdgeProfile", "edge_profile"]

# beyond the last position where the factor is above 1 + this, it is 1
FACTOR_TOLERANCE = 1e-3
# impulses filtered per pass when measuring a profile (memory: this × the probe's length)
_IMPULSES = 512


@dataclass(frozen=True)
class EdgeProfile:
    """The edge factor at each distance from a segment's start (``start[k]``: k periods after
    its first sample) and from its end (``end[k]``: k periods before its last; empty for a
    causal operator, whose end is like its middle), both ≥ 1 and 1 beyond their length."""

    start: FloatArray
    end: FloatArray
    period_s: float

    @property
    def span_s(self) -> float:
        """How long after a start or before an end the factor is above 1."""
        return max(len(self.start), len(self.end)) * self.period_s

    def factors(self, since_start_s: FloatArray, until_end_s: FloatArray | None) -> FloatArray:
        """The factor of samples at these times from their segment's start and (None: not
        known to be near) its end: linear in time between the profile's positions; the excess
        variances of both ends add."""
        excess = _excess(self.start, since_start_s / self.period_s)
        if until_end_s is not None and len(self.end):
            excess = excess + _excess(self.end, until_end_s / self.period_s)
        out: FloatArray = np.sqrt(1.0 + excess)
        return out


def _excess(profile: FloatArray, position: FloatArray) -> FloatArray:
    """f² − 1 of ``profile`` at fractional ``position``s (0 beyond the profile)."""
    if not len(profile):
        return np.zeros(len(position))
    excess = profile * profile - 1.0
    grid = np.arange(len(profile), dtype=np.float64)
    out: FloatArray = np.interp(position, grid, excess, right=0.0)
    return out


def edge_profile(band: Band, period_s: float, warmup: int = 0) -> EdgeProfile:
    """The edge factors of ``band`` on samples every ``period_s``, its causal filters started
    after ``warmup`` samples (``StreamingLowPass``; cached)."""
    return _profile(band, float(period_s), int(warmup))


@lru_cache(maxsize=64)
def _profile(band: Band, period_s: float, warmup: int) -> EdgeProfile:
    fs = 1.0 / period_s
    settle = max(settling_samples(lp.sos(fs)) for lp in band.filters)
    reach = max(max(decay_margin(lp.sos(fs)), lp.padlen(fs)) for lp in band.filters)
    # long enough that its middle sees neither end: both ends' settling and reach, and more
    length = 2 * (settle + reach + warmup) + 64
    energy = np.zeros(length)
    stamps = np.round(np.arange(length) * period_s * 1e9).astype(np.int64)
    for first in range(0, length, _IMPULSES):
        at = np.arange(first, min(length, first + _IMPULSES))
        impulses = np.zeros((length, len(at)))
        impulses[at, np.arange(len(at))] = 1.0
        out = band.apply(stamps, impulses, period_s, warmup)
        energy += np.einsum("ij,ij->i", out, out)
    factor = np.sqrt(np.maximum(energy / energy[length // 2], 1.0))
    causal = all(lp.causal for lp in band.filters)
    half = length // 2
    return EdgeProfile(
        _trimmed(factor[:half]),
        np.zeros(0) if causal else _trimmed(factor[::-1][:half]),
        period_s,
    )


def _trimmed(factor: FloatArray) -> FloatArray:
    """The profile up to its last position above 1 + ``FACTOR_TOLERANCE``."""
    above = np.flatnonzero(factor > 1.0 + FACTOR_TOLERANCE)
    out: FloatArray = factor[: int(above[-1]) + 1] if len(above) else factor[:0]
    out.setflags(write=False)
    return out


class EdgeFactors(SegmentedStage):
    """Per sample, the edge factor of each of ``profiles`` (one column each) from its time since
    its segment's first sample and, while within a profile's end span, until its last (segments
    cut at gaps as every stage cuts). A sample is emitted once the samples of the next
    ``lookahead_s`` are known or its segment has ended: at once when no profile has an end."""

    def __init__(
        self,
        profiles: Sequence[EdgeProfile],
        period_s: float,
        gap_factor: float = DEFAULT_GAP_FACTOR,
    ) -> None:
        super().__init__(period_s, gap_factor)
        self.profiles = tuple(profiles)
        reach = max((len(p.end) * p.period_s for p in self.profiles), default=0.0)
        self.reach_ns = math.ceil(reach * 1e9)
        # samples held for the end: enough that those emitted are past every end span
        self.lookahead = math.ceil(reach / self.period_s) + 1 if reach else 0
        self._t = np.zeros(0, dtype=np.int64)  # stamps of the segment not emitted yet
        self._first: int | None = None  # the segment's first stamp

    def _shape(self, parts: list[FloatArray]) -> FloatArray:
        """One column per profile, whatever the values pushed (the stamps)."""
        parts = [p for p in parts if len(p)]
        empty = np.zeros((0, len(self.profiles)))
        out = np.ascontiguousarray(np.concatenate(parts)) if parts else empty
        self.emitted += len(out)
        return out

    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray:
        if self._first is None:
            self._first = int(t[0])
        self._t = np.concatenate((self._t, t))
        if not self.reach_ns:  # no end span: every sample is ready
            return self._emit(len(self._t), None)
        # a held sample more than the end span before the newest one is not near the end
        ready = int(np.searchsorted(self._t, int(self._t[-1]) - self.reach_ns, side="left"))
        return self._emit(ready, None)

    def _end_segment(self) -> FloatArray:
        held = len(self._t)
        out = self._emit(held, int(self._t[-1])) if held else np.zeros((0, len(self.profiles)))
        self._first = None
        return out

    def _emit(self, k: int, last: int | None) -> FloatArray:
        t, self._t = self._t[:k], self._t[k:]
        assert self._first is not None
        since = (t - self._first).astype(np.float64) * 1e-9
        until = None if last is None else (last - t).astype(np.float64) * 1e-9
        columns = [p.factors(since, until) for p in self.profiles]
        return np.column_stack(columns) if columns else np.zeros((k, 0))


def edge_scaled(residual: FloatArray, factor: FloatArray | None, band: int = 0) -> FloatArray:
    """``residual`` (N, joints) with each row divided by its edge factor in ``band`` (a column of
    the chain's (N, bands) ``edge_factor``; None: no edges, as is): what scoring weighs, so that
    a segment's ends are judged with the noise their filtering leaves there."""
    if factor is None:
        return residual
    f = np.asarray(factor, dtype=np.float64).reshape(len(residual), -1)[:, band]
    out: FloatArray = residual / f[:, None]
    return out
