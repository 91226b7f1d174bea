"""Shared pieces of the learning baselines: the per-dimension min–max scaler of the paper's
eq. (8), and time windows of samples (Park et al.'s 16-sample windows).

The scaler learns x_min and x_max on training data only; transforming other data never changes
them (values outside the training range map outside [0, 1], as eq. (8) implies).

A window is ``size`` consecutive samples of one gap-free segment of a log (the segments of
``twincd.signal.derivatives.segment_bounds``), flattened time-major into ``size × channels`` inputs:
τ(t−15), …, τ(t) for the paper's size 16. Windows never span a gap. The same start indices
serve the scores and the labels, so both always have one entry per window.
"""

from __future__ import annotations

import numpy as np

from twincd.errors import DataError, NotFittedError
from twincd.signal.derivatives import segment_bounds
from twincd.types import BoolArray, FloatArray, IntArray

WINDOW_SIZE = 16  # paper IV-B 6): 16 samples × 7 joints = 112 inputs

# The learned baselines train on at most this many units (samples, windows, or the LSTM's
# samples): a seeded uniform random subsample when the training logs hold more (the method's
# ``note`` says so). Twice the paper's whole training set (30 paths, about 85 000 samples), so
# the paper's protocol and the shipped sample logs train on everything; long logs (a 20 min
# 1 kHz log holds 1.2 M samples) would otherwise make the deep baselines' epochs, and the
# tensors they copy, grow with the log.
DEFAULT_MAX_TRAIN_UNITS = 200_000
DEFAULT_SUBSAMPLE_SEED = 0  # the subsample's seed: not the method's, so repeats share it


class MinMaxScaler:
    """x ↦ (x − x_min) / (x_max − x_min) per dimension, x_min and x_max from training data only.

    A dimension constant on the training data gets a range of 1 (it is only shifted).
    """

    def __init__(self) -> None:
        self.min_: FloatArray | None = None
        self.range_: FloatArray | None = None

    def fit(self, x: FloatArray) -> MinMaxScaler:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or len(x) == 0:
            raise DataError(
                "no training data to normalise",
                f"shape {x.shape}",
                "give longer training logs",
                option="train",
            )
        if not np.isfinite(x).all():
            raise DataError(
                "training data has NaN or infinite values",
                "min-max normalisation",
                "check the training logs for gaps in effort or velocity",
                option="train",
            )
        lo = x.min(axis=0)
        span = x.max(axis=0) - lo
        self.min_ = lo
        self.range_ = np.where(span > 0, span, 1.0)
        return self

    def transform(self, x: FloatArray) -> FloatArray:
        if self.min_ is None or self.range_ is None:
            raise NotFittedError("min-max scaler used before fit()", "baselines", "call fit()")
        out: FloatArray = (np.asarray(x, dtype=np.float64) - self.min_) / self.range_
        return out

    def inverse_transform(self, x: FloatArray) -> FloatArray:
        if self.min_ is None or self.range_ is None:
            raise NotFittedError("min-max scaler used before fit()", "baselines", "call fit()")
        out: FloatArray = np.asarray(x, dtype=np.float64) * self.range_ + self.min_
        return out


def window_starts(t_s: FloatArray, size: int = WINDOW_SIZE, stride: int = WINDOW_SIZE) -> IntArray:
    """First-sample indices of the windows of one log: every ``stride`` samples within each
    gap-free segment, from the segment's start, whole windows only."""
    if size < 1 or stride < 1:
        raise ValueError("window size and stride must be >= 1")
    starts: list[IntArray] = []
    for a, b in segment_bounds(np.asarray(t_s, dtype=np.float64)):
        if b - a >= size:
            starts.append(np.arange(a, b - size + 1, stride, dtype=np.int64))
    if not starts:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate(starts)


def windows(x: FloatArray, starts: IntArray, size: int = WINDOW_SIZE) -> FloatArray:
    """(len(starts), size × channels): the windows of ``x`` (N, channels), time-major."""
    x = np.asarray(x, dtype=np.float64)
    idx = starts[:, None] + np.arange(size)[None, :]
    out: FloatArray = x[idx].reshape(len(starts), size * x.shape[1])
    return out


def window_labels(labels: BoolArray | None, n: int, starts: IntArray, size: int) -> BoolArray:
    """A window is a collision if any of its samples is labelled (paper IV-B 6)."""
    if labels is None:
        return np.zeros(len(starts), dtype=bool)
    lab = np.asarray(labels, dtype=bool)[:n]
    idx = starts[:, None] + np.arange(size)[None, :]
    out: BoolArray = lab[idx].any(axis=1)
    return out


def subsample(n: int, cap: int | None, seed: int) -> IntArray | None:
    """Sorted indices of a seeded random ``cap`` of ``n`` rows, or None when all fit."""
    if cap is None or n <= cap:
        return None
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n, size=cap, replace=False)).astype(np.int64)
