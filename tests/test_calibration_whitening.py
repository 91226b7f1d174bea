"""The whitened models' noise scale by speed and their depth statistic
(twincd/calibration/models/): the scale comes exactly out of the fit's one pass, merges in any
split, the statistic is a z on every depth, and the calibration file keeps both (old files keep
their one scale per joint and their sum)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from support.calibrations import refused

from twincd.calibration import Calibration
from twincd.calibration.models import (
    EPSILON_GRID,
    MIN_BIN_SAMPLES,
    SPEED_BINS,
    FitStats,
    IdentifiedStats,
    SpeedStats,
    depth_order,
    depth_score,
    make_model,
    speed_bin,
    wilson_hilferty,
)
from twincd.signal.features import ModelInputs


def _samples(n: int, seed: int, joints: int = 3) -> dict[str, np.ndarray]:
    """A friction plant whose noise grows at rest (a stiction band), as a real arm's does."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    # stretches at rest between motions, and every speed bin visited
    v = np.stack([np.sin(0.5 * t + k) ** 3 * (0.4 + 0.2 * k) for k in range(joints)], axis=1)
    v[np.abs(v) < 0.02] = 0.0
    x = np.stack([2 * np.cos(0.3 * t + k) + k for k in range(joints)], axis=1)
    noise = rng.standard_normal((n, joints)) * np.where(v == 0.0, 0.5, 0.05)
    y = 1.2 * x + 0.3 + 0.6 * np.tanh(v / 0.02) + 0.2 * v + noise
    coulomb = np.stack([np.tanh(v / e) for e in EPSILON_GRID], axis=1)
    return ModelInputs(
        sim_effort_f=x,
        effort_f=y,
        velocity=v,
        velocity_f=v,
        coulomb_f=coulomb,
        coulomb_eps=EPSILON_GRID,
    )


def test_the_speed_scale_is_the_fitted_residual_rms_in_each_bin():
    inputs = _samples(6000, 0)
    clean = np.random.default_rng(1).uniform(size=6000) < 0.95
    model = make_model("friction-whitened").solve(FitStats.from_inputs(inputs, clean))
    assert model.scale_ is not None and model.scale_.shape == (3, len(SPEED_BINS) + 1)
    r = model.residual(inputs)[clean]
    bins = speed_bin(inputs.velocity[clean])
    for j, b in itertools.product(range(3), range(len(SPEED_BINS) + 1)):
        at = bins[:, j] == b
        want = np.sqrt(np.mean(r[at, j] ** 2)) if at.sum() >= MIN_BIN_SAMPLES else model.rmse_[j]
        np.testing.assert_allclose(model.scale_[j, b], want, rtol=1e-7)
    # at rest the stiction band is ten times wider than in motion, and the scale says so
    assert np.all(model.scale_[:, 0] > 5 * model.scale_[:, -1])


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 799), max_size=4), seed=st.integers(0, 1000))
def test_speed_statistics_merge_exactly_in_any_split_and_order(cuts: list[int], seed: int) -> None:
    inputs = _samples(800, seed)
    clean = np.random.default_rng(seed).uniform(size=800) < 0.9
    whole = FitStats.from_inputs(inputs, clean).speed
    bounds = [0, *sorted(set(cuts)), 800]
    parts = [
        FitStats.from_inputs(
            ModelInputs.of({k: v[a:b] for k, v in inputs.columns().items()}, EPSILON_GRID),
            clean[a:b],
        ).speed
        for a, b in itertools.pairwise(bounds)
    ]
    merged = SpeedStats.zeros(3, 0, len(EPSILON_GRID))
    for p in reversed(parts):
        merged = merged + p
    np.testing.assert_array_equal(merged.n, whole.n)
    np.testing.assert_allclose(merged.mean, whole.mean, atol=1e-9)
    np.testing.assert_allclose(merged.cross, whole.cross, rtol=1e-9, atol=1e-7)


def test_pooled_speed_bins_are_the_identified_statistics():
    inputs = _samples(3000, 4, joints=2)
    rng = np.random.default_rng(5)
    regressor = rng.standard_normal((3000, 2, 10))
    clean = rng.uniform(size=3000) < 0.9
    speed = SpeedStats.from_arrays(
        inputs.velocity,
        inputs.sim_effort_f,
        inputs.effort_f,
        inputs.velocity_f,
        inputs.coulomb_f,
        regressor,
        None,
        clean,
    )
    direct = IdentifiedStats.from_arrays(
        inputs.sim_effort_f,
        regressor,
        inputs.velocity_f,
        inputs.coulomb_f,
        inputs.effort_f,
        clean,
    )
    n, mean, cross = speed.pooled()
    assert n == direct.n == clean.sum()
    np.testing.assert_allclose(mean, direct.mean, atol=1e-10)
    np.testing.assert_allclose(cross, direct.cross, rtol=1e-9, atol=1e-7)


def test_wilson_hilferty_gives_the_normal_quantile_of_chi_square():
    body = np.array([0.5, 0.9, 0.99])
    tail = np.array([0.9999, 1 - 1e-6])
    for k in (1, 2, 6, 7):
        z = wilson_hilferty(stats.chi2.isf(1 - body, k), k)
        np.testing.assert_allclose(z, stats.norm.ppf(body), atol=0.03)
        # in the far tail the cube root understates z a little (a fifth of a σ at most at
        # 4.75 σ for one joint, less with more): conservative, never an extra alarm
        excess = wilson_hilferty(stats.chi2.isf(1 - tail, k), k) - stats.norm.ppf(tail)
        assert np.all(excess < 0.0) and np.all(excess > -0.3)


