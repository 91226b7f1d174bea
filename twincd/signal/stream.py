"""Time, gaps and the push/finish machinery shared by the streaming signal stages.

Time is int64 nanoseconds (absolute header stamps). Intervals are taken in integer ns before
they become float seconds, so a result never depends on where a chunk starts. The sampling
period is given (the calibration's, or ``nominal_period`` of a log's first samples), never
estimated from a whole log; a gap is an interval longer than ``gap_factor`` × the period, and
every stage restarts after one, so the derivative and the filter cut at the same places.
"""

from __future__ import annotations

import itertools
import math
from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import ArrayLike

from twincd.errors import DataError, UsageError
from twincd.types import FloatArray, IntArray

DEFAULT_GAP_FACTOR = 5.0
# intervals looked at by nominal_period: enough for a stable median, cheap on hour-long logs
PERIOD_INTERVALS = 1000
# samples handed to a stage at a time, however many are pushed at once
PUSH_BLOCK = 65536


def seconds_to_ns(t_s: ArrayLike) -> IntArray:
    """Float seconds → int64 ns since the first sample (for the whole-log wrappers)."""
    t = np.asarray(t_s, dtype=np.float64)
    if len(t) == 0:
        return np.zeros(0, dtype=np.int64)
    ns: IntArray = np.rint((t - t[0]) * 1e9).astype(np.int64)
    return ns


def nominal_period(stamp_ns: ArrayLike, source: str = "") -> float:
    """Nominal sampling period in seconds: the median of the first min(n − 1, 1000) positive
    intervals of ``stamp_ns`` (int ns). Robust to jitter, duplicates and a few gaps."""
    stamps = np.asarray(stamp_ns).astype(np.int64, copy=False)
    if stamps.ndim != 1:
        raise UsageError("stamps must be one-dimensional", source, "pass one stamp per sample")
    # look at a growing head of the log only: duplicates may hide the positive intervals
    head = PERIOD_INTERVALS + 1
    while True:
        dt = np.diff(stamps[:head])
        positive = dt[dt > 0][:PERIOD_INTERVALS]
        if len(positive) >= PERIOD_INTERVALS or head >= len(stamps):
            break
        head *= 4
    if len(positive) == 0:
        raise DataError(
            "log too short to filter: fewer than two distinct stamps give no sampling period",
            source,
            "record more samples",
        )
    return float(np.median(positive)) * 1e-9


def check_period(period_s: float, gap_factor: float) -> None:
    """UsageError unless the period and the gap factor are finite and positive."""
    if not (math.isfinite(period_s) and period_s > 0):
        raise UsageError(
            f"sampling period {period_s!r} s is not a positive number",
            "signal stage",
            "give the nominal period in seconds (see nominal_period)",
        )
    if not (math.isfinite(gap_factor) and gap_factor > 0):
        raise UsageError(
            f"gap factor {gap_factor!r} is not a positive number",
            "signal stage",
            "use a gap factor above 1 (default 5)",
        )


class Segmenter:
    """Cuts a stream of stamps into gap-free segments, chunk by chunk.

    A gap is an interval longer than ``gap_factor × period_s`` (compared in integer ns), so
    the cuts depend only on neighbouring stamps, never on how the stream is chunked.
    Intervals that are zero or negative are not gaps.
    """

    def __init__(self, period_s: float, gap_factor: float = DEFAULT_GAP_FACTOR) -> None:
        check_period(period_s, gap_factor)
        self.period_s = float(period_s)
        self.gap_factor = float(gap_factor)
        self.gap_ns = self.gap_factor * self.period_s * 1e9
        self._last: int | None = None

    def starts(self, stamp_ns: IntArray) -> IntArray:
        """Positions in this chunk where a new segment begins (0 when the chunk's first sample is
        the stream's first or follows a gap)."""
        n = len(stamp_ns)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        if self._last is None:
            first_new = True
        else:
            first_new = float(int(stamp_ns[0]) - self._last) > self.gap_ns
        self._last = int(stamp_ns[-1])
        # int64 → float64 is exact for intervals below 2^53 ns (104 days)
        cuts = np.flatnonzero(np.diff(stamp_ns).astype(np.float64) > self.gap_ns) + 1
        if first_new:
            cuts = np.concatenate((np.zeros(1, dtype=np.int64), cuts))
        out: IntArray = cuts.astype(np.int64)
        return out

    def reset(self) -> None:
        """Forget the last stamp: the next chunk starts a new segment."""
        self._last = None


