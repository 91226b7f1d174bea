"""twincd.evaluation.metrics against scikit-learn on small arrays (DESIGN §6)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import f1_score, precision_score, recall_score, roc_auc_score

from twincd.evaluation.metrics import SWEEP_K, at_threshold, auc, best_of, f1_sweep

Y = np.array([0, 0, 1, 1, 0, 1, 0, 1, 1, 0], dtype=bool)
S = np.array([0.1, 0.4, 0.35, 0.8, 0.2, 0.9, 0.7, 0.3, 0.95, 0.05])


def test_sweep_is_the_papers():
    assert SWEEP_K == (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 2.0, 3.0, 4.0, 5.0)


@pytest.mark.parametrize("threshold", [0.0, 0.3, 0.35, 0.5, 0.9, 2.0])
def test_at_threshold_matches_sklearn(threshold):
    pred = threshold <= S
    got = at_threshold(Y, S, threshold)
    assert got.f1 == pytest.approx(f1_score(Y, pred, zero_division=0))
    assert got.precision == pytest.approx(precision_score(Y, pred, zero_division=0))
    assert got.recall == pytest.approx(recall_score(Y, pred, zero_division=0))


def test_flag_is_score_at_or_above_threshold():
    # eq. 7: score ≥ thres is a collision
    assert at_threshold(np.array([True]), np.array([0.5]), 0.5).recall == 1.0


def test_sweep_and_best():
    mu, sigma = 0.3, 0.2
    sweep = f1_sweep(Y, S, mu, sigma)
    assert [k for k, _ in sweep] == list(SWEEP_K)
    for k, f in sweep:
        assert f == pytest.approx(f1_score(Y, mu + k * sigma <= S, zero_division=0))
    k, f = best_of(sweep)
    assert f == max(f for _, f in sweep)
    assert best_of([(0.0, 0.5), (0.1, 0.7), (0.2, 0.7)]) == (0.1, 0.7)  # ties: smallest i


def test_auc_matches_sklearn_and_is_none_for_one_class():
    assert auc(Y, S) == pytest.approx(roc_auc_score(Y, S))
    assert auc(np.zeros(4, dtype=bool), np.arange(4.0)) is None
    assert auc(np.ones(4, dtype=bool), np.arange(4.0)) is None
