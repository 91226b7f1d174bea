"""Signals that cannot be right are named, never answered silently: positions in degrees, an
effort that is zero, constant or of the wrong sign, a URDF edited after ``fit``, a log too short
to judge. Logs are the shipped xArm 7 sample logs rewritten with rosbags' writer (and edited on
the way), and tiny twin logs."""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import build_twin_log
from support.builders import rewrite
from support.clitools import assert_one_line_error, run
from support.robots import xarm_urdf

from twincd.calibration import Calibration
from twincd.errors import CalibrationError
from twincd.signal.checks import SignalChecks

SAMPLES = Path(__file__).resolve().parent.parent / "sample_logs"
CALIBRATION = SAMPLES / "calibration.json"
CLEAN = SAMPLES / "val" / "val_000.mcap"
XARM = tuple(f"joint{i}" for i in range(1, 8))


def detect_json(*args: Any) -> tuple[int, dict[str, Any], str]:
    result = run("detect", *args, "--json")
    return result.exit_code, json.loads(result.stdout), result.stderr


def doubts(warnings: list[str], *words: str) -> list[str]:
    return [w for w in warnings if all(word in w for word in words)]


# ---------------------------------------------------------------- the checks on their own


def test_limits_name_the_joints_and_recognise_degrees() -> None:
    checks = SignalChecks(("a", "b", "c"), {"a": (-2.0, 2.0), "b": (-1.0, 3.0)})
    q = np.array([[-1.5, 0.0, 50.0], [1.9, 2.9, -80.0]])  # c has no limits: never judged
    checks.push(q, np.ones((2, 3)) * [[1.0], [2.0]])
    assert checks.warnings("log") == []
    checks.push(np.degrees(q), None)
    (line,) = checks.warnings("log")
    assert "a -85.94 to 108.9" in line and "b 0 to 166.2" in line and " c " not in line
    assert "look like degrees" in line


def test_out_of_limits_that_are_not_degrees_say_so_differently() -> None:
    checks = SignalChecks(("a",), {"a": (0.0, 1.0)})
    checks.push(np.array([[1.2]]), None)  # 20 % of the range past it: a URDF's approximation
    assert checks.warnings("log") == []
    checks.push(np.array([[-3.0]]), None)  # beyond a turn? no: 3 rad, not degrees
    (line,) = checks.warnings("log")
    assert "a -3 to 1.2" in line and "degrees" not in line and "joint map" in line


def test_zero_and_constant_effort_are_named_per_joint() -> None:
    checks = SignalChecks(("a", "b", "c"), {})
    for c in (1.0, 1.0, 1.5):  # c is constant within each block, not across them
        checks.push(np.zeros((4, 3)), np.array([[0.0, 2.5, c]] * 4))
    (line,) = checks.warnings("log")
    assert "all zero on a and constant on b:" in line


# ---------------------------------------------------------------- detect on edited sample logs


def test_the_untouched_log_gives_no_doubt(tmp_path: Path) -> None:
    log = rewrite(CLEAN, tmp_path / "clean", form="rosbag2-mcap")
    code, doc, _ = detect_json(log, "-c", CALIBRATION)
    assert code == 0 and doc["warnings"] == []
    (entry,) = doc["logs"]
    assert entry["too_short"] is False and entry["judged_samples"] > 0.9 * entry["samples"]


def test_degrees_are_named_never_silent(tmp_path: Path) -> None:
    def degrees(msg: Any) -> None:
        msg.position = np.degrees(msg.position)

    log = rewrite(CLEAN, tmp_path / "deg.mcap", degrees)
    code, doc, stderr = detect_json(log, "-c", CALIBRATION)
    assert code in (0, 1)
    (line,) = doubts(doc["warnings"], "look like degrees")
    assert str(log) in line and "joint2" in line and "joint limits" in line
    assert line in stderr.replace("twincd: warning: ", "")


@pytest.mark.parametrize(
    ("effort", "said"),
    [
        # joints 1 and 7 (every joint's all zero is the drives off: test_read_as_recorded)
        (lambda e: np.where(np.arange(len(e)) % 6 == 0, 0.0, e), "all zero on joint1, joint7"),
        (lambda e: 0.0 * e + 3.0, "constant on joint1"),
    ],
)
def test_zero_or_constant_effort_is_named(
    tmp_path: Path, effort: Callable[[Any], Any], said: str
) -> None:
    def edit(msg: Any) -> None:
        msg.effort = effort(msg.effort)

    _, doc, _ = detect_json(rewrite(CLEAN, tmp_path / "e.mcap", edit), "-c", CALIBRATION)
    (line,) = doubts(doc["warnings"], said)
    assert "joint7" in line


def test_flipped_effort_is_mostly_flagged(tmp_path: Path) -> None:
    def flip(msg: Any) -> None:
        msg.effort = -msg.effort

    log = rewrite(CLEAN, tmp_path / "flip.mcap", flip)
    code, doc, _ = detect_json(log, "-c", CALIBRATION)
    assert code == 1
    (line,) = doubts(doc["warnings"], "judged samples are flagged", "does not fit this log")
    assert str(log) in line and "sign" in line
    # the causal calibration (the chain live detection runs) says the same
    code, doc, _ = detect_json(log, "-c", SAMPLES / "calibration.causal.json")
    assert doubts(doc["warnings"], "does not fit this log")


