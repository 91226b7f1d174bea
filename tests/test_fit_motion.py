"""``fit`` judges what the logs' motion determines (contract: Exit codes and streams): an arm
that does not move is refused, a coefficient the motion does not determine is held at its prior
and said with the motion that would determine it, and the warnings speak of the fitted model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import build_twin_log
from support import synthlogs
from support.clitools import assert_one_line_error, run

from twincd.calibration import AffineStats, solve
from twincd.calibration.excitation import (
    CONDITION_LIMIT,
    REST_POSITION,
    MotionStats,
    check_motion,
    conditioning,
)
from twincd.errors import DataError


@pytest.fixture(scope="module")
def still_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    """Two synthetic training paths with the arm held still in its first pose, as a bare MCAP
    (twincd's writer) and as rosbag2 sqlite3 folders (rosbags' writer)."""
    root = tmp_path_factory.mktemp("still")
    out: dict[str, list[Path]] = {"mcap": [], "rosbag2-sqlite3": []}
    for i in range(2):
        run_ = synthlogs.held(synthlogs.path("train", i))
        for form in out:
            out[form].append(synthlogs.write(run_, root / f"{form}_{i}", form))
    return out


@pytest.mark.parametrize("form", ["mcap", "rosbag2-sqlite3"])
@pytest.mark.parametrize("model", [None, "affine", "friction"])
def test_an_arm_at_rest_is_refused(still_logs, tmp_path, form, model):
    """Before: b = +9596 N·m, a = −139, exit 0 and no word (the issue's case)."""
    options = [] if model is None else ["--model", model]
    result = run("fit", *still_logs[form], "-o", tmp_path / "cal.json", *options)
    assert_one_line_error(result, "the logs hold no motion")
    assert f"less than {REST_POSITION:g} rad" in result.stderr
    assert "moving through its work" in result.stderr
    assert not (tmp_path / "cal.json").exists()


def test_inspect_says_the_arm_does_not_move(still_logs, locked):
    result = run("inspect", still_logs["rosbag2-sqlite3"][0], "--json")
    assert result.exit_code == 0, result.output  # detect and threshold judge it
    warnings = json.loads(result.stdout)["logs"][0]["warnings"]
    assert any("the arm does not move" in w and "fit refuses" in w for w in warnings)
    moving = json.loads(run("inspect", locked[0], "--json").stdout)["logs"][0]["warnings"]
    assert not any("does not move" in w for w in moving)


@pytest.fixture(scope="module")
def locked(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three training paths in which joint5 and joint6 never move (the others do)."""
    root = tmp_path_factory.mktemp("locked")
    return [
        synthlogs.write(synthlogs.held(synthlogs.path("train", i), [4, 5]), root / f"l{i}")
        for i in range(3)
    ]


@pytest.mark.parametrize("model", [None, "friction"])
def test_joints_that_do_not_move_keep_no_friction(locked, tmp_path, model):
    options = [] if model is None else ["--model", model]
    result = run("fit", *locked, "-o", tmp_path / "cal.json", *options)
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.stderr.splitlines() if "do not move" in ln]
    assert len(lines) == 1 and "joint5, joint6 do not move" in lines[0]
    assert "held at 0" in lines[0] and "move both ways at several speeds" in lines[0]
    cal = json.loads((tmp_path / "cal.json").read_text())
    joints = cal["fit"]["joints"]
    assert joints["joint5"]["held"] == ["c", "d"] and joints["joint6"]["held"] == ["c", "d"]
    assert all("held" not in joints[f"joint{i}"] for i in (1, 2, 3, 4, 7))
    coefficients = cal["model"]["joints"]
    assert coefficients["joint5"]["c"] == 0.0 and coefficients["joint6"]["d"] == 0.0
    # the moving joints keep their friction, near the plant's (Coulomb 0.8–1.5 N·m)
    assert all(0.5 < coefficients[f"joint{i}"]["c"] < 2.0 for i in (1, 2, 3, 4))
    assert "+0.000*" in result.stdout and "* held" in result.stdout
    assert "do not determine a" not in result.stderr  # the twin's effort still varies


def test_a_joint_that_turns_one_way_at_one_speed(tmp_path):
    """j1 turns at a constant speed the whole log: tanh(q̇/ε) and q̇ are constant, so c and d
    and the offset b cannot be told apart."""

    def one_way(arrays: dict[str, np.ndarray]) -> None:
        t = (arrays["stamps"] - arrays["stamps"][0]) * 1e-9
        arrays["q"][:, 0] = 0.4 * t
        arrays["qd"][:, 0] = 0.4

    log = build_twin_log(tmp_path / "one_way.mcap", edit=one_way)
    result = run("fit", log, "-o", tmp_path / "cal.json", "--model", "friction")
    assert result.exit_code == 0, result.output
    assert "do not determine c (Coulomb friction) on j1" in result.stderr
    assert "do not determine d (viscous friction) on j1" in result.stderr
    assert "moves both ways" in result.stderr and "several speeds" in result.stderr
    held = json.loads((tmp_path / "cal.json").read_text())["fit"]["joints"]
    assert held["j1"]["held"] == ["c", "d"] and "held" not in held["j2"]


def test_a_twin_effort_at_one_level_holds_the_gain(tmp_path):
    """j2's twin effort stays at one level (its joint holds a pose the others do not move)
    while j1 and j3 move: its gain a and the offset b are one coefficient."""

    def level(arrays: dict[str, np.ndarray]) -> None:
        rng = np.random.default_rng(5)
        twin = 12.0 + 1e-4 * rng.standard_normal(len(arrays["twin"]))
        arrays["effort"][:, 1] += 0.8 * (twin - arrays["twin"][:, 1])
        arrays["twin"][:, 1] = twin

    log = build_twin_log(tmp_path / "level.mcap", edit=level)
    result = run("fit", log, "-o", tmp_path / "cal.json", "--model", "affine")
    assert result.exit_code == 0, result.output
    line = next(ln for ln in result.stderr.splitlines() if "do not determine a" in ln)
    assert "on j2:" in line and "held at 1" in line and "change the effort" in line
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert cal["model"]["joints"]["j2"]["a"] == 1.0
    assert abs(cal["model"]["joints"]["j2"]["b"]) < 5.0  # not an offset thousands of N·m off
    assert cal["fit"]["joints"]["j2"]["held"] == ["a"]


def test_well_moving_logs_hold_nothing(xarm_dataset, tmp_path):
    """twincd's own synthetic logs: no coefficient held, and no negative-gain warning (the
    affine a of a wrist joint whose twin effort barely varies was negative there)."""
    result = run("fit", xarm_dataset / "train", "-o", tmp_path / "cal.json")
    assert result.exit_code == 0, result.output
    assert "warning" not in result.stderr, result.stderr
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert all("held" not in j for j in cal["fit"]["joints"].values())


def test_the_sign_warning_speaks_of_the_fitted_model(xarm_dataset, tmp_path):
    """An effort logged with the opposite sign: the default (identified) model's gain on the
    twin's effort is negative, and the warning says so of that model."""
    flipped = []
    for i in range(2):
        run_ = synthlogs.scaled(synthlogs.path("train", i), -1.0)
        flipped.append(synthlogs.write(run_, tmp_path / f"flip{i}"))
    result = run("fit", *flipped, "-o", tmp_path / "cal.json")
    assert result.exit_code == 0, result.output
    line = next(ln for ln in result.stderr.splitlines() if "negative" in ln)
    assert "the identified-whitened model's gain on the twin's effort is negative on" in line
    assert "joint2" in line and "rigid-body effort" in line and "effort sign" in line
    assert "(of a·twin + b)" not in result.stderr


@pytest.mark.parametrize("model", [None, "affine", "friction"])
def test_a_fit_on_two_seconds_holds_what_it_cannot_determine(tmp_path, model):
    """2 s of a synthetic path: 163 clean samples at 100 Hz (its ends weighed by their edge
    noise, those noisier than the middle's by 10 % left out), about 5 independent ones once
    low-passed at 1.5 Hz. Before: gains of −180 and +0.03, offsets of +1928 N·m, and only a
    motion warning. Now each model fits what 5 samples determine (2 a coefficient: a and b)
    and holds the rest at its prior, saying which of the model fitted (each with the default
    model's filter: the critically damped 1.5 Hz)."""
    short = synthlogs.write(synthlogs.path("train", 0, 2.0, longest=2.0), tmp_path / "short")
    options = [] if model is None else ["--model", model, "--filter-kind", "critical"]
    options += [] if model is None else ["--cutoff", "1.5"]
    result = run("fit", short, "-o", tmp_path / "cal.json", *options)
    assert result.exit_code == 0, result.output
    cal = json.loads((tmp_path / "cal.json").read_text())
    kind = cal["model"]["kind"]
    assert cal["fit"]["samples"] == 163
    lines = [ln for ln in result.stderr.splitlines() if "independent samples" in ln]
    expected = {"identified-whitened": ["c", "d", "theta"], "affine": None}
    held = expected.get(kind, ["c", "d"])
    if held is None:  # a and b: 4 samples' worth, determined
        assert lines == []
    else:
        (line,) = lines
        assert f"the {kind} model" in line and "about 4.89 independent samples" in line
        assert "held at their prior" in line and "a (the gain" not in line
    for name, joint in cal["fit"]["joints"].items():
        if name == "joint4" and kind != "affine":  # it does not move: c, d held for that
            assert set(joint["held"]) >= {"c", "d"}
        else:
            assert joint.get("held") == held, (name, joint)
    for coefficients in cal["model"]["joints"].values():
        assert 0.5 < coefficients["a"] < 10.0  # the twin's scale: 1.2–1.6, joint 7's 6.3
        assert all(v == 0.0 for v in coefficients.get("theta", []))
        assert abs(coefficients["b"]) < 1.0  # not thousands of N·m


def test_a_fit_holds_theta_where_the_logs_hold_too_few_samples_for_it():
    """θ as a whole (its directions the motion spans), then d, c, a, as the independent
    samples run short; with as many as its coefficients take, nothing is held."""
    from twincd.calibration.excitation import SAMPLES_PER_COEFFICIENT, scarce

    free = np.ones((3, 3), dtype=bool)
    directions = np.array([0, 0, 5])
    held = scarce(free, directions, independent=SAMPLES_PER_COEFFICIENT * 3)
    # 3 coefficients' samples: b, a and c; d held (and the third joint, with θ's 5, all)
    assert held.tolist() == [[False, False, True]] * 2 + [[True, True, True]]
    assert not scarce(free, directions, None).any()  # not known: nothing held for it
    assert not scarce(free, directions, SAMPLES_PER_COEFFICIENT * 9).any()


def test_conditioning():
    rng = np.random.default_rng(0)
    n = 1000
    x = np.column_stack([rng.normal(size=n), 5.0 + 1e-6 * rng.normal(size=n), np.zeros(n)])
    x = np.column_stack([x, x[:, 0] * 2.0 + 1e-9 * rng.normal(size=n)])
    mean = x.mean(axis=0)
    cross = (x - mean).T @ (x - mean)
    share = conditioning(n, mean, cross)
    assert share[1] < 1.0 / CONDITION_LIMIT  # a constant plus noise: the intercept's
    assert share[2] == 0.0  # all zeros
    assert share[0] < 1e-5 and share[3] < 1e-5  # one another's
    alone = conditioning(n, mean[:1], cross[:1, :1])
    assert alone[0] == pytest.approx(np.std(x[:, 0]) / np.sqrt(np.mean(x[:, 0] ** 2)), rel=1e-9)


def test_a_precise_gain_is_determined_even_at_one_level():
    """A twin effort far from zero that varies little but far above the noise still determines
    its gain: holding it takes both."""
    rng = np.random.default_rng(1)
    x = 1e4 + rng.normal(0, 0.5, (2000, 1))
    sol = solve(AffineStats.from_arrays(x, 2 * x + rng.normal(0, 1e-3, (2000, 1))))
    assert not sol.held[0] and sol.a[0] == pytest.approx(2.0, rel=1e-4)
    noisy = solve(AffineStats.from_arrays(x, 2e4 + rng.normal(0, 1.0, (2000, 1))))
    assert noisy.held[0] and noisy.a[0] == 1.0


def test_motion_statistics_merge_exactly_and_refuse_rest():
    rng = np.random.default_rng(2)
    q = np.cumsum(rng.normal(size=(500, 3)), axis=0)
    whole = MotionStats.from_arrays(q)
    parts = MotionStats.from_arrays(q[:123]) + MotionStats.from_arrays(q[123:])
    np.testing.assert_allclose(parts.spread, whole.spread, rtol=1e-12)
    np.testing.assert_allclose(whole.spread, q.std(axis=0), rtol=1e-12)
    check_motion(whole, ("a", "b", "c"))
    rest = MotionStats.from_arrays(0.3 + 1e-5 * rng.normal(size=(500, 3)))
    with pytest.raises(DataError, match="hold no motion"):
        check_motion(rest, ("a", "b", "c"))
