"""``twincd inspect``: what a log holds and what twincd will make of it, without the twin."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.builders import SUFFIX, XARM, Message, joint_recording, joint_state, write
from support.clitools import run
from support.robots import xarm_urdf

from twincd.calibration import Calibration
from twincd.commands.inspection import inspect_log

SAMPLE = Path(__file__).parents[1] / "sample_logs"
PANDA = (
    *tuple(f"panda_joint{i}" for i in range(1, 8)),
    "panda_finger_joint1",
    "panda_finger_joint2",
)


def test_sample_log_is_usable_and_described():
    found = inspect_log(SAMPLE / "test" / "test_000.mcap")
    assert found.usable and found.joint_topic == "/joint_states"
    assert found.matched == XARM and not found.ignored and not found.locked
    assert [s.joints for s in found.joint_sets] == [XARM]
    assert found.sampling is not None and found.sampling.rate_hz == pytest.approx(100.0)
    assert found.sampling.gaps == 0 and found.label_messages > 0
    assert "link4" in found.link_labels
    # every joint within its limits, with a non-trivial effort
    for j in found.joints:
        if j.lower_limit is not None and j.upper_limit is not None:
            assert j.lower_limit <= j.position_min <= j.position_max <= j.upper_limit
        assert j.effort_std is not None and j.effort_std > 0


@pytest.mark.parametrize("form", ["mcap", "ros1"])
def test_panda_shaped_log_names_the_ignored_finger_joints(tmp_path, form):
    n = 300
    effort = np.random.default_rng(0).normal(0, 1, (n, len(PANDA)))
    msgs = joint_recording(n=n, names=PANDA, effort=effort)
    log = write(tmp_path / f"panda{'.bag' if form == 'ros1' else '.mcap'}", form, msgs)
    result = run("inspect", log, "--robot", "panda", "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)["logs"][0]
    assert doc["usable"] and doc["matched"] == list(PANDA[:7])
    assert doc["ignored"] == ["panda_finger_joint1", "panda_finger_joint2"]
    assert doc["sampling"]["samples"] == n
    assert doc["sampling"]["rate_hz"] == pytest.approx(100.0)


@pytest.mark.parametrize("form", ["mcap", "rosbag2-sqlite3"])
def test_without_a_calibration_inspect_names_the_robot_model(tmp_path, form):
    """``--robot`` and no calibration: the ignored joints are those the robot model lacks, as
    detect says it (before: "not in the calibration")."""
    names = (*XARM, "drive_joint")
    effort = np.random.default_rng(1).normal(0, 1, (300, len(names)))
    log = write(
        tmp_path / ("grip.mcap" if form == "mcap" else "grip"),
        form,
        joint_recording(n=300, names=names, effort=effort),
    )
    result = run("inspect", log, "--robot", "xarm7", "--json")
    assert result.exit_code == 0, result.output
    warnings = json.loads(result.stdout)["logs"][0]["warnings"]
    assert any("ignoring 1 log joint(s) not in the robot model: drive_joint" in w for w in warnings)
    assert not any("not in the calibration" in w for w in warnings), warnings


def test_gaps_and_two_joint_sets_are_counted(tmp_path):
    msgs = joint_recording(n=400, effort=np.ones((400, 7)))
    del msgs[200:260]  # a 0.6 s gap
    gripper = [
        Message(
            "/joint_states",
            m.msgtype,
            m.log_time + 1,
            joint_state(m.log_time + 1, ["drive_joint"], [0.1]),
        )
        for m in msgs[::10]
    ]
    log = write(tmp_path / "cell.mcap", "mcap", sorted(msgs + gripper, key=lambda m: m.log_time))
    found = inspect_log(log)
    assert {s.joints: s.messages for s in found.joint_sets} == {XARM: 340, ("drive_joint",): 34}
    assert found.sampling is not None and found.sampling.gaps == 1
    assert found.sampling.largest_gap_s == pytest.approx(0.61)
    assert found.ignored == ("drive_joint",)


def test_calibration_joints_missing_is_unusable_exit_2(tmp_path):
    names = XARM[:6]
    log = write(
        tmp_path / "six.mcap", "mcap", joint_recording(names=names, effort=np.ones((400, 6)))
    )
    result = run("inspect", log, "-c", SAMPLE / "calibration.json")
    assert result.exit_code == 2
    assert "joint7" in result.stderr and result.stderr.count("twincd: error:") == 1
    assert "NOT usable" in result.stdout


def test_unreadable_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not a log")
    result = run("inspect", bad)
    assert result.exit_code == 2 and result.stderr.startswith("twincd: error:")
    assert "Traceback" not in result.output


def test_text_report_names_what_a_user_needs(tmp_path):
    result = run("inspect", SAMPLE / "test" / "test_000.mcap")
    assert result.exit_code == 0
    for words in ("/joint_states", "matched: joint1", "100 Hz", "labels: ", "→ usable"):
        assert words in result.stdout


def test_warnings_detect_would_give_are_listed_with_the_log(tmp_path):
    """Degrees, a gripper node's messages and a missing velocity: each said once, in the
    inspection, not only on stderr."""
    n = 400
    msgs = joint_recording(n=n, effort=np.ones((n, 7)) + np.arange(n)[:, None] * 1e-3)
    for m in msgs:
        m.msg.position = m.msg.position * 180 / np.pi  # logged in degrees
        m.msg.velocity = np.zeros(0)
    gripper = [
        Message(m.topic, m.msgtype, m.log_time + 1, joint_state(m.log_time + 1, ["g1"], [0.0]))
        for m in msgs[::4]
    ]
    log = write(tmp_path / "odd.mcap", "mcap", sorted(msgs + gripper, key=lambda m: m.log_time))
    found = inspect_log(log)
    text = "\n".join(found.warnings)
    assert found.usable and found.robot_is_default
    assert "look like degrees" in text and "velocity missing" in text
    assert "ignoring 100 message(s)" in text, text
    result = run("inspect", log, "--json")
    assert result.exit_code == 0 and result.stderr == ""
    assert json.loads(result.stdout)["warnings"] == found.warnings


def test_a_urdf_of_other_dynamics_makes_the_log_unusable(tmp_path):
    """Judged by content: a comment added changes nothing the twin uses; a link's mass
    does."""
    urdf = xarm_urdf(tmp_path / "arm.urdf")
    log = write(tmp_path / "run.mcap", "mcap", joint_recording(effort=np.ones((400, 7))))
    cal = tmp_path / "cal.json"
    assert run("fit", log, "--robot", urdf, "-o", cal, "-q").exit_code == 0
    assert inspect_log(log, robot=str(urdf)).usable
    xarm_urdf(urdf, comment=True)
    assert run("inspect", log, "-c", cal).exit_code == 0
    xarm_urdf(urdf, heavier=True)
    result = run("inspect", log, "-c", cal)
    assert result.exit_code == 2 and "other dynamics than the calibration" in result.stderr


def test_a_log_cut_before_its_first_joint_state_says_so(tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes((SAMPLE / "test" / "test_000.mcap").read_bytes()[:3000])
    found = inspect_log(cut)
    assert not found.usable and "no readable messages" in str(found.problem)
    assert any("damaged" in w for w in found.warnings)
    result = run("inspect", cut)
    assert result.exit_code == 2 and result.stderr.count("twincd: error:") == 1


@pytest.mark.parametrize("form", ["mcap", "rosbag2-sqlite3"])
def test_a_log_sampled_over_the_gap_rule_below_the_calibration_is_refused_alike(tmp_path, form):
    """Sampled every 60 ms against the calibration's 10 ms, every interval is a gap: no sample
    can be judged, so detect refuses the log (exit 2, not events on one-sample segments) and
    inspect calls it unusable in the same words. Every 20 ms is judged, said; so is a log
    whose first 10 s only are that slow (the rest judged, the slow start not)."""
    cal = SAMPLE / "calibration.json"
    fast = joint_recording(n=3000, effort=np.ones((3000, 7)) + np.arange(3000)[:, None] * 1e-3)
    logs = {
        "every_60ms": (joint_recording(n=500, period_ns=60_000_000, effort=np.ones((500, 7))), 1),
        "every_20ms": (joint_recording(n=1500, period_ns=20_000_000, effort=np.ones((1500, 7))), 0),
        "slow_start": ([*fast[:1000:6], *fast[1000:]], 0),
    }
    for name, (msgs, refused) in logs.items():
        log = write(tmp_path / f"{name}{SUFFIX[form]}", form, msgs)
        found = inspect_log(log, calibration=Calibration.load(cal))
        detected = run("detect", log, "-c", cal, "--json")
        if refused:
            words = f"{len(msgs) - 1} of the {len(msgs) - 1} intervals between its samples are gaps"
            assert not found.usable and found.problem is not None and words in found.problem
            assert detected.exit_code == 2 and detected.stdout == ""
            assert found.problem in detected.stderr
            copy = tmp_path / "cal.json"
            copy.write_bytes(cal.read_bytes())
            for refusal in (run("threshold", log, "-c", copy), run("evaluate", log, "-c", cal)):
                assert refusal.exit_code == 2 and found.problem in refusal.stderr
            assert copy.read_bytes() == cal.read_bytes()
            continue
        assert found.usable, found.problem
        assert detected.exit_code in (0, 1), detected.stderr
        spans = json.loads(detected.stdout)["logs"][0]["unjudged_spans"]
        if name == "every_20ms":
            assert "sampled every 20 ms" in detected.stderr and spans == []
        else:  # the slow start's 166 intervals are gaps, then every sample lies together
            assert len(spans) == 166 and spans[-1][1] == pytest.approx(9.96)
