"""Long signals downsampled for drawing, streamed at bounded memory: per column the minimum and
the maximum, so that no spike vanishes however long the log (a one-sample spike stays the
maximum of its column)."""

from __future__ import annotations

import numpy as np

from twincd.types import FloatArray, IntArray


class Envelope:
    """Min/max per column of samples pushed block by block, never more than ``2·columns``
    columns: when full, neighbouring columns merge pairwise and each column then spans twice
    as many samples. Memory is O(columns · channels) whatever the log length; the state is a
    few numpy arrays, so it pickles small (it travels back from worker processes).

    Non-finite values are ignored (a column with none finite holds NaN)."""

    def __init__(self, channels: int, columns: int = 1000) -> None:
        if columns < 1 or channels < 1:
            raise ValueError("an envelope needs at least one column and one channel")
        self.channels = channels
        self.columns = columns
        self.span = 1  # samples per column
        self.samples = 0
        cap = 2 * columns
        self._t = np.zeros(cap, dtype=np.int64)  # time of each column's first sample
        self._lo = np.full((cap, channels), np.inf)
        self._hi = np.full((cap, channels), -np.inf)
        self._used = 0  # columns started (the last one may be partly filled)

    def push(self, t: IntArray, values: FloatArray) -> None:
        """Add samples: ``t`` (n,) times, ``values`` (n, channels)."""
        values = np.asarray(values, dtype=np.float64).reshape(len(t), self.channels)
        t = np.asarray(t, dtype=np.int64)
        start = 0
        while start < len(t):
            if self.samples == len(self._t) * self.span:  # every column full
                self._halve()
            # the samples that still belong to the current run of columns at this span
            room = len(self._t) * self.span - self.samples
            stop = min(len(t), start + room)
            self._add(t[start:stop], values[start:stop])
            start = stop

    def _add(self, t: IntArray, values: FloatArray) -> None:
        index = (self.samples + np.arange(len(t))) // self.span
        # a column's time is that of its first sample, which may have come in an earlier push
        new = (self.samples + np.arange(len(t))) % self.span == 0
        self._t[index[new]] = t[new]
        finite = np.isfinite(values)
        np.minimum.at(self._lo, index, np.where(finite, values, np.inf))
        np.maximum.at(self._hi, index, np.where(finite, values, -np.inf))
        self.samples += len(t)
        self._used = int(index[-1]) + 1 if len(t) else self._used

    def _halve(self) -> None:
        """Merge neighbouring columns pairwise: half the columns, each twice the span."""
        cap = len(self._t)
        self._t[: cap // 2] = self._t[0::2]
        self._lo[: cap // 2] = np.minimum(self._lo[0::2], self._lo[1::2])
        self._hi[: cap // 2] = np.maximum(self._hi[0::2], self._hi[1::2])
        self._lo[cap // 2 :] = np.inf
        self._hi[cap // 2 :] = -np.inf
        self._used = cap // 2
        self.span *= 2

    @property
    def t(self) -> IntArray:
        """Time of each column's first sample."""
        t: IntArray = self._t[: self._used].copy()
        return t

    @property
    def low(self) -> FloatArray:
        """(columns, channels) minima; NaN where a column had no finite value."""
        lo = self._lo[: self._used]
        return np.where(np.isfinite(lo), lo, np.nan)

    @property
    def high(self) -> FloatArray:
        hi = self._hi[: self._used]
        return np.where(np.isfinite(hi), hi, np.nan)

    def __getstate__(self) -> dict[str, object]:
        # only the columns in use: the spare capacity stays behind
        state = dict(self.__dict__)
        state["_t"] = self._t[: self._used].copy()
        state["_lo"] = self._lo[: self._used].copy()
        state["_hi"] = self._hi[: self._used].copy()
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        cap = 2 * self.columns
        used = self._used
        t = np.zeros(cap, dtype=np.int64)
        lo = np.full((cap, self.channels), np.inf)
        hi = np.full((cap, self.channels), -np.inf)
        t[:used], lo[:used], hi[:used] = self._t, self._lo, self._hi
        self._t, self._lo, self._hi = t, lo, hi

    def line(self, channel: int) -> tuple[FloatArray, FloatArray]:
        """(x, y) to draw one channel as a line through each column's min and max: two points
        per column at its start time, so a spike shows as a vertical stroke."""
        x = np.repeat(self.t.astype(np.float64), 2)
        y = np.empty(2 * self._used)
        y[0::2] = self.low[:, channel]
        y[1::2] = self.high[:, channel]
        return x, y
