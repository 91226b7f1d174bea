"""Every option the user names is honoured or refused (contract: Inputs, Exit codes and streams):
a named topic or joint-map entry that matches nothing in any of the run's logs is an error; one
that matches in some logs is honoured there with one warning naming the others; defaults that
match nothing are no error; the default robot model is not silently reduced onto another arm."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.builders import XARM, Bool, Message, String, joint_recording, write_by
from support.clitools import assert_one_line_error, run

from twincd.errors import TopicError, UsageError

WRITERS = ["rosbags", "twincd"]
SIX = tuple(f"joint{i}" for i in range(1, 7))
UR5 = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)


def arm_log(
    path: Path,
    writer: str,
    names: tuple[str, ...] = XARM,
    seed: int = 0,
    twin_topic: str | None = None,
    label_topic: str | None = None,
) -> Path:
    """An arm's joint states with effort (4 s at 100 Hz); with ``twin_topic``, its controller's
    model effort logged there (what ``--sim-topic`` reads); with ``label_topic``, labels."""
    rng = np.random.default_rng(seed)
    effort = rng.normal(size=(400, len(names)))
    msgs = joint_recording(n=400, names=names, effort=effort, seed=seed)
    if twin_topic is not None:
        twin = joint_recording(n=400, names=names, effort=0.9 * effort, seed=seed, topic=twin_topic)
        msgs = [m for pair in zip(msgs, twin, strict=True) for m in pair]
    if label_topic is not None:
        msgs.append(
            Message(label_topic, "std_msgs/msg/Bool", msgs[0].log_time - 1, Bool(data=False))
        )
    return write_by(writer, path, msgs)


# ---------------------------------------------------------------- a named option matching nothing


@pytest.mark.parametrize("writer", WRITERS)
def test_a_mistyped_sim_topic_is_refused_not_simulated(tmp_path, writer):
    logs = [arm_log(tmp_path / f"a{i}.mcap", writer, seed=i, twin_topic="/controller/model_effort")
            for i in range(2)]  # fmt: skip
    result = run("fit", *logs, "--sim-topic", "/controller/model_efort", "-o", tmp_path / "c.json")
    assert_one_line_error(result, "simulated effort topic /controller/model_efort")
    assert "/controller/model_effort" in result.stderr and "--sim-topic" in result.stderr
    assert not (tmp_path / "c.json").exists()
    # spelled right, it is used: no robot model needed
    ok = run("fit", *logs, "--sim-topic", "/controller/model_effort", "-o", tmp_path / "c.json")
    assert ok.exit_code == 0, ok.output
    assert json.loads((tmp_path / "c.json").read_text())["robot"]["simulated"] is False


@pytest.mark.parametrize(
    ("option", "value", "match"),
    [
        ("--topic", "/arm/joint_states", "joint-state topic /arm/joint_states"),
        ("--label-topic", "/colision_flag", "label topic /colision_flag"),
        ("--joint-map", "joint_1=joint1", "joint map entry joint_1=joint1"),
        ("--joint-prefix", "left_", "joint prefix left_ matches no joint"),
        ("--link-topic", "/touched", "link topic /touched"),
    ],
)
@pytest.mark.parametrize("command", ["fit", "threshold", "inspect", "simulate"])
def test_every_named_option_that_matches_nothing_is_an_error(
    tmp_path, option, value, match, command
):
    log = arm_log(tmp_path / "a.mcap", "rosbags", label_topic="/collision_flag")
    args = {
        "fit": ["-o", tmp_path / "c.json"],
        "threshold": ["-c", tmp_path / "cal.json"],
        "inspect": [],
        "simulate": ["-o", tmp_path / "a.twin.mcap"],
    }[command]
    if command == "threshold":  # a calibration that recorded the option as named
        fitted = arm_log(tmp_path / "f.mcap", "rosbags", names=XARM, seed=3)
        _renamed(fitted, tmp_path / "f2.mcap", option, value)
        assert run("fit", tmp_path / "f2.mcap", option, value, "-o", tmp_path / "cal.json",
                   "--model", "affine").exit_code == 0  # fmt: skip
    result = run(command, log, option, value, *args)
    assert_one_line_error(result, match)


def _renamed(source: Path, target: Path, option: str, value: str) -> None:
    """``source`` with the named topic (or the joint) that ``option value`` asks for."""
    from rosbags.highlevel import AnyReader

    old, _, new = value.partition("=")
    msgs = []
    with AnyReader([source]) as reader:
        for c, t, raw in reader.messages():
            msg = reader.deserialize(raw, c.msgtype)
            topic = c.topic
            if option == "--topic" and topic == "/joint_states":
                topic = value
            if option == "--label-topic" and topic == "/collision_flag":
                topic = value
            if option == "--joint-map" and c.msgtype.endswith("JointState"):
                msg.name = [old if n == new else n for n in msg.name]
            if option == "--joint-prefix" and c.msgtype.endswith("JointState"):
                msg.name = [value + n for n in msg.name]
            msgs.append(Message(topic, c.msgtype, t, msg))
    if option == "--label-topic" and not any(m.topic == value for m in msgs):
        msgs.append(Message(value, "std_msgs/msg/Bool", msgs[0].log_time - 1, Bool(data=False)))
    if option == "--link-topic":
        msgs.append(Message(value, "std_msgs/msg/String", msgs[0].log_time - 1, String(data="")))
    write_by("rosbags", target, msgs)


def test_detect_refuses_a_named_topic_its_log_lacks(tmp_path):
    fitted = arm_log(tmp_path / "f.mcap", "rosbags", seed=3)
    _renamed(fitted, tmp_path / "f2.mcap", "--topic", "/arm/joint_states")
    cal = tmp_path / "cal.json"
    args = ["--topic", "/arm/joint_states"]
    assert run("fit", tmp_path / "f2.mcap", *args, "-o", cal, "--model", "affine").exit_code == 0
    assert run("threshold", tmp_path / "f2.mcap", *args, "-c", cal, "-k", "4").exit_code == 0
    log = arm_log(tmp_path / "a.mcap", "twincd")  # on /joint_states
    assert_one_line_error(run("detect", log, "-c", cal, *args), "/arm/joint_states")
    # not named: the calibration's topic, and the log's only JointState topic, as before
    assert run("detect", log, "-c", cal).exit_code in (0, 1)


def test_evaluate_refuses_a_named_link_topic_no_test_log_has(twin_calibration, twin_dataset):
    test = twin_dataset / "test" / "test_0.mcap"
    result = run("evaluate", test, "-c", twin_calibration, "--link-topic", "/colision_link")
    assert_one_line_error(result, "link topic /colision_link")
    # the default link topic, absent, is no error
    assert run("evaluate", test, "-c", twin_calibration, "-q").exit_code == 0


@pytest.mark.parametrize("writer", WRITERS)
def test_a_named_option_some_logs_lack_is_honoured_where_it_matches(tmp_path, writer):
    with_labels = arm_log(tmp_path / "a.mcap", writer, seed=0, label_topic="/my_flags")
    without = arm_log(tmp_path / "b.mcap", writer, seed=1)
    result = run(
        "fit", with_labels, without, "--label-topic", "/my_flags", "-o", tmp_path / "c.json"
    )
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.stderr.splitlines() if "label topic /my_flags" in ln]
    assert len(lines) == 1 and "b.mcap" in lines[0] and "a.mcap" not in lines[0]
    assert (
        json.loads((tmp_path / "c.json").read_text())["log_options"]["label_topic"] == "/my_flags"
    )


def test_a_default_label_topic_absent_is_no_error(tmp_path):
    logs = [arm_log(tmp_path / f"a{i}.mcap", "rosbags", seed=i) for i in range(2)]
    result = run("fit", *logs, "-o", tmp_path / "c.json")
    assert result.exit_code == 0, result.output
    assert "label topic" not in result.stderr.replace("no collision labels", "")


def test_the_library_refuses_a_named_option_alike(tmp_path):
    from twincd import SetupOptions, fit_calibration
    from twincd.prepare.setup import read_log  # noqa: F401 - the library's reader

    log = arm_log(tmp_path / "a.mcap", "twincd", twin_topic="/controller/model_effort")
    with pytest.raises(TopicError, match="simulated effort topic /controller/model_efort"):
        fit_calibration([log], sim_topic="/controller/model_efort")
    # one log read alone (the block stream): refused by the reader itself
    setup = SetupOptions(label_topic="/nope").resolve()
    with (
        pytest.raises(TopicError, match="label topic /nope is not in the log"),
        setup.open(log) as s,
    ):
        list(s)
    with pytest.raises(UsageError, match="joint map entry j9=joint1"):
        fit_calibration([log], joint_map={"j9": "joint1"})
    with pytest.raises(UsageError, match="joint prefix left_ matches no joint of the log"):
        fit_calibration([log], joint_prefix="left_")


def test_of_several_renamings_the_one_that_matches_nothing_is_named(tmp_path):
    """A joint prefix that matches one log and a joint-map entry that matches none: the entry
    is the error, and its own words say so (not the prefix's)."""
    prefixed = tmp_path / "left.mcap"
    _renamed(arm_log(tmp_path / "a.mcap", "rosbags"), prefixed, "--joint-prefix", "left_")
    plain = arm_log(tmp_path / "b.mcap", "rosbags", seed=1)
    asked = ("--joint-prefix", "left_", "--joint-map", "j9=joint1", "-o", tmp_path / "c.json")
    result = run("fit", prefixed, plain, *asked)
    assert_one_line_error(result, "joint map entry j9=joint1 matches no joint of the logs")
    assert "(option --joint-map)" in result.stderr


# ---------------------------------------------------------------- the default robot


@pytest.mark.parametrize("writer", WRITERS)
def test_the_default_robot_on_another_arm_is_an_error_that_says_to_name_it(tmp_path, writer):
    six = arm_log(tmp_path / "six.mcap", writer, names=SIX)
    for command, args in (
        ("fit", ["-o", tmp_path / "c.json"]),
        ("simulate", ["-o", tmp_path / "six.twin.mcap"]),
    ):
        result = run(command, six, *args)
        assert_one_line_error(result, "not those of the default xarm7 (it lacks joint7)")
        assert "--robot" in result.stderr
    inspected = run("inspect", six)
    assert inspected.exit_code == 2 and "NOT usable" in inspected.stdout
    assert not (tmp_path / "c.json").exists()


def test_no_robot_is_needed_for_a_logged_twin_effort_or_a_named_robot(tmp_path):
    six = arm_log(tmp_path / "six.mcap", "rosbags", names=SIX, twin_topic="/model_effort")
    result = run("fit", six, "--sim-topic", "/model_effort", "-o", tmp_path / "c.json")
    assert result.exit_code == 0, result.output
    ur = arm_log(tmp_path / "ur.mcap", "rosbags", names=UR5)
    named = run("fit", ur, "--robot", "ur5", "-o", tmp_path / "ur.json")
    assert named.exit_code == 0, named.output
    # the default robot's own joints (and a gripper's beside them) need no name
    xarm = arm_log(tmp_path / "x.mcap", "rosbags", names=(*XARM, "drive_joint"))
    assert run("fit", xarm, "-o", tmp_path / "x.json").exit_code == 0
