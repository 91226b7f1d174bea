"""A calibration travels (contract: Robot models, The calibration file, The library does what
the CLI does): what it learned (the robot's dynamics, the joints after the map, the filter, the
model, the threshold) is judged by content; how a recording is read (topics, the joint map or
prefix, the URDF's path) is each run's, the calibration's recorded values only its defaults.
One arm of a two-arm bag, test logs labelled on another topic and a URDF that moved are read
with options, not by editing JSON."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path
from typing import Any

import pytest
from support.arms import left_arm_alone, messages_of, retopic, two_arm_bag
from support.builders import write
from support.clitools import assert_one_line_error, run
from support.robots import xarm_urdf

import twincd
from twincd.defaults import DEFAULT_LABEL_TOPIC

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs"
PREFIX_MAP = ",".join(f"left_joint{i}=joint{i}" for i in range(1, 8))


@pytest.fixture(scope="module")
def moved(xarm_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A calibration fitted (and thresholded) with the xArm URDF at ``urdf``, on
    ``xarm_dataset``; the URDF then moved to ``new`` (byte for byte), its old path gone."""
    root = tmp_path_factory.mktemp("moved")
    urdf = xarm_urdf(root / "robots" / "arm.urdf")
    cal = root / "cals" / "cal.json"
    cal.parent.mkdir()
    fitted = run("fit", xarm_dataset / "train", "--robot", urdf, "-o", cal, "-q")
    assert fitted.exit_code == 0, fitted.output
    assert run("threshold", xarm_dataset / "val", "-c", cal, "-q").exit_code == 0
    log = xarm_dataset / "test" / "test_000.mcap"
    reference = root / "reference.json"
    found = run("detect", log, "-c", cal, "--json", "--no-summary", "-q")
    assert found.exit_code in (0, 1), found.output
    reference.write_text(found.stdout)
    new = root / "elsewhere" / "xarm.urdf"
    new.parent.mkdir()
    shutil.move(urdf, new)
    return {"cal": cal, "urdf": urdf, "new": new, "log": log, "reference": reference}


def _detected(*args: Any) -> list[dict[str, Any]]:
    """``twincd detect ARGS --json``'s logs, their paths left out, once it answered."""
    result = run("detect", *args, "--json", "--no-summary")
    assert result.exit_code in (0, 1), result.output
    return [
        {k: v for k, v in log.items() if k != "path"} for log in json.loads(result.stdout)["logs"]
    ]


def _reference(moved: dict[str, Path]) -> list[dict[str, Any]]:
    doc = json.loads(moved["reference"].read_text())
    return [{k: v for k, v in log.items() if k != "path"} for log in doc["logs"]]


def test_a_moved_urdf_is_found_by_robot_and_beside_the_calibration(moved, tmp_path):
    """Before: "URDF file not found", and ``--robot NEW_PATH`` "contradicts the
    calibration's …". Now the URDF is the run's: given, or found beside the calibration."""
    cal, log = moved["cal"], moved["log"]
    lost = run("detect", log, "-c", cal)
    assert_one_line_error(lost, "the calibration's robot URDF is not found on this machine")
    assert "put arm.urdf beside the calibration" in lost.stderr and "--robot" in lost.stderr
    assert _detected(log, "-c", cal, "--robot", moved["new"]) == _reference(moved)
    # the calibration on another machine, its URDF beside it
    travelled = tmp_path / "ci" / "cal.json"
    travelled.parent.mkdir()
    shutil.copy(cal, travelled)
    shutil.copy(moved["new"], travelled.parent / "arm.urdf")
    assert _detected(log, "-c", travelled) == _reference(moved)
    # the library alike
    summary = twincd.detect_file(log, cal, robot=str(moved["new"]), step_summary=False)
    assert [{k: v for k, v in summary.to_dict().items() if k != "path"}] == _reference(moved)