def test_depth_score_takes_the_most_significant_depth():
    # one joint far out: the first depth that holds it is the most significant
    w = np.array([[0.1, 6.0, 0.1, 0.1]])
    z = [wilson_hilferty(np.cumsum(w**2)[k : k + 1], k + 1)[0] for k in range(4)]
    assert depth_score(w)[0] == pytest.approx(max(z)) == pytest.approx(z[1])
    # in the kinematic order given, not the columns' order
    assert depth_score(w, np.array([1, 0, 2, 3]))[0] > depth_score(w)[0]
    # clean whitened noise: a z per depth, small; and it grows with any joint's residual
    noise = np.random.default_rng(0).standard_normal((20000, 6))
    clean = depth_score(noise)
    assert 0.0 < np.median(clean) < 1.5 and np.quantile(clean, 0.999) < 4.5
    louder = noise.copy()
    louder[:, 3] *= 2
    assert np.all(depth_score(louder) >= depth_score(noise) - 1e-12)


def test_depth_order_puts_the_base_first():
    assert depth_order(None, 3) == (0, 1, 2)
    assert depth_order((2, 1, 3, 1), 4) == (1, 3, 0, 2)


def test_a_binned_model_scores_by_the_sample_speed_and_needs_it():
    scale = np.array([[1.0, 0.1, 0.1, 0.1, 0.1, 0.1], [1.0] * 6])
    model = make_model("affine-whitened").with_coefficients(
        {"a": np.ones(2), "b": np.zeros(2), "scale": scale}
    )
    r = np.array([[0.5, 0.0], [0.5, 0.0]])
    v = np.array([[0.0, 0.0], [1.0, 0.0]])  # the first at rest, the second fast
    at_rest, moving = model.score(r, v)
    assert moving > at_rest + 3  # 0.5 is 5 σ in motion, half a σ at rest
    with pytest.raises(Exception, match="speeds"):
        model.score(r)


def _calibration(scale: np.ndarray) -> Calibration:
    from twincd.signal.filters import LowPass

    model = make_model("affine-whitened", (0, 1)).with_coefficients(
        {"a": np.ones(2), "b": np.zeros(2), "scale": scale}, rmse=np.array([0.3, 0.4])
    )
    return Calibration(("j1", "j2"), model, LowPass(), depths=(1, 2))


def test_the_calibration_file_keeps_the_binned_scale_and_old_files_keep_their_sum(tmp_path):
    binned = _calibration(np.arange(1, 13, dtype=float).reshape(2, 6) / 10)
    doc = json.loads(json.dumps(binned.to_dict()))
    assert doc["model"]["statistic"] == "depth"
    assert doc["model"]["speed_bins"] == list(SPEED_BINS)
    back = Calibration.from_dict(doc)
    scale = back.model.scale_
    assert scale is not None and np.array_equal(scale, binned.model.scale_)
    r, v = np.array([[0.2, -0.3]]), np.array([[0.05, 0.0]])
    assert back.model.score(r, v) == binned.model.score(r, v)
    # isolation weighs the whitened residual itself: no second scale
    joint_scale = back.model.joint_scale
    assert joint_scale is not None and np.array_equal(joint_scale, [1.0, 1.0])
    # a file written before the bins: one scale per joint, scored by the sum
    old = json.loads(json.dumps(_calibration(np.array([0.5, 2.0])).to_dict()))
    assert old["model"]["statistic"] == "sum"
    loaded = Calibration.from_dict(old)
    assert loaded.model.statistic == "sum"
    np.testing.assert_allclose(loaded.model.score(r), [(0.2 / 0.5) ** 2 + (0.3 / 2.0) ** 2])
    # broken ones are refused in one line
    for edit in (
        lambda d: d["model"].update(statistic="max"),
        lambda d: d["model"].update(speed_bins=[0.1, 0.01, 0.2, 0.3, 0.4]),
        lambda d: d["model"]["joints"]["j1"].update(scale=[1.0, 2.0]),
        lambda d: d["model"]["joints"]["j2"].update(scale=[1.0, 2.0, 3.0, 4.0, "x", 6.0]),
        lambda d: d["model"]["joints"]["j2"].update(scale=[1.0, 2.0, 3.0, 4.0, 0.0, 6.0]),
    ):
        with refused(doc) as broken:
            edit(broken)


def test_a_threshold_s_estimator_and_mean_are_checked_on_load():
    from twincd.calibration import Threshold

    cal = _calibration(np.arange(1, 13, dtype=float).reshape(2, 6) / 10)
    cal = Calibration.from_dict(
        {
            **cal.to_dict(),
            "threshold": Threshold(
                4.0, 0.9, 0.8, estimator="median-mad", mean=1.0, sd=0.9
            ).to_dict(),
        }
    )
    assert cal.threshold is not None and cal.threshold.mean_sd == (1.0, 0.9)
    doc = cal.to_dict()
    for key, value in (("estimator", "trimmed"), ("mean", "1.0"), ("sd", float("nan"))):
        with refused(doc, f"threshold.{key}") as broken:
            broken["threshold"][key] = value
