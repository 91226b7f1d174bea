"""Learning baselines without PyTorch: OCSVM per sample and per window, the shared min–max
scaler and windows, and the deep methods' skip without PyTorch."""

from __future__ import annotations

import sys
from functools import lru_cache

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score
from test_baselines_mob import make_log, pushed_log

from twincd.errors import NotFittedError
from twincd.evaluation.baselines.mob import mob_tau_ext
from twincd.evaluation.baselines.ocsvm import PointOcsvm, WindowOcsvm
from twincd.evaluation.baselines.windows import (
    MinMaxScaler,
    subsample,
    window_labels,
    window_starts,
    windows,
)
from twincd.evaluation.methods import MethodSkipped, ScoringMethod, make_method
from twincd.prepare.prepared import PreparedLog


@lru_cache(maxsize=1)
def data() -> tuple[list[PreparedLog], PreparedLog]:
    train = [pushed_log(10 + i, seconds=10.0) for i in range(3)]
    return train, pushed_log(20, seconds=16.0, pushes=4)


def auc(method: ScoringMethod, log: PreparedLog) -> float:
    score = method.score(log)
    labels = method.unit_labels(log)
    assert score.shape == labels.shape
    return float(roc_auc_score(labels, score))


# ------------------------------------------------------------------ scaler and windows


def test_minmax_scaler_uses_training_range_only() -> None:
    train = np.array([[0.0, 5.0, 1.0], [2.0, 7.0, 1.0]])
    scaler = MinMaxScaler().fit(train)
    np.testing.assert_allclose(scaler.transform(train), [[0, 0, 0], [1, 1, 0]])
    test = np.array([[4.0, 3.0, 2.0]])
    np.testing.assert_allclose(scaler.transform(test), [[2.0, -1.0, 1.0]])  # not clipped
    np.testing.assert_allclose(scaler.inverse_transform(scaler.transform(test)), test)
    np.testing.assert_array_equal(scaler.min_, [0.0, 5.0, 1.0])  # unchanged by test data
    with pytest.raises(NotFittedError):
        MinMaxScaler().transform(test)


def test_windows_stay_inside_gap_free_segments() -> None:
    t = np.concatenate([np.arange(40) * 0.01, 1.0 + np.arange(20) * 0.01])  # gap at 40
    starts = window_starts(t, size=16, stride=16)
    np.testing.assert_array_equal(starts, [0, 16, 40])
    np.testing.assert_array_equal(window_starts(t, 16, 8), [0, 8, 16, 24, 40])
    x = np.arange(60 * 2, dtype=float).reshape(60, 2)
    w = windows(x, starts, 16)
    assert w.shape == (3, 32)
    np.testing.assert_array_equal(w[2, :4], [80, 81, 82, 83])  # time-major: t0 joints, t1 …
    labels = np.zeros(60, dtype=bool)
    labels[31] = True  # last sample of window 2
    np.testing.assert_array_equal(window_labels(labels, 60, starts, 16), [False, True, False])


def test_subsample_is_seeded() -> None:
    assert subsample(10, None, 0) is None and subsample(10, 10, 0) is None
    a, b = subsample(1000, 50, 3), subsample(1000, 50, 3)
    assert a is not None and b is not None and len(a) == 50
    np.testing.assert_array_equal(a, b)
    assert (np.diff(a) > 0).all()


# ------------------------------------------------------------------ OCSVM


@pytest.mark.parametrize("name", ["point-ocsvm", "window-ocsvm"])
def test_ocsvm_scores_pushes_higher(name: str) -> None:
    train, test = data()
    method = make_method(name)
    assert isinstance(method, PointOcsvm | WindowOcsvm) and method.learns
    with pytest.raises(NotFittedError):
        method.score(test)
    method.check([*train, test])
    method.fit(train)
    assert method.note is None
    assert auc(method, test) > 0.8
    if name == "window-ocsvm":
        assert method.unit == "window"
        assert len(method.score(test)) == len(window_starts(test.states.t_s))


def test_normalisation_leaks_nothing_from_test_data() -> None:
    train, test = data()
    method = PointOcsvm().fit(train)
    assert method.scaler_ is not None and method.scaler_.min_ is not None
    features = np.concatenate([mob_tau_ext(log) for log in train])
    np.testing.assert_array_equal(method.scaler_.min_, features.min(axis=0))
    np.testing.assert_allclose(method.scaler_.range_, np.ptp(features, axis=0))
    lo = method.scaler_.min_.copy()
    # a test log far outside the training range changes nothing learned
    wild = make_log(
        test.states.t_s,
        test.states.position,
        test.states.velocity,
        test.effort * 3 + 20,
        test.labels,
        test.robot,
    )
    before = method.score(test)
    method.score(wild)
    np.testing.assert_array_equal(method.scaler_.min_, lo)
    np.testing.assert_array_equal(method.score(test), before)


def test_subsampling_cap_is_reported() -> None:
    train, test = data()
    method = PointOcsvm(max_train=500, subsample_seed=1).fit(train)
    assert method.note is not None and "500 of 3000" in method.note
    again = PointOcsvm(max_train=500, subsample_seed=1).fit(train)
    np.testing.assert_array_equal(method.score(test), again.score(test))


def test_mob_learners_skip_without_robot() -> None:
    train, _ = data()
    log = train[0]
    bare = make_log(log.states.t_s, log.states.position, log.states.velocity, log.effort)
    for name in ("point-ocsvm", "window-ocsvm"):
        with pytest.raises(MethodSkipped, match="robot model"):
            make_method(name).check([bare])


@pytest.mark.parametrize("name", ["point-ae", "window-ae", "lstm-mob"])
def test_deep_methods_skip_without_torch(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch now raises ImportError
    train, _ = data()
    method = make_method(name, seed=0, epochs=1)
    with pytest.raises(MethodSkipped, match=r"needs PyTorch: pip install 'twincd\[baselines\]'"):
        method.check(train)