def test_the_robot_is_judged_by_its_dynamics_not_its_file(moved, tmp_path):
    """A URDF edited where the twin does not look (a comment) is the same robot; one whose
    link is heavier is not (refused, unless allowed)."""
    cal, log = moved["cal"], moved["log"]
    commented = xarm_urdf(tmp_path / "commented.urdf", comment=True)
    assert _detected(log, "-c", cal, "--robot", commented) == _reference(moved)
    heavier = xarm_urdf(tmp_path / "heavier.urdf", heavier=True)
    refused = run("detect", log, "-c", cal, "--robot", heavier)
    assert_one_line_error(refused, "has other dynamics than the calibration was fitted with")
    allowed = run("detect", log, "-c", cal, "--robot", heavier, "--allow-urdf-change", "-q")
    assert allowed.exit_code in (0, 1), allowed.output
    recorded = json.loads(cal.read_text())["robot"]
    assert recorded["name"] == str(moved["urdf"]) and len(recorded["dynamics_sha256"]) == 64
    panda = run("detect", log, "-c", cal, "--robot", "panda")
    assert_one_line_error(panda, "no joint of the log is in the robot model")


def test_a_calibration_that_records_the_file_s_sha256_is_checked_the_old_way(
    moved, tmp_path, caplog
):
    """Files written before the dynamics' hash (every /1 and /2 file until now) load, with one
    note, and are checked by the URDF file's bytes: a byte-identical file anywhere passes, a
    comment added does not."""
    old = json.loads(moved["cal"].read_text())
    del old["robot"]["dynamics_sha256"]
    legacy = tmp_path / "legacy.json"
    legacy.write_text(json.dumps(old))
    with caplog.at_level(logging.INFO, logger="twincd"):
        twincd.Calibration.load(legacy)
    notes = [r.getMessage() for r in caplog.records if "byte for byte" in r.getMessage()]
    assert len(notes) == 1 and r"re-fit it" in notes[0] and caplog.records[0].levelno < 30
    log = moved["log"]
    assert _detected(log, "-c", legacy, "--robot", moved["new"]) == _reference(moved)
    commented = xarm_urdf(tmp_path / "commented.urdf", comment=True)
    refused = run("detect", log, "-c", legacy, "--robot", commented, "-q")
    assert_one_line_error(refused, "changed since the calibration was fitted")
    v2 = SAMPLE.parent / "tests" / "data" / "calibrations_v2" / "calibration.json"  # a /2 file
    shipped = run("detect", SAMPLE / "test" / "test_000.mcap", "-c", v2)
    assert "checked byte for byte" in shipped.stderr
    assert "warning" not in shipped.stderr  # a note, not a warning: --json's are unchanged


def test_a_package_uri_finds_the_urdf(moved, xarm_dataset, tmp_path, monkeypatch):
    """A URDF inside a ROS package (on ROS_PACKAGE_PATH) is recorded by its package:// URI
    too, and found by it on a machine where the package lies elsewhere; --robot takes a
    package:// URI."""
    packages = tmp_path / "ws"
    urdf = xarm_urdf(packages / "my_arm_description" / "urdf" / "arm.urdf")
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(packages))
    cal = tmp_path / "cal.json"
    assert run("fit", xarm_dataset / "train", "--robot", urdf, "-o", cal, "-q").exit_code == 0
    assert run("threshold", xarm_dataset / "val", "-c", cal, "-q").exit_code == 0
    recorded = json.loads(cal.read_text())["robot"]
    assert recorded["package"] == "package://my_arm_description/urdf/arm.urdf"
    elsewhere = tmp_path / "other_ws"
    shutil.move(packages, elsewhere)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(elsewhere))
    log = moved["log"]
    by_package = _detected(log, "-c", cal)
    assert by_package == _detected(
        log, "-c", cal, "--robot", "package://my_arm_description/urdf/arm.urdf"
    )
    assert by_package == _reference(moved)
    missing = run("detect", log, "-c", cal, "--robot", "package://nothing_here/urdf/arm.urdf")
    assert_one_line_error(missing, "URDF not found in any installed package")


@pytest.mark.parametrize("form", ["rosbag2-mcap", "rosbag2-sqlite3", "mcap"])
def test_one_arm_of_a_two_arm_bag_is_read_with_the_topic_and_a_joint_prefix(
    moved, xarm_dataset, tmp_path, form
):
    """Before: with a calibration fitted on the unprefixed arm, ``--topic /left/joint_states
    --joint-map …`` "contradicts the calibration's /joint_states"; only editing the JSON
    worked. Now the left arm reads as that arm logged alone, by a prefix or a joint map."""
    cal = moved["cal"]
    left, right = moved["log"], xarm_dataset / "val" / "val_000.mcap"
    bag = two_arm_bag(tmp_path / "two_arms", left, right, form)
    alone = _detected(
        left_arm_alone(tmp_path / "alone", left, form), "-c", cal, "--robot", moved["new"]
    )
    asked = ("-c", cal, "--robot", moved["new"], "--topic", "/left/joint_states")
    assert _detected(bag, *asked, "--joint-prefix", "left_") == alone
    assert _detected(bag, *asked, "--joint-map", PREFIX_MAP) == alone
    several = run("detect", bag, "-c", cal, "--robot", moved["new"])
    assert_one_line_error(several, "several JointState topics")
    unprefixed = run("detect", bag, *asked)
    assert unprefixed.exit_code == 2 and "joint" in unprefixed.stderr
    nothing = run("detect", bag, *asked, "--joint-prefix", "arm_")
    assert_one_line_error(nothing, "joint prefix arm_ matches no joint of the logs")


