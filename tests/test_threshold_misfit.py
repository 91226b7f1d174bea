"""``threshold`` refuses logs that are not collision-free data the calibration fits (contract:
Exit codes and streams): their score far above the calibration's clean level, or mostly flagged
at the threshold set on them. Before, a threshold set on an arm at rest (median 84.5) or on an
effort three times the training's (the score saturated, σ = 0) was written, and ``detect``
then answered "no collision" where a sane threshold finds the presses."""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import pytest
from support import synthlogs
from support.calibrations import threshold_prepared_logs
from support.clitools import assert_one_line_error, run

from twincd.calibration import Calibration, Threshold
from twincd.calibration.threshold import (
    MISFIT_REFUSED,
    score_log,
)
from twincd.commands import threshold_calibration
from twincd.detection.files import AlarmTally, record_false_alarms
from twincd.errors import DataError
from twincd.prepare.setup import Setup

FORMS = ("mcap", "rosbag2-sqlite3")


@pytest.fixture(scope="module")
def validation(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, list[Path]]]:
    """Per kind (clean, still, effort × 3) and form, two validation paths of the synthetic
    plant the calibrations are fitted on (``xarm_dataset``: its seed)."""
    root = tmp_path_factory.mktemp("validation")
    out: dict[str, dict[str, list[Path]]] = {}
    for i in range(2):
        clean = synthlogs.path("val", i)
        kinds = {
            "clean": clean,
            "still": synthlogs.held(clean),
            "x3": synthlogs.scaled(clean, 3.0),
        }
        for kind, run_ in kinds.items():
            for form in FORMS:
                target = synthlogs.write(run_, root / f"{kind}_{form}_{i}", form)
                out.setdefault(kind, {}).setdefault(form, []).append(target)
    return out


@pytest.fixture(scope="module")
def calibrations(xarm_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The default model (identified-whitened, depth score) and the paper's affine model,
    fitted on the moving arm."""
    root = tmp_path_factory.mktemp("misfit_cals")
    out = {}
    for name, options in (("default", []), ("affine", ["--model", "affine"])):
        out[name] = root / f"{name}.json"
        result = run("fit", xarm_dataset / "train", "-o", out[name], "-q", *options)
        assert result.exit_code == 0, result.output
    return out


def _copy(cal: Path, tmp_path: Path) -> Path:
    target = tmp_path / "cal.json"
    target.write_bytes(cal.read_bytes())
    return target


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["still", "x3"])
def test_the_default_model_refuses_logs_it_does_not_fit(
    calibrations, validation, tmp_path, form, kind
):
    cal = _copy(calibrations["default"], tmp_path)
    before = cal.read_bytes()
    result = run("threshold", *validation[kind][form], "-c", cal)
    assert_one_line_error(result, "these logs are not collision-free data the calibration fits")
    line = result.stderr
    assert "collision-free score has median" in line and "where data the calibration fits" in line
    assert "the residual over the fit's noise: joint" in line
    assert "same payload, effort sign and scale" in line
    assert cal.read_bytes() == before  # nothing written


@pytest.mark.parametrize("form", FORMS)
def test_clean_logs_of_the_moving_arm_are_taken(calibrations, validation, tmp_path, form):
    cal = _copy(calibrations["default"], tmp_path)
    result = run("threshold", *validation["clean"][form], "-c", cal)
    assert result.exit_code == 0, result.output
    assert json.loads(cal.read_text())["threshold"]["value"] > 0


def test_the_refused_logs_score_above_a_sane_threshold(
    calibrations, validation, xarm_dataset, tmp_path
):
    """The case behind the rule: with a threshold from clean logs of the moving arm detect
    finds the presses, and half the still logs' clean samples score above it: a threshold
    set on them would sit above the presses."""
    cal = _copy(calibrations["default"], tmp_path)
    assert run("threshold", *validation["clean"]["mcap"], "-c", cal, "-q").exit_code == 0
    found = run("detect", xarm_dataset / "test", "-c", cal, "--json", "-q")
    assert found.exit_code == 1 and json.loads(found.stdout)["logs"][0]["events"]
    calibration = Calibration.load(cal)
    setup = Setup.from_calibration(calibration)
    still = score_log(validation["still"]["mcap"][0], calibration, setup).stats.robust()[0]
    assert still > calibration.require_threshold().value


def test_the_affine_model_compares_the_residual_with_its_fit(calibrations, validation, tmp_path):
    cal = _copy(calibrations["affine"], tmp_path)
    result = run("threshold", *validation["x3"]["mcap"], "-c", cal)
    assert_one_line_error(result, "score's mean is")
    assert f"more than {MISFIT_REFUSED**2:g}×" in result.stderr
    assert run("threshold", *validation["clean"]["mcap"], "-c", cal).exit_code == 0


def test_every_rule_refuses(calibrations, validation, tmp_path):
    cal = _copy(calibrations["default"], tmp_path)
    for options in (["-k", "4"], ["--false-alarms-per-hour", "10"]):
        result = run("threshold", *validation["x3"]["mcap"], "-c", cal, *options)
        assert_one_line_error(result, "not collision-free data the calibration fits")


def test_the_library_refuses_as_the_cli(calibrations, validation):
    calibration = Calibration.load(calibrations["default"])
    with pytest.raises(DataError, match="not collision-free data the calibration fits"):
        threshold_calibration(validation["still"]["mcap"], calibration)
    done = threshold_calibration(validation["clean"]["mcap"], calibration)
    th = done.calibration.require_threshold()
    assert th.false_alarms is not None and th.judged_s  # counted, as `twincd threshold` does


def test_evaluate_says_it_and_judges(calibrations, validation, caplog):
    """``evaluate --val`` sets a method's threshold as ``threshold`` would: logs that do not
    fit are said in a warning, and the run still judges (its figures show the misfit)."""
    calibration = Calibration.load(calibrations["default"])
    logs = [calibration.prepare(p) for p in validation["x3"]["mcap"]]
    with caplog.at_level(logging.WARNING, logger="twincd"):
        done = threshold_prepared_logs(logs, calibration, 4.0)
    assert "not collision-free data the calibration fits" in caplog.text
    assert done.threshold is not None


def test_a_threshold_that_flags_most_of_its_own_logs_is_refused(calibrations):
    """A score stuck at one level (σ = 0) puts the threshold at μ: it flags its own logs."""
    calibration = Calibration.load(calibrations["default"])
    cal = replace(calibration, threshold=Threshold(4.0, 90.0, 0.0, ("v.mcap",), 1000))
    tallies = [AlarmTally("v.mcap", 0, 10.0, clean_samples=1000, clean_flagged=1000)]
    with pytest.raises(DataError, match="flags 100 % of their collision-free samples"):
        record_false_alarms(cal, tallies)
    fine = [AlarmTally("v.mcap", 0, 10.0, clean_samples=1000, clean_flagged=3)]
    assert record_false_alarms(cal, fine).require_threshold().false_alarms == 0