def segment_bounds(
    t_s: ArrayLike, gap_factor: float = DEFAULT_GAP_FACTOR, period_s: float | None = None
) -> list[tuple[int, int]]:
    """[start, stop) index ranges of the gap-free segments of times ``t_s`` (seconds), by the
    rule the streaming stages use; ``period_s`` None → ``nominal_period`` of these times."""
    ns = seconds_to_ns(t_s)
    n = len(ns)
    if n < 2:
        return [(0, n)] if n else []
    segmenter = Segmenter(period_s or nominal_period(ns), gap_factor)
    edges = [*segmenter.starts(ns).tolist(), n]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


class SegmentedStage(ABC):
    """Base of the streaming stages: checks and shapes pushes and splits them at gaps.

    Subclasses implement ``_extend`` (samples of the current segment arrive; return the outputs
    now ready, (k, channels)) and ``_end_segment`` (the segment is over; return the rest).
    Outputs always come for the oldest samples not emitted yet, in order.
    """

    def __init__(self, period_s: float, gap_factor: float = DEFAULT_GAP_FACTOR) -> None:
        self._segmenter = Segmenter(period_s, gap_factor)
        self.period_s = self._segmenter.period_s
        self.gap_factor = self._segmenter.gap_factor
        self._flat: bool | None = None
        self._width = 0
        self.pushed = 0
        self.emitted = 0

    @property
    def pending(self) -> int:
        """Samples pushed but not emitted yet."""
        return self.pushed - self.emitted

    def push(self, stamp_ns: ArrayLike, values: ArrayLike) -> FloatArray:
        """Take samples (stamps (n,) int ns; values (n,) or (n, channels)); return the outputs
        that are ready, for the oldest samples not emitted yet, in order."""
        t, y = self._check(stamp_ns, values)
        parts: list[FloatArray] = []
        starts = set(self._segmenter.starts(t).tolist())
        edges = sorted({0, len(t), *starts})
        for a, b in itertools.pairwise(edges):
            if a in starts:
                parts.append(self._end_segment())
            # big pushes go in blocks: working memory stays bounded by the block, not the push
            for c in range(a, b, PUSH_BLOCK):
                d = min(c + PUSH_BLOCK, b)
                parts.append(self._extend(t[c:d], y[c:d]))
        self.pushed += len(t)
        return self._shape(parts)

    def finish(self) -> FloatArray:
        """End of the stream: the outputs of every sample still held. The stage may then take
        a new stream (its first sample starts a new segment)."""
        out = self._shape([self._end_segment()])
        self._segmenter.reset()
        return out

    def _check(self, stamp_ns: ArrayLike, values: ArrayLike) -> tuple[IntArray, FloatArray]:
        t = np.asarray(stamp_ns)
        if t.ndim != 1 or not (np.issubdtype(t.dtype, np.integer) or len(t) == 0):
            raise UsageError(
                "stamps must be a one-dimensional array of integer nanoseconds",
                f"got {t.dtype} of shape {t.shape}",
                "pass header stamps as int64 ns",
            )
        y = np.asarray(values, dtype=np.float64)
        if y.ndim not in (1, 2) or len(y) != len(t):
            raise UsageError(
                "values must be (n,) or (n, channels) with one row per stamp",
                f"{len(t)} stamps, values of shape {y.shape}",
                "pass as many rows as stamps",
            )
        flat = y.ndim == 1
        y2 = y[:, None] if flat else y
        if self._flat is None:
            if len(t):  # an empty push does not fix the shape
                self._flat, self._width = flat, y2.shape[1]
        elif flat != self._flat or y2.shape[1] != self._width:
            raise UsageError(
                "values changed shape between pushes",
                f"{y.shape[1:]} after {'()' if self._flat else (self._width,)}",
                "push the same channels every time",
            )
        return t.astype(np.int64, copy=False), y2

    def _shape(self, parts: list[FloatArray]) -> FloatArray:
        parts = [p for p in parts if len(p)]
        width = max(self._width, 1)
        # always C order: scipy hands back column-major blocks, and a layout that changed with
        # the chunking would change the summation order of reductions downstream
        out = np.ascontiguousarray(np.concatenate(parts)) if parts else np.zeros((0, width))
        self.emitted += len(out)
        if self._flat or self._flat is None:
            flat: FloatArray = out[:, 0]
            return flat
        return out

    @abstractmethod
    def _extend(self, t: IntArray, y: FloatArray) -> FloatArray: ...

    @abstractmethod
    def _end_segment(self) -> FloatArray: ...


def run_whole(stage: SegmentedStage, stamp_ns: IntArray, values: FloatArray) -> FloatArray:
    """One push of everything, then finish: the whole-log result of a streaming stage."""
    head = stage.push(stamp_ns, values)
    tail = stage.finish()
    out: FloatArray = np.concatenate((head, tail))
    return out