def test_a_fit_on_one_arm_records_how_it_was_read(xarm_dataset, tmp_path):
    """fit on the left arms of two-arm bags records the topic and the prefix as the
    calibration's defaults: later runs on such bags need no option."""
    train = sorted((xarm_dataset / "train").glob("*.mcap"))
    bags = [two_arm_bag(tmp_path / f"bag{i}", log, train[0]) for i, log in enumerate(train)]
    cal = tmp_path / "cal.json"
    asked = ("--topic", "/left/joint_states", "--joint-prefix", "left_")
    assert run("fit", *bags, *asked, "-o", cal, "-q").exit_code == 0
    options = json.loads(cal.read_text())["log_options"]
    assert options["topic"] == "/left/joint_states" and options["joint_prefix"] == "left_"
    assert json.loads(cal.read_text())["robot"]["joint_names"][0] == "joint1"
    val = two_arm_bag(tmp_path / "val", xarm_dataset / "val" / "val_000.mcap", train[0])
    assert run("threshold", val, "-c", cal, "-q").exit_code == 0


@pytest.fixture(scope="module")
def relabelled(moved, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The test log with its labels on ``/collision`` (as rosbag2 MCAP, rosbags' writer)."""
    root = tmp_path_factory.mktemp("relabelled")
    msgs = retopic(messages_of(moved["log"]), {DEFAULT_LABEL_TOPIC: "/collision"})
    return write(root / "test_on_collision", "rosbag2-mcap", msgs)


def _evaluated(*args: Any) -> dict[str, Any]:
    result = run("evaluate", *args, "--json", "--no-summary")
    assert result.exit_code == 0, result.output
    doc: dict[str, Any] = json.loads(result.stdout)
    return {"samples": doc["samples"], "positives": doc["positives"], "methods": doc["methods"]}


def test_test_logs_labelled_on_another_topic_are_judged_with_evaluate_label_topic(
    moved, relabelled, xarm_dataset, tmp_path
):
    """Fit logs clean and unlabelled, test logs labelled on /collision. Before: evaluate said
    "no collision labels", ``--label-topic /collision`` "contradicts the calibration's
    /collision_flag", and fit refused the topic its logs lack. Now evaluate takes it, and
    judges as on the same log labelled on the calibration's topic; a topic named that no
    log has is still an error."""
    robot = ("--robot", moved["new"])
    same = _evaluated(moved["log"], "-c", moved["cal"], *robot)
    taken = _evaluated(relabelled, "-c", moved["cal"], *robot, "--label-topic", "/collision")
    for row in (*same["methods"], *taken["methods"]):
        row.pop("train_s"), row.pop("test_s")
    assert taken == same and same["positives"] > 0
    unlabelled = run("evaluate", relabelled, "-c", moved["cal"], *robot, "--json", "-q")
    assert_one_line_error(unlabelled, "the log has no collision labels")
    assert "(option --label-topic)" in unlabelled.stderr
    refused = run(
        "fit", xarm_dataset / "train", "--label-topic", "/collision", "-o", tmp_path / "c.json"
    )
    assert_one_line_error(refused, "label topic /collision is in none of the logs")
    assert not (tmp_path / "c.json").exists()


def test_a_named_link_topic_that_matches_nothing_is_an_error(moved, xarm_dataset, tmp_path):
    """The link topic is a reading option like the others: recorded by fit, overridable, and
    refused when named and absent."""
    cal = tmp_path / "cal.json"
    refused = run("fit", xarm_dataset / "train", "--link-topic", "/touched", "-o", cal)
    assert_one_line_error(refused, "link topic /touched is in none of the logs")
    assert json.loads(moved["cal"].read_text())["log_options"]["link_topic"] == "/collision_link"