def test_evaluate_says_a_calibration_does_not_fit_a_log(tmp_path: Path) -> None:
    def flip(msg: Any) -> None:
        msg.effort = -msg.effort

    log = rewrite(SAMPLES / "test" / "test_000.mcap", tmp_path / "flip.mcap", flip)
    result = run("evaluate", log, "-c", CALIBRATION, "--json", "--no-summary")
    assert result.exit_code == 0, result.stderr
    warnings = json.loads(result.stdout)["warnings"]
    # evaluate names the calibration's own model (the shipped one is identified-whitened)
    assert doubts(warnings, str(log), "flagged by identified-whitened", "does not fit this log")


def test_what_twincd_assumes_is_said(tmp_path: Path) -> None:
    def no_velocity_no_stamp(msg: Any) -> None:
        msg.velocity = np.zeros(0)
        msg.header.stamp.sec = msg.header.stamp.nanosec = 0

    log = rewrite(CLEAN, tmp_path / "bare.mcap", no_velocity_no_stamp)
    code, doc, _ = detect_json(log, "-c", CALIBRATION)
    assert code == 0
    assert doubts(doc["warnings"], "velocity missing on joint1", "differentiated from position")
    assert doubts(doc["warnings"], "carry no header stamp", "log time")


# ---------------------------------------------------------------- a URDF edited after fit


def _xarm_urdf(folder: Path) -> Path:
    from twincd.twin.robot import resolve_urdf

    folder.mkdir()
    return Path(shutil.copy(resolve_urdf("xarm7"), folder / "xarm7.urdf"))


def test_a_urdf_edited_after_fit_is_refused_unless_allowed(tmp_path: Path) -> None:
    """An edit of what the twin uses (link1's mass; the fixed base's inertia would not be):
    other dynamics than the calibration's, refused unless allowed."""
    urdf = _xarm_urdf(tmp_path / "robot")
    cal = tmp_path / "cal.json"
    train = [SAMPLES / "train" / f"train_00{i}.mcap" for i in range(3)]
    assert run("fit", *train, "--robot", urdf, "-o", cal, "-q", "-j", "1").exit_code == 0
    assert run("threshold", SAMPLES / "val", "-c", cal, "-q", "-j", "1").exit_code == 0
    assert run("detect", CLEAN, "-c", cal, "-q").exit_code == 0
    xarm_urdf(urdf, heavier=True)

    for command in (("detect", CLEAN), ("threshold", SAMPLES / "val", "-o", tmp_path / "t.json")):
        result = run(*command, "-c", cal, "-j", "1")
        assert_one_line_error(result, match="other dynamics than the calibration was fitted with")
        assert str(urdf) in result.stderr and "--allow-urdf-change" in result.stderr
    result = run("evaluate", SAMPLES / "test" / "test_000.mcap", "-c", cal, "--no-summary")
    assert_one_line_error(result, match=str(urdf))

    code, doc, _ = detect_json(CLEAN, "-c", cal, "--allow-urdf-change")
    assert code in (0, 1)
    (line,) = doubts(doc["warnings"], "other dynamics than the calibration was fitted with")
    assert str(urdf) in line and str(CLEAN) in line


def test_the_live_detector_checks_the_urdf(caplog: pytest.LogCaptureFixture) -> None:
    from twincd.detection import OnlineDetector

    # a file of the release before, which records the URDF file's sha256 only
    cal = Calibration.load(SAMPLES.parent / "tests/data/calibrations_v2/calibration.causal.json")
    assert cal.dynamics_sha256 is None
    OnlineDetector(cal)  # the URDF it was fitted with
    edited = replace(cal, urdf_sha256="0" * 64)
    with pytest.raises(CalibrationError, match="changed since the calibration was fitted"):
        OnlineDetector(edited)
    with caplog.at_level(logging.WARNING, logger="twincd"):
        OnlineDetector(edited, allow_urdf_change=True, source="arm")
    assert [r.getMessage() for r in caplog.records if "changed" in r.getMessage()]
    OnlineDetector(replace(cal, urdf_sha256=None))  # an old file without a sha256: not checked
    with pytest.raises(CalibrationError, match="other dynamics"):  # a file of this version
        OnlineDetector(replace(cal, dynamics_sha256="0" * 64))


# ---------------------------------------------------------------- a log near its ends throughout


def test_a_log_near_its_ends_throughout_is_judged_and_said_to_be_short(
    tmp_path: Path, twin_calibration: Path
) -> None:
    from twincd.prepare.notices import edges_s
    from twincd.signal.filters import LowPass

    cal = Calibration.load(twin_calibration)
    near = edges_s(cal.lowpass, 0.01)  # both ends' stretch of ≥ 1.5× the middle's noise
    assert 0.2 < near < 1.0  # 20 samples at least: fewer, and a log is refused
    log = build_twin_log(tmp_path / "short.mcap", seconds=near, labels=False)
    code, doc, _ = detect_json(log, "-c", twin_calibration)
    assert code == 0
    (entry,) = doc["logs"]
    assert entry["too_short"] is False and entry["judged_samples"] == entry["samples"] > 0
    (line,) = doubts(doc["warnings"], "judged less sensitively")
    assert "is short" in line and str(log) in line
    plain = run("detect", log, "-c", twin_calibration)
    assert "no collision" in plain.stdout and "judged less sensitively" in plain.stderr
    causal = LowPass(causal=True)  # near its start only
    assert edges_s(causal, 0.01) > 0
