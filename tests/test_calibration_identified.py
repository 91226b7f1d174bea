"""The identified calibration models (twincd/calibration/models/): the joint-torque regressor
against RNEA, mergeable statistics, the recovery of a plant whose inertial parameters differ from
the URDF's, the calibration file, and fit → threshold → detect, batch and live, end to end."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.builders import jittered_xarm_log, trajectory
from support.calibrations import refused
from support.clitools import assert_one_line_error, evaluate_methods, run
from support.streaming import blocks, detect_frames, pushed

from twincd.calibration import Calibration
from twincd.calibration.affine import AffineStats
from twincd.calibration.models import (
    EPSILON_GRID,
    FrictionStats,
    IdentifiedModel,
    IdentifiedStats,
    fit_model,
    solve_identified,
)
from twincd.commands import fit_calibration, threshold_calibration
from twincd.detection import OnlineDetector, detect_log
from twincd.errors import DataError
from twincd.prepare.setup import Setup
from twincd.signal.derivatives import differentiate
from twincd.signal.features import ModelFeatures, ModelInputs
from twincd.twin.dynamics import (
    inertial_parameters,
    inverse_dynamics,
    regressor_mask,
    torque_regressor,
)
from twincd.twin.robot import load_robot


@pytest.fixture(scope="module")
def xarm():  # type: ignore[no-untyped-def]
    return load_robot("xarm7")


def _motion(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    w = rng.uniform(0.3, 1.2, 7)
    phase = rng.uniform(0, np.pi, 7)
    q = 0.8 * np.sin(w * t[:, None] + phase)
    qd = 0.8 * w * np.cos(w * t[:, None] + phase)
    qdd = -0.8 * w**2 * np.sin(w * t[:, None] + phase)
    return q, qd, qdd


def test_regressor_times_the_urdf_parameters_is_rnea(xarm) -> None:  # type: ignore[no-untyped-def]
    q, qd, qdd = _motion(200, 0)
    y = torque_regressor(xarm, q, qd, qdd)
    assert y.shape == (200, 7, 70)
    tau = inverse_dynamics(xarm, q, qd, qdd)
    np.testing.assert_allclose(y @ inertial_parameters(xarm), tau, atol=1e-9)
    # joint j feels only the links it carries: a link's parameters never act on the joints
    # beyond it (the kinematic chain, the same fact isolation rests on)
    for j in range(7):
        assert not np.any(y[:, j, : 10 * j])
    # what the filter stage keeps: every entry that is ever non-zero, about half of them
    mask = regressor_mask(xarm)
    assert np.any(y != 0, axis=0).sum() <= mask.sum() < 0.6 * mask.size
    assert not np.any(y[:, ~mask])


def test_regressor_of_a_reduced_model_follows_its_joints() -> None:
    reduced = load_robot("xarm7", keep=("joint1", "joint2", "joint4"))
    t = np.linspace(0, 3, 60)
    q, qd, _ = trajectory(t)
    q, qd = q[:, :3], qd[:, :3]
    qdd = differentiate(t, qd)
    y = torque_regressor(reduced, q, qd, qdd)
    tau = inverse_dynamics(reduced, q, qd, qdd)
    np.testing.assert_allclose(y @ inertial_parameters(reduced), tau, atol=1e-9)


def _heavier_plant(xarm, n: int, seed: int):  # type: ignore[no-untyped-def]
    """What a plant whose inertial parameters are off the URDF's by 20 % each (a heavier link,
    a shifted centre of mass), with friction, measures: features and efforts as the fit reads
    them (unfiltered stand-ins)."""
    q, qd, qdd = _motion(n, seed)
    y = torque_regressor(xarm, q, qd, qdd)
    theta = inertial_parameters(xarm)
    true = theta * (1 + 0.2 * np.random.default_rng(99).standard_normal(theta.shape))
    coulomb = np.stack([np.tanh(qd / e) for e in EPSILON_GRID], axis=1)
    rng = np.random.default_rng(seed + 1)
    effort = y @ true + 0.8 * np.tanh(qd / 0.02) + 0.3 * qd + 0.2
    effort = effort + 0.01 * rng.standard_normal(effort.shape)
    return y @ theta, y, qd, coulomb, effort


def test_identified_model_recovers_a_plant_the_affine_map_cannot(xarm) -> None:  # type: ignore[no-untyped-def]
    twin, y, qd, coulomb, effort = _heavier_plant(xarm, 3000, 1)
    stats = IdentifiedStats.from_arrays(twin, y, qd, coulomb, effort)
    sol = solve_identified(stats)
    np.testing.assert_allclose(sol.friction.epsilon, 0.02)
    np.testing.assert_allclose(sol.friction.c, 0.8, atol=0.02)
    np.testing.assert_allclose(sol.friction.d, 0.3, atol=0.02)
    affine = AffineStats.from_arrays(twin, effort)
    friction = FrictionStats.from_arrays(twin, qd, coulomb, effort)
    # on motion it was not fitted on, the residual is near the noise (0.01) on every joint
    twin2, y2, qd2, coulomb2, effort2 = _heavier_plant(xarm, 2000, 7)
    columns = {"effort_f": effort2, "sim_effort_f": twin2, "velocity_f": qd2}
    unseen = ModelInputs.of({**columns, "coulomb_f": coulomb2, "regressor_f": y2}, EPSILON_GRID)
    rms = {}
    for kind in ("friction", "identified", "identified-whitened"):
        model = fit_model(kind, affine, friction, stats)
        assert (getattr(model, "theta_", None) is not None) == kind.startswith("identified")
        rms[kind] = np.sqrt(np.mean(model.residual(unseen) ** 2, axis=0))
    assert np.all(rms["identified"] < 0.04), rms["identified"]
    assert np.max(rms["friction"]) > 4 * np.max(rms["identified"]), rms
    np.testing.assert_allclose(rms["identified-whitened"], rms["identified"])


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 299), max_size=4), seed=st.integers(0, 1000))
def test_identified_statistics_merge_exactly_in_any_split(cuts: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, d, p = 300, 3, 5
    twin, qd, effort = (rng.standard_normal((n, d)) + 1e3 for _ in range(3))  # big offsets
    y = rng.standard_normal((n, d, p))
    coulomb = np.stack([np.tanh(qd / e) for e in EPSILON_GRID], axis=1)
    mask = rng.uniform(size=n) < 0.8
    whole = IdentifiedStats.from_arrays(twin, y, qd, coulomb, effort, mask)
    bounds = [0, *sorted(set(cuts)), n]
    merged = IdentifiedStats.zeros(d, p)
    for a, b in reversed(list(itertools.pairwise(bounds))):  # the order does not matter
        part = IdentifiedStats.from_arrays(
            twin[a:b], y[a:b], qd[a:b], coulomb[a:b], effort[a:b], mask[a:b]
        )
        merged = merged + part
    assert merged.n == whole.n and merged.params == p
    # features near zero (a mean of tanh(q̇/ε) features, ~1e-6) merge to the last bits of the
    # unit-scale features they are means of, not of themselves
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(merged.cross, whole.cross, rtol=1e-9, atol=1e-7)


def test_chunked_regressor_equals_the_whole_log(tmp_path: Path) -> None:
    log = jittered_xarm_log(tmp_path / "run.mcap")
    setup = Setup(robot="xarm7", block_size=1 << 20)
    features = ModelFeatures(coulomb_eps=EPSILON_GRID, regressor=True)
    whole = setup.prepare(log, features)
    parts = replace(setup, block_size=7).prepare(log, features)
    assert whole.regressor_f is not None and parts.regressor_f is not None
    assert whole.regressor_f.shape == (len(whole), 7, 70)
    scale = np.ptp(whole.regressor_f, axis=0) + 1e-12
    assert np.all(np.abs(parts.regressor_f - whole.regressor_f) <= 1e-9 * scale)
    # the filter is linear: the filtered regressor times the URDF's θ is the filtered twin
    assert whole.robot is not None
    np.testing.assert_allclose(
        whole.regressor_f @ inertial_parameters(whole.robot),
        whole.sim_effort_f,
        atol=1e-6 * float(np.ptp(whole.sim_effort_f)),
    )


# ---------------------------------------------------------------- the file and the CLI


@pytest.fixture(scope="module")
def identified_cal(xarm_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("identified") / "cal.json"
    model = ["--model", "identified-whitened"]
    assert run("fit", xarm_dataset / "train", "-o", path, *model, "-q").exit_code == 0
    assert run("threshold", xarm_dataset / "val", "-c", path, "-k", "8", "-q").exit_code == 0
    return path


def test_fit_threshold_detect_end_to_end(identified_cal: Path, xarm_dataset: Path) -> None:
    doc = json.loads(identified_cal.read_text())
    assert doc["model"]["kind"] == "identified-whitened"
    assert doc["filter"]["kind"] == "critical"  # the identified models' default: no ringing
    for coeff in doc["model"]["joints"].values():
        assert len(coeff["theta"]) == 70 and {"a", "b", "c", "d", "epsilon", "scale"} <= set(coeff)
    cal = Calibration.load(identified_cal)
    assert (
        cal.model.features.regressor
        and cal.model.coefficients()["theta"] is not None
        and cal.model.coefficients()["theta"].shape == (7, 70)
    )
    back = Calibration.from_dict(cal.to_dict()).model
    assert back.coefficients()["theta"] is not None  # the round trip keeps θ
    # the synthetic plant's links are not the URDF's: the identified residual is far smaller
    friction_rmse = Calibration.load(identified_cal).model.rmse_
    assert friction_rmse is not None and np.all(friction_rmse < 0.1)
    hit = run("detect", xarm_dataset / "test" / "test_000.mcap", "-c", identified_cal, "--json")
    assert hit.exit_code == 1, hit.output
    events = json.loads(hit.stdout)["logs"][0]["events"]
    # each event names its link, or says it cannot and lists the candidates (named first)
    assert events and all(e["link_candidates"] for e in events)
    assert all(e["link"] in (None, e["link_candidates"][0]) for e in events)
    assert any(e["link"] for e in events)
    clean = run("detect", xarm_dataset / "val" / "val_000.mcap", "-c", identified_cal)
    assert clean.exit_code == 0, clean.output


def test_identified_needs_a_urdf(twin_dataset: Path, tmp_path: Path) -> None:
    # the fixture's logs carry their own twin effort for joints no robot model has
    out = tmp_path / "c.json"
    result = run("fit", twin_dataset / "train", "-o", out, "--model", "identified")
    assert_one_line_error(result, "URDF")
    assert not out.exists()
    # evaluate skips the method there, and still runs the others
    rows = evaluate_methods(twin_dataset, "-m", "friction,identified")
    assert rows["friction"]["auc"] > 0.9
    assert "URDF" in rows["identified"]["skipped"] and rows["identified"].get("auc") is None


def test_broken_theta_is_refused(identified_cal: Path) -> None:
    doc = json.loads(identified_cal.read_text())
    with refused(doc, "one length") as ragged:
        next(iter(ragged["model"]["joints"].values()))["theta"].pop()
    with refused(doc, "theta") as nan:
        next(iter(nan["model"]["joints"].values()))["theta"][3] = "NaN"
    with refused(doc, "not 10 per link") as short:
        for coeff in short["model"]["joints"].values():
            coeff["theta"] = coeff["theta"][:65]
    with refused(doc, "lacks its coefficient") as missing:
        for coeff in missing["model"]["joints"].values():
            del coeff["theta"]
    with refused(doc, "theta, which it does not learn") as stray:
        stray["model"]["kind"] = "friction-whitened"


@pytest.mark.parametrize("chunk", [1, 333])
def test_online_detector_equals_batch_with_an_identified_model(
    xarm_dataset: Path, chunk: int
) -> None:
    train = sorted((xarm_dataset / "train").glob("*.mcap"))
    cal = fit_calibration(
        train,
        model="identified",
        robot="xarm7",
        cutoff_hz=3.0,
        causal=True,
        filter_kind="butterworth",
    ).calibration
    val = sorted((xarm_dataset / "val").glob("*.mcap"))
    cal = threshold_calibration(val, cal, k_sigma=6.0).calibration
    log = xarm_dataset / "test" / "test_000.mcap"
    batch, frames = detect_frames(log, cal)
    assert batch.events
    states = Setup.from_calibration(cal).prepare(log).states
    det = OnlineDetector(cal)
    outs = pushed(det, states, blocks(len(states), chunk))
    events = [event for out in outs for event in out.events] + det.close()
    live = np.concatenate([out.score for out in outs])
    np.testing.assert_allclose(live, frames.column("score"), rtol=1e-12)
    assert events == batch.events


def test_detect_log_on_a_whole_log_equals_the_stream(
    identified_cal: Path, xarm_dataset: Path
) -> None:
    """The library's whole-log path (``detect_log`` on ``Calibration.prepare``) scores a fitted
    identified model as ``detect`` streams it, both bands; a log prepared for a fit (its
    inputs filtered, no fast band) is refused with what to do."""
    cal = Calibration.load(identified_cal)
    setup = Setup.from_calibration(cal)
    log = xarm_dataset / "test" / "test_000.mcap"
    streamed, frames = detect_frames(log, cal, setup)
    prepared = cal.prepare(log)
    assert prepared.residual_fast is not None and cal.score.fast is not None
    whole = detect_log(prepared, cal)
    np.testing.assert_allclose(whole.scores, frames.column("score"), rtol=1e-9, atol=1e-12)
    assert whole.events == streamed.events and whole.events
    with pytest.raises(DataError, match="prepared for a fit"):
        detect_log(setup.prepare(log, cal.model.features), cal)


def test_filter_kind_is_a_choice_and_the_calibration_keeps_it(
    identified_cal: Path, xarm_dataset: Path, tmp_path: Path
) -> None:
    out = tmp_path / "b.json"
    args = ["--model", "identified", "--filter-kind", "butterworth", "-q"]
    assert run("fit", xarm_dataset / "train", "-o", out, *args).exit_code == 0
    assert json.loads(out.read_text())["filter"]["kind"] == "butterworth"
    test_log = xarm_dataset / "test" / "test_000.mcap"
    result = run("evaluate", test_log, "-c", identified_cal, "--filter-kind", "butterworth")
    assert_one_line_error(result, "--filter-kind")
    result = run("fit", xarm_dataset / "train", "-o", out, "--filter-kind", "bessel")
    assert_one_line_error(result, "--filter-kind")


# ---------------------------------------------------------------- flat memory: blocks, mask


def test_identified_fit_in_blocks_equals_one_block(tmp_path: Path) -> None:
    from twincd.calibration.fitting import fit_log, merge_fits
    from twincd.calibration.models import fit_features, model_inputs

    log = jittered_xarm_log(tmp_path / "run.mcap")
    one = Setup(robot="xarm7", block_size=1 << 20)
    blocks = replace(one, block_size=97)
    features = fit_features("identified")
    fits = [fit_log(log, s, (), features) for s in (one, blocks)]
    whole, parts = (f.stats.identified for f in fits)
    # 12 s in two segments, 1.63 s of filter edge at each of their four ends: 1 297 samples
    assert whole is not None and parts is not None and whole.n == parts.n > 1000
    np.testing.assert_allclose(parts.mean, whole.mean, rtol=1e-9, atol=1e-12)
    scale = np.sqrt(np.einsum("dkk->dk", whole.cross))  # each column's spread
    assert np.all(np.abs(parts.cross - whole.cross) <= 1e-9 * scale[:, :, None] * scale[:, None])
    cals = [merge_fits([f], one, "identified") for f in fits]
    for name in ("a", "b", "c", "d", "epsilon", "rmse", "r2"):
        got, want = (getattr(c.model, f"{name}_") for c in (cals[1], cals[0]))
        np.testing.assert_allclose(got, want, rtol=1e-9)
    # and the fitted map scores a log alike
    prepared = one.prepare(log, features)
    residuals = [c.model.residual(model_inputs(prepared)) for c in cals]
    np.testing.assert_allclose(residuals[1], residuals[0], atol=1e-9 * np.ptp(prepared.effort_f))


def test_masked_regressor_statistics_and_prediction_equal_the_whole_ones(xarm) -> None:  # type: ignore[no-untyped-def]
    twin, y, qd, coulomb, effort = _heavier_plant(xarm, 700, 2)
    mask = regressor_mask(xarm)
    rows = np.random.default_rng(3).uniform(size=len(y)) < 0.9
    whole = IdentifiedStats.from_arrays(twin, y, qd, coulomb, effort, rows)
    kept = IdentifiedStats.from_arrays(twin, y[:, mask], qd, coulomb, effort, rows, mask)
    assert kept.n == whole.n  # the same bits: the entries off the mask are zero by structure
    assert np.array_equal(kept.mean, whole.mean) and np.array_equal(kept.cross, whole.cross)
    affine = AffineStats.from_arrays(twin, effort)
    friction = FrictionStats.from_arrays(twin, qd, coulomb, effort)
    model = fit_model("identified", affine, friction, whole)
    # θ lives on the mask
    assert isinstance(model, IdentifiedModel) and not np.any(model.theta_[~mask])
    columns = {"effort_f": effort, "sim_effort_f": twin, "velocity_f": qd, "coulomb_f": coulomb}
    inputs = ModelInputs.of(columns, EPSILON_GRID)
    full = model.predict(replace(inputs, regressor_f=y))
    compact = model.predict(replace(inputs, regressor_f=y[:, mask], regressor_mask=mask))
    np.testing.assert_allclose(compact, full, rtol=1e-12, atol=1e-12 * np.ptp(full))
    with pytest.raises(DataError, match="mask"):  # a compact regressor needs its mask
        IdentifiedStats.from_arrays(twin, y[:, mask], qd, coulomb, effort)


def test_streamed_frames_carry_only_the_masked_regressor(tmp_path: Path) -> None:
    log = jittered_xarm_log(tmp_path / "run.mcap")
    setup = Setup(robot="xarm7", block_size=500)
    features = ModelFeatures(coulomb_eps=EPSILON_GRID, regressor=True)
    with setup.open(log, features=features) as stream:
        frames = list(stream)
        mask = stream.regressor_mask
    assert mask is not None and mask.shape == (7, 70)
    assert all(f["regressor_f"].shape == (f.n, int(mask.sum())) for f in frames)
    # the regressor's rows never come in blocks bigger than REGRESSOR_BLOCK, whatever asked
    from twincd.prepare.setup import REGRESSOR_BLOCK

    assert setup.block_size_for(True) == 500 and setup.block_size_for(False) == 500
    big = replace(setup, block_size=1 << 20)
    assert big.block_size_for(True) == REGRESSOR_BLOCK and big.block_size_for(False) == 1 << 20
    whole = setup.prepare(log, features).regressor_f
    assert whole is not None and not np.any(whole[:, ~mask])
    np.testing.assert_array_equal(
        whole[:, mask], np.concatenate([f["regressor_f"] for f in frames])
    )
