"""twincd.calibration: sufficient statistics, the affine fit (eq. 3–4) and the calibration file."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from conftest import GAINS, OFFSET, TWIN_JOINTS

from twincd.calibration import (
    SCHEMA,
    AffineCalibration,
    AffineStats,
    Calibration,
    FitInfo,
    Threshold,
    make_model,
    solve,
)
from twincd.calibration.affine import FIT_EDGE_FACTOR
from twincd.commands import fit_calibration
from twincd.errors import CalibrationError, DataError, NotFittedError
from twincd.io.logs import expand_logs
from twincd.io.options import LogOptions
from twincd.signal.bands import slow_band
from twincd.signal.edges import edge_profile
from twincd.signal.filters import LowPass

A = np.array([1.39, 1.17, 21.7])
B = np.array([0.24, -1.27, 0.18])


def synthetic(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.random.default_rng(seed).normal(0, 2, (n, 3))
    return x, A * x + B


def test_known_a_b_are_recovered_exactly():
    x, y = synthetic(500, 0)
    est = AffineCalibration().fit_arrays(y, x)
    np.testing.assert_allclose(est.a_, A, rtol=1e-10)
    np.testing.assert_allclose(est.b_, B, atol=1e-10)
    np.testing.assert_allclose(est.r2_, 1.0)
    np.testing.assert_allclose(est.rmse_, 0.0, atol=1e-6)
    np.testing.assert_allclose(est.predict(x), y, atol=1e-9)


def test_matches_numpy_least_squares_with_noise():
    x, y = synthetic(400, 1)
    y = y + np.random.default_rng(2).normal(0, 0.3, y.shape)
    sol = solve(AffineStats.from_arrays(x, y))
    for j in range(3):
        a, b = np.polyfit(x[:, j], y[:, j], 1)
        assert sol.a[j] == pytest.approx(a, rel=1e-9)
        assert sol.b[j] == pytest.approx(b, rel=1e-9, abs=1e-12)
        resid = y[:, j] - (a * x[:, j] + b)
        assert sol.rmse[j] == pytest.approx(np.sqrt(np.mean(resid**2)), rel=1e-6)
        assert sol.r2[j] == pytest.approx(1 - resid.var() / y[:, j].var(), rel=1e-9)


def test_masked_samples_are_left_out():
    x, y = synthetic(300, 3)
    mask = np.ones(300, dtype=bool)
    mask[100:150] = False
    y[100:150] += 50.0  # a "collision" that must not bend the fit
    est = AffineCalibration().fit_arrays(y, x, mask)
    np.testing.assert_allclose(est.a_, A, rtol=1e-10)
    assert est.n_samples_ == 250


def test_merged_per_log_statistics_equal_one_concatenation():
    parts = [synthetic(n, seed) for seed, n in enumerate((50, 120, 7, 300))]
    merged = AffineStats.zeros(3)
    for x, y in parts:
        merged = merged + AffineStats.from_arrays(x, y)
    whole = AffineStats.from_arrays(
        np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    )
    assert merged.n == whole.n
    for field in ("mean_x", "mean_y", "cxx", "cyy", "cxy"):
        np.testing.assert_allclose(getattr(merged, field), getattr(whole, field), rtol=1e-10)
    np.testing.assert_allclose(solve(merged).a, solve(whole).a, rtol=1e-12)


def test_streaming_hundreds_of_logs_keeps_state_constant():
    # 400 logs streamed one at a time: the state is six (D,) arrays whatever the count
    rng = np.random.default_rng(5)
    total = AffineStats.zeros(3)
    xs, ys = [], []
    for _ in range(400):
        x = rng.normal(0, 1, (25, 3))
        y = A * x + B + rng.normal(0, 0.01, x.shape)
        total = total + AffineStats.from_arrays(x, y)
        xs.append(x)
        ys.append(y)
        assert total.mean_x.shape == (3,)
    whole = solve(AffineStats.from_arrays(np.concatenate(xs), np.concatenate(ys)))
    np.testing.assert_allclose(solve(total).a, whole.a, rtol=1e-10)
    np.testing.assert_allclose(solve(total).b, whole.b, rtol=1e-8)


def test_badly_conditioned_joint_warns(caplog):
    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, (500, 2))
    x[:, 1] *= 0.001  # the twin barely moves this joint
    y = x + rng.normal(0, 0.1, x.shape)
    with caplog.at_level(logging.WARNING, logger="twincd"):
        AffineCalibration(["good", "tip"]).fit_arrays(y, x)
    assert "tip is badly conditioned" in caplog.text
    assert "good" not in caplog.text


def test_constant_twin_does_not_divide_by_zero(caplog):
    """A twin effort that never varies does not determine the gain: it is held at 1 (the twin
    as it is) and said, and b takes the rest."""
    x = np.zeros((100, 1))
    y = np.random.default_rng(0).normal(1.0, 0.1, (100, 1))
    with caplog.at_level(logging.WARNING, logger="twincd"):
        est = AffineCalibration().fit_arrays(y, x)
    assert est.a_[0] == 1.0 and est.b_[0] == pytest.approx(y.mean())
    assert "do not determine a" in caplog.text


def test_errors_before_fit_and_without_data():
    with pytest.raises(NotFittedError):
        AffineCalibration().predict(np.zeros((2, 3)))
    with pytest.raises(DataError, match="too few"):
        solve(AffineStats.zeros(3))
    with pytest.raises(DataError, match="no logs"):
        AffineCalibration().fit([])


def make_calibration(**kw) -> Calibration:
    coefficients = {"a": np.array([1.2, 0.9]), "b": np.array([0.1, -0.3])}
    r2, rmse = np.array([0.9, 0.8]), np.array([0.1, 0.2])
    base = dict(
        joint_names=("j1", "j2"),
        model=make_model("affine").with_coefficients(coefficients, r2, rmse),
        lowpass=LowPass(2.0, 3),
        options=LogOptions(topic="/js", joint_map={"a": "j1"}),
        robot="xarm7",
        urdf_sha256="abc",
        fit=FitInfo(logs=("x.mcap",), samples=100),
    )
    base.update(kw)
    return Calibration(**base)


def test_file_round_trip_and_layout(tmp_path):
    cal = make_calibration(threshold=Threshold(4.0, 1.5, 0.5, ("v.mcap",), 80))
    path = tmp_path / "cal.json"
    cal.save(path)
    doc = json.loads(path.read_text())
    assert doc["schema"] == SCHEMA
    assert doc["model"] == {
        "kind": "affine",
        "statistic": "sum",
        "joints": {"j1": {"a": 1.2, "b": 0.1}, "j2": {"a": 0.9, "b": -0.3}},
    }
    assert doc["filter"]["cutoff_hz"] == 2.0 and doc["filter"]["zero_phase"] is True
    assert doc["robot"]["joint_names"] == ["j1", "j2"] and doc["robot"]["name"] == "xarm7"
    assert doc["fit"]["joints"]["j2"] == {"r2": 0.8, "rmse": 0.2}
    assert doc["threshold"]["value"] == pytest.approx(3.5)
    back = Calibration.load(path)
    assert back.joint_names == cal.joint_names and back.lowpass == cal.lowpass
    assert back.options == cal.options and back.robot == "xarm7"
    np.testing.assert_array_equal(back.model.a_, cal.model.a_)
    assert back.threshold == cal.threshold
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


def test_other_schema_and_broken_files_are_calibration_errors(tmp_path):
    cal = make_calibration()
    doc = cal.to_dict()
    doc["schema"] = "twincd.calibration/99"
    (tmp_path / "v3.json").write_text(json.dumps(doc))
    with pytest.raises(CalibrationError, match="schema"):
        Calibration.load(tmp_path / "v3.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(CalibrationError, match="not JSON"):
        Calibration.load(tmp_path / "bad.json")
    doc = cal.to_dict()
    del doc["model"]["joints"]["j2"]
    (tmp_path / "partial.json").write_text(json.dumps(doc))
    with pytest.raises(CalibrationError, match=r"lacks the field 'model\.joints\.j2'"):
        Calibration.load(tmp_path / "partial.json")
    (tmp_path / "binary.json").write_bytes(b"\x89MCAP0\r\n\xff\xfe")
    with pytest.raises(CalibrationError, match="not JSON text"):
        Calibration.load(tmp_path / "binary.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(CalibrationError, match="a JSON list, not an object"):
        Calibration.load(tmp_path / "list.json")
    with pytest.raises(CalibrationError, match="cannot read"):
        Calibration.load(tmp_path / "missing.json")


def test_threshold_is_required_for_detection():
    with pytest.raises(NotFittedError, match="no threshold"):
        make_calibration(source="c.json").require_threshold()


def test_fit_calibration_over_logs_recovers_the_gains(twin_dataset):
    paths = expand_logs([twin_dataset / "train"])
    cal = fit_calibration(paths, cutoff_hz=5.0, filter_kind="butterworth").calibration
    assert cal.joint_names == TWIN_JOINTS
    np.testing.assert_allclose(cal.model.a_, GAINS, rtol=0.02)
    np.testing.assert_allclose(cal.model.b_, OFFSET, atol=0.05)
    assert cal.robot is None and not cal.simulated  # the logs carry their own twin effort
    # the samples next to each end whose filtered values are noisier than the middle's by more
    # than FIT_EDGE_FACTOR are not fitted (judged, not fitted: twincd.signal.edges)
    profile = edge_profile(slow_band(LowPass(5.0)), 0.01)
    start = int((profile.start > FIT_EDGE_FACTOR).sum())
    end = int((profile.end > FIT_EDGE_FACTOR).sum())
    assert 0 < start < 10 and 0 < end < 10  # a few samples, not the settling time (33)
    assert len(cal.fit.logs) == 3 and cal.fit.samples == 3 * (1600 - start - end)
    assert np.all(cal.model.r2_ > 0.9)


def test_labelled_collisions_are_excluded_from_the_fit(twin_dataset):
    paths = expand_logs([twin_dataset / "test"])
    cal = fit_calibration(paths, cutoff_hz=5.0, filter_kind="butterworth").calibration
    np.testing.assert_allclose(cal.model.a_, GAINS, rtol=0.03)
    assert cal.fit.samples < 2 * 1600


def test_large_offsets_do_not_cancel_the_signal():
    # efforts far from zero with a small spread: raw Σx² − (Σx)²/n would lose the slope
    rng = np.random.default_rng(3)
    parts = []
    for _ in range(5):
        x = 1e6 + rng.normal(0, 0.05, (400, 1))
        parts.append((x, 2 * x + 3 + rng.normal(0, 1e-3, (400, 1))))
    merged = AffineStats.zeros(1)
    for x, y in parts:
        merged = merged + AffineStats.from_arrays(x, y)
    sol = solve(merged)
    x_all = np.concatenate([p[0] for p in parts])[:, 0]
    y_all = np.concatenate([p[1] for p in parts])[:, 0]
    a_ref, b_ref = np.polyfit(x_all - 1e6, y_all, 1)  # centred reference fit
    assert sol.a[0] == pytest.approx(a_ref, rel=1e-6)
    # b = ȳ − a·x̄ with x̄ = 1e6: float64 leaves ~1e-8 relative in a, so ~0.01 in b
    # (the uncentred formula was off by ~3e4 here)
    assert sol.b[0] == pytest.approx(b_ref - a_ref * 1e6, abs=0.05)
    assert 0.99 < sol.r2[0] < 1.0


def _with(doc, dotted: str, value):
    """``doc`` with the field at ``dotted`` (a.b.c) replaced by ``value``."""
    node = doc
    *parents, last = dotted.split(".")
    for key in parents:
        node = node[key]
    node[last] = value
    return doc


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("model.joints.j1.a", float("nan"), r"a\[j1\] is nan"),
        ("model.joints.j2.b", float("inf"), r"b\[j2\] is inf"),
        ("model.joints.j1.a", "0.8", r"a\[j1\] is str"),
        ("model.joints.j1.b", True, r"b\[j1\] is bool"),
        ("model.joints.j1.a", None, r"a\[j1\] is NoneType"),
        ("threshold.mu", float("nan"), "threshold.mu is nan"),
        ("threshold.sigma", float("-inf"), "threshold.sigma is -inf"),
        ("threshold.sigma", -1.0, "negative sigma"),
        ("threshold.value", 99.0, "not mu"),
        ("threshold.k_sigma", "4", "threshold.k_sigma is str"),
        ("filter.cutoff_hz", 0, "filter.cutoff_hz is 0"),
        ("filter.order", 2.5, "filter.order is 2.5"),
        ("filter.sample_rate_hz", float("nan"), "sample_rate_hz is nan"),
        ("robot.joint_names", ["j1", "j1"], "names a joint twice"),
        ("robot.joint_names", "j1", "not a list of joint names"),
    ],
)
def test_every_number_is_validated_on_load(tmp_path, field, value, match):
    doc = make_calibration(threshold=Threshold(4.0, 1.5, 0.5, ("v.mcap",), 80)).to_dict()
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(_with(doc, field, value)))  # json writes NaN/Infinity tokens
    with pytest.raises(CalibrationError, match=match):
        Calibration.load(path)


def test_finite_array_checks_the_joint_count():
    from twincd.calibration.values import finite_array

    np.testing.assert_array_equal(finite_array([1, 2.5], ("a", "b"), "c", "w"), [1.0, 2.5])
    with pytest.raises(CalibrationError, match=r"1 value\(s\) for 2 joint"):
        finite_array([1.0], ("a", "b"), "c", "w")
    with pytest.raises(CalibrationError, match="not a list"):
        finite_array("12", ("a", "b"), "c", "w")
