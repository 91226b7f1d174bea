"""The deep baselines (PyTorch): each trains on tiny logs in seconds and scores pushes higher."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.needs import need
from test_baselines_learning import auc, data
from test_baselines_mob import pushed_log

from twincd.errors import NotFittedError
from twincd.evaluation.baselines.autoencoder import PointAE, WindowAE
from twincd.evaluation.baselines.lstm import LstmMob, training_pieces
from twincd.evaluation.baselines.windows import (
    DEFAULT_MAX_TRAIN_UNITS,
    DEFAULT_SUBSAMPLE_SEED,
)
from twincd.evaluation.methods import make_method

torch = need("torch")

pytestmark = pytest.mark.torch


@pytest.mark.parametrize(("name", "epochs"), [("point-ae", 40), ("window-ae", 40)])
def test_autoencoders_score_pushes_higher(name: str, epochs: int) -> None:
    train, test = data()
    method = make_method(name, seed=0, epochs=epochs)
    assert isinstance(method, PointAE | WindowAE)
    with pytest.raises(NotFittedError):
        method.score(test)
    method.check([*train, test])
    state = torch.random.get_rng_state()
    method.fit(train)
    assert torch.equal(state, torch.random.get_rng_state())  # caller's RNG untouched
    assert len(method.loss_history_) == epochs
    assert method.loss_history_[-1] < method.loss_history_[0]
    assert auc(method, test) > 0.8
    # same seed, same model; another seed, another model
    again = make_method(name, seed=0, epochs=epochs).fit(train)
    np.testing.assert_array_equal(again.score(test), method.score(test))
    other = make_method(name, seed=1, epochs=epochs).fit(train)
    assert not np.array_equal(other.score(test), method.score(test))


def test_autoencoder_layer_sizes() -> None:
    train, _ = data()
    point = PointAE(epochs=1).fit(train)
    window = WindowAE(epochs=1).fit(train)
    sizes = [m.in_features for m in point.net_ if isinstance(m, torch.nn.Linear)]
    assert sizes == [7, 5, 3, 5]
    sizes = [m.out_features for m in window.net_ if isinstance(m, torch.nn.Linear)]
    assert sizes == [32, 11, 32, 112]
    drops = [m.p for m in window.net_ if isinstance(m, torch.nn.Dropout)]
    assert drops == [0.1, 0.1, 0.1]


def test_lstm_mob_learns_the_model_error() -> None:
    train, test = data()
    method = make_method("lstm-mob", seed=0, epochs=15, lr=3e-3)
    assert isinstance(method, LstmMob)
    method.check(train)
    method.fit(train)
    assert method.loss_history_[-1] < method.loss_history_[0]
    pred = method.predict(test)
    assert pred.shape == (len(test), 7)
    score = method.score(test)
    assert score.shape == (len(test),)
    assert auc(method, test) > 0.8
    # scoring does not depend on other logs, and short logs (< one sequence) work
    short = pushed_log(30, seconds=0.5)
    assert method.score(short).shape == (len(short),)
    np.testing.assert_array_equal(method.score(test), score)


def test_long_training_sets_are_subsampled_by_a_documented_seed() -> None:
    # the cap and the seed the guide documents; every training log here fits under the cap
    assert (DEFAULT_MAX_TRAIN_UNITS, DEFAULT_SUBSAMPLE_SEED) == (200_000, 0)
    guide = (Path(__file__).parents[1] / "docs" / "guide.md").read_text()
    assert "200 000" in guide and "subsample_seed" in guide
    train, test = data()  # 3 logs of 1000 samples
    assert PointAE(epochs=1).fit(train).note is None
    capped = PointAE(epochs=2, max_train=500, subsample_seed=1).fit(train)
    assert capped.note is not None and "500 of 3000" in capped.note
    again = PointAE(epochs=2, max_train=500, subsample_seed=1).fit(train)
    np.testing.assert_array_equal(again.score(test), capped.score(test))  # same seed, same rows
    other = PointAE(epochs=2, max_train=500, subsample_seed=2).fit(train)
    assert not np.array_equal(other.score(test), capped.score(test))
    # the LSTM keeps whole stretches of 10 sequences, drawn alike
    pieces = training_pieces([1000, 1000, 1000], 1000, 200, 1)
    assert pieces == training_pieces([1000, 1000, 1000], 1000, 200, 1)
    assert pieces is not None and len(pieces) == 5 and all(b - a == 200 for _, a, b in pieces)
    assert pieces != training_pieces([1000, 1000, 1000], 1000, 200, 2)
    assert training_pieces([1000, 1000, 1000], 3000, 200, 1) is None
    lstm = LstmMob(epochs=1, seq_len=20, max_train=1000, subsample_seed=1).fit(train)
    assert lstm.note is not None and "1000 of 3000" in lstm.note
