"""Log reading (contract: Inputs): every input form, name matching, time handling, labels."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from support.builders import (
    FORMS,
    SUFFIX,
    XARM,
    Bool,
    Message,
    String,
    joint_recording,
    joint_state,
    write,
)

from twincd.errors import LogReadError, TopicError, UsageError
from twincd.io.logs import expand_logs
from twincd.io.options import LogOptions, parse_joint_map
from twincd.prepare.setup import read_log


@pytest.fixture
def recording() -> list[Message]:
    rng = np.random.default_rng(1)
    msgs = joint_recording(n=200, effort=rng.normal(size=(200, 7)))
    t0 = msgs[0].log_time
    msgs += [
        Message("/collision_flag", "std_msgs/msg/Bool", t0 + 500_000_000, Bool(data=True)),
        Message("/collision_flag", "std_msgs/msg/Bool", t0 + 800_000_000, Bool(data=False)),
        Message("/chatter", "std_msgs/msg/String", t0 + 1, String(data="hello")),
    ]
    return msgs


@pytest.mark.parametrize("form", FORMS)
def test_every_form_gives_the_same_arrays(tmp_path, recording, form):
    reference = read_log(write(tmp_path / "ref.mcap", "mcap", recording))
    states = read_log(write(tmp_path / f"log{SUFFIX[form]}", form, recording))
    assert states.joint_names == XARM
    np.testing.assert_array_equal(states.stamp_ns, reference.stamp_ns)
    np.testing.assert_array_equal(states.position, reference.position)
    np.testing.assert_array_equal(states.velocity, reference.velocity)
    np.testing.assert_array_equal(states.effort, reference.effort)
    np.testing.assert_array_equal(states.labels, reference.labels)
    assert len(states) == 200


def test_labels_are_a_zero_order_hold(tmp_path, recording):
    states = read_log(write(tmp_path / "a.mcap", "mcap", recording))
    assert states.labels is not None
    t = (states.log_time_ns - states.log_time_ns[0]) * 1e-9
    expected = (t >= 0.5 - 1e-9) & (t < 0.8 - 1e-9)
    np.testing.assert_array_equal(states.labels, expected)


def test_no_label_topic_gives_none(tmp_path):
    states = read_log(write(tmp_path / "a.mcap", "mcap", joint_recording(n=20)))
    assert states.labels is None
    assert states.effort is None


def test_folder_of_logs_expands_to_every_log(tmp_path, recording):
    (tmp_path / "logs").mkdir()
    write(tmp_path / "logs" / "a.mcap", "mcap", recording)
    write(tmp_path / "logs" / "bag2", "rosbag2-sqlite3", recording)
    (tmp_path / "logs" / "sub").mkdir()
    write(tmp_path / "logs" / "sub" / "c.bag", "ros1", recording)
    (tmp_path / "logs" / "notes.txt").write_text("not a log")
    found = expand_logs([tmp_path / "logs"])
    assert [p.name for p in found] == ["a.mcap", "bag2", "c.bag"]
    # the rosbag2 folder stands for itself, not for its storage file
    assert expand_logs([tmp_path / "logs" / "bag2"]) == [tmp_path / "logs" / "bag2"]


def test_empty_folder_and_missing_path_are_errors(tmp_path):
    with pytest.raises(LogReadError, match="no logs"):
        expand_logs([tmp_path])
    with pytest.raises(LogReadError, match="no such file"):
        expand_logs([tmp_path / "nope.mcap"])


def test_shuffled_order_extra_joints_and_missing_velocity(tmp_path):
    clean = joint_recording(n=300)
    rng = np.random.default_rng(2)
    messy = []
    for m in clean:
        order = rng.permutation(9)
        names = [*XARM, "gripper_left", "gripper_right"]
        pos = [*m.msg.position, 0.01, 0.02]
        messy.append(
            Message(
                m.topic,
                m.msgtype,
                m.log_time,
                joint_state(m.log_time, [names[k] for k in order], [pos[k] for k in order]),
            )
        )
    ref = read_log(write(tmp_path / "clean.mcap", "mcap", clean))
    states = read_log(write(tmp_path / "messy.mcap", "mcap", messy)).select(XARM)
    np.testing.assert_array_equal(states.position, ref.position)
    assert states.velocity_from_position and not ref.velocity_from_position
    # differentiated velocity follows the logged one (smooth trajectory, 100 Hz)
    assert np.abs(states.velocity - ref.velocity).max() < 1e-3


def test_unsorted_duplicates_and_zero_stamps(tmp_path):
    msgs = joint_recording(n=50)
    dup = Message(
        msgs[10].topic,
        msgs[10].msgtype,
        msgs[10].log_time + 5,
        joint_state(msgs[10].log_time, XARM, np.full(7, 99.0)),
    )
    zero = msgs[20]
    zero.msg.header.stamp.sec = 0
    zero.msg.header.stamp.nanosec = 0
    shuffled = [*list(reversed(msgs[:30])), dup, *msgs[30:]]
    states = read_log(write(tmp_path / "a.mcap", "mcap", shuffled))
    assert len(states) == 49
    assert np.all(np.diff(states.stamp_ns) > 0)
    # the duplicate stamp was dropped, keeping the first message in log order
    assert not np.any(states.position == 99.0)
    # a zero header stamp among real ones is a time like any other (never the log time): far
    # behind the clock, so dropped as a backward jump
    assert zero.log_time not in states.stamp_ns and 0 not in states.stamp_ns


def test_header_stamp_is_preferred_over_log_time(tmp_path):
    msgs = joint_recording(n=20)
    for i, m in enumerate(msgs):
        m.log_time += 2_000_000 + 1000 * i  # recorder latency
    states = read_log(write(tmp_path / "a.mcap", "mcap", msgs))
    np.testing.assert_array_equal(np.diff(states.stamp_ns), 10_000_000)
    assert np.all(states.log_time_ns - states.stamp_ns >= 2_000_000)


def test_topic_fallback_and_ambiguity(tmp_path, caplog):
    single = joint_recording(n=20, topic="/arm/joint_states")
    with caplog.at_level(logging.WARNING, logger="twincd"):
        states = read_log(write(tmp_path / "one.mcap", "mcap", single))
    assert states.topic == "/arm/joint_states"
    assert "using its only JointState topic" in caplog.text
    both = single + joint_recording(n=20, topic="/other/joint_states")
    path = write(tmp_path / "two.mcap", "mcap", both)
    with pytest.raises(TopicError, match="several JointState topics"):
        read_log(path)
    assert read_log(path, LogOptions(topic="/other/joint_states")).topic == "/other/joint_states"


def test_no_joint_state_topic(tmp_path):
    msgs = [Message("/chatter", "std_msgs/msg/String", 1, String(data="x"))]
    with pytest.raises(TopicError, match="no sensor_msgs/msg/JointState"):
        read_log(write(tmp_path / "a.mcap", "mcap", msgs))


def test_ragged_arrays_are_dropped(tmp_path, caplog):
    msgs = joint_recording(n=10)
    msgs[3].msg.position = np.zeros(3)
    got = read_log(write(tmp_path / "a.mcap", "mcap", msgs))
    assert len(got) == 9 and "ragged" in caplog.text


def test_joint_map_renames(tmp_path):
    msgs = joint_recording(n=10, names=[f"arm_{n}" for n in XARM])
    options = LogOptions(joint_map=parse_joint_map(",".join(f"arm_{n}={n}" for n in XARM)))
    assert read_log(write(tmp_path / "a.mcap", "mcap", msgs), options).joint_names == XARM
    with pytest.raises(UsageError):
        parse_joint_map("a=b,broken")


@pytest.mark.parametrize(
    "content",
    [b"", b"\x89MCAP0\r\n" + bytes(range(256)) * 4, np.random.default_rng(0).bytes(4096)],
    ids=["empty", "bad-records", "random"],
)
def test_corrupt_files_are_one_clear_error(tmp_path, content):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(LogReadError):
        read_log(path)


def test_truncated_mcap_is_an_error(tmp_path, recording):
    good = write(tmp_path / "good.mcap", "mcap", recording)
    data = good.read_bytes()
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(LogReadError):
        read_log(bad)


def test_folders_skip_twin_copies_of_their_logs(tmp_path):
    msgs = joint_recording(n=10)
    write(tmp_path / "a.mcap", "mcap", msgs)
    write(tmp_path / "a.twin.mcap", "mcap", msgs)  # simulate's output of a.mcap
    write(tmp_path / "b.twin.mcap", "mcap", msgs)  # a twin file whose source is elsewhere
    assert [p.name for p in expand_logs([tmp_path])] == ["a.mcap", "b.twin.mcap"]
    # named explicitly, a twin file is used
    assert expand_logs([tmp_path / "a.twin.mcap"]) == [tmp_path / "a.twin.mcap"]


def test_partial_messages_never_displace_complete_ones(tmp_path):
    # a gripper driver publishing its own joint on /joint_states with the arm's stamps, first
    msgs = []
    for m in joint_recording(n=20):
        msgs.append(
            Message(m.topic, m.msgtype, m.log_time, joint_state(m.log_time, ["grip"], [0.01]))
        )
        grip = joint_state(m.log_time, [*XARM, "grip"], [*m.msg.position, 0.01])
        msgs.append(Message(m.topic, m.msgtype, m.log_time + 1, grip))
    states = read_log(write(tmp_path / "a.mcap", "mcap", msgs))
    assert len(states) == 20
    assert np.isfinite(states.position).all()
