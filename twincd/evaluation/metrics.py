"""The seed paper's evaluation metrics (section IV-C, DESIGN §6), on scikit-learn's metrics.

Per unit (sample or window) over all evaluated logs together: F1 at μ + iσ for the paper's
sweep of i, precision/recall/F1 at one threshold, and the ROC AUC of the raw score.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from sklearn.metrics import precision_recall_fscore_support, roc_auc_score

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

# i = 0, 0.1, …, 1.0, then 2, 3, 4, 5 (rounded so that keys read 0.3, not 0.30000000000000004)
SWEEP_K: tuple[float, ...] = (*(round(0.1 * i, 1) for i in range(11)), 2.0, 3.0, 4.0, 5.0)


@dataclass(frozen=True)
class AtThreshold:
    threshold: float
    precision: float
    recall: float
    f1: float


def at_threshold(labels: BoolArray, scores: FloatArray, threshold: float) -> AtThreshold:
    """Precision, recall and F1 of the flags score ≥ threshold (eq. 7)."""
    pred = np.asarray(scores) >= threshold
    p, r, f, _ = precision_recall_fscore_support(
        np.asarray(labels, dtype=bool), pred, average="binary", zero_division=0
    )
    return AtThreshold(float(threshold), float(p), float(r), float(f))


def f1_sweep(
    labels: BoolArray, scores: FloatArray, mu: float, sigma: float, ks: Sequence[float] = SWEEP_K
) -> list[tuple[float, float]]:
    """(i, F1 at μ + iσ) for every i of the sweep."""
    return [(float(k), at_threshold(labels, scores, mu + k * sigma).f1) for k in ks]


def best_of(sweep: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """(i, F1) of the best F1; ties go to the smallest i."""
    best = max(sweep, key=lambda kf: kf[1])
    return best


def auc(labels: BoolArray, scores: FloatArray) -> float | None:
    """ROC AUC of the raw score; None when only one class is present (it is undefined)."""
    y = np.asarray(labels, dtype=bool)
    if y.all() or not y.any():
        return None
    return float(roc_auc_score(y, np.asarray(scores, dtype=np.float64)))


def roc_points(labels: BoolArray, scores: FloatArray, most: int = 300) -> list[tuple[float, float]]:
    """(false positive rate, true positive rate) of the ROC curve, at most ``most`` points
    (evenly thinned, ends kept) so that results stay small; empty when AUC is undefined."""
    from sklearn.metrics import roc_curve

    y = np.asarray(labels, dtype=bool)
    if y.all() or not y.any():
        return []
    fpr, tpr, _ = roc_curve(y, np.asarray(scores, dtype=np.float64))
    if len(fpr) > most:
        keep = np.unique(np.linspace(0, len(fpr) - 1, most).round().astype(int))
        fpr, tpr = fpr[keep], tpr[keep]
    return [(float(f), float(t)) for f, t in zip(fpr, tpr, strict=True)]
