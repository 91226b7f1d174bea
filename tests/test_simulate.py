"""``simulate``: lossless MCAP copies with the twin's effort, from every input form."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from support.builders import (
    XARM,
    Bool,
    Message,
    String,
    joint_recording,
    joint_state,
    trajectory,
    write,
    write_humble_sqlite3,
)

from twincd.io.mcap import QOS_KEY
from twincd.prepare.setup import read_log
from twincd.prepare.simulate import default_output, simulate_log
from twincd.signal.filters import LowPass


def recording(n: int = 300) -> list[Message]:
    msgs = joint_recording(n=n, effort=np.random.default_rng(0).normal(size=(n, 7)))
    t0 = msgs[0].log_time
    msgs.append(Message("/collision_flag", "std_msgs/msg/Bool", t0 + 7, Bool(data=True)))
    msgs.append(Message("/rosout_text", "std_msgs/msg/String", t0 + 9, String(data="hello")))
    return msgs


def mcap_records(path: Path) -> list[tuple[str, int, int, bytes]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        return sorted(
            (c.topic, m.log_time, m.publish_time, bytes(m.data))
            for _, c, m in reader.iter_messages(log_time_order=False)
        )


def rosbags_records(path: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([path]) as reader:
        return sorted((c.topic, t, bytes(raw)) for c, t, raw in reader.messages())


def test_three_storage_forms_give_identical_twins_and_lossless_copies(tmp_path):
    msgs = recording()
    sources = {
        "sqlite3": write(tmp_path / "sqlite_bag", "rosbag2-sqlite3", msgs),
        "rosbag2-mcap": write(tmp_path / "mcap_bag", "rosbag2-mcap", msgs),
        "mcap": write(tmp_path / "bare.mcap", "mcap", msgs),
    }
    input_records = rosbags_records(sources["mcap"])
    assert len(input_records) == len(msgs)
    sims = {}
    for form, src in sources.items():
        out = simulate_log(src, None, "xarm7").output
        assert out == default_output(src) and out.suffix == ".mcap"
        sims[form] = read_log(out).sim_effort
        # every input message is in the output, byte-identical (read with rosbags and with mcap)
        out_rosbags = [r for r in rosbags_records(out) if r[0] != "/twincd/sim_effort"]
        assert out_rosbags == input_records
        out_mcap = [r for r in mcap_records(out) if r[0] != "/twincd/sim_effort"]
        assert [(t, lt, d) for t, lt, _, d in out_mcap] == input_records
        with open(out, "rb") as f:
            reader = make_reader(f)
            assert reader.get_header().profile == "ros2"
            summary = reader.get_summary()
            assert summary is not None
            for channel in summary.channels.values():
                assert QOS_KEY in channel.metadata and channel.message_encoding == "cdr"
            assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    np.testing.assert_allclose(sims["sqlite3"], sims["mcap"], atol=1e-9)
    np.testing.assert_allclose(sims["rosbag2-mcap"], sims["mcap"], atol=1e-9)
    assert np.isfinite(sims["mcap"]).all()


def test_bare_mcap_copy_keeps_publish_times_and_metadata(tmp_path):
    src = write(tmp_path / "in.mcap", "mcap", recording())
    out = simulate_log(src, tmp_path / "out.mcap", "xarm7").output
    before = mcap_records(src)
    after = [r for r in mcap_records(out) if r[0] != "/twincd/sim_effort"]
    assert after == before
    sim = [r for r in mcap_records(out) if r[0] == "/twincd/sim_effort"]
    joint = [r for r in before if r[0] == "/joint_states"]
    # each sim message carries its joint-state sample's log time
    assert [r[1] for r in sim] == [r[1] for r in joint]


def test_new_messages_share_stamps_and_fill_every_field(tmp_path):
    src = write(tmp_path / "in.mcap", "mcap", recording(50))
    out = simulate_log(src, None, "xarm7").output
    with AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == "/twincd/sim_effort"]
        msgs = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages(conns)]
    states = read_log(src)
    assert len(msgs) == 50
    for i, (t, msg) in enumerate(msgs):
        assert t == states.log_time_ns[i]
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        assert stamp == states.stamp_ns[i]
        assert list(msg.name) == list(XARM)
        np.testing.assert_array_equal(msg.position, states.position[i])
        np.testing.assert_array_equal(msg.velocity, states.velocity[i])
        assert len(msg.effort) == 7


def test_simulating_twice_replaces_the_channel_and_in_place_works(tmp_path):
    src = write(tmp_path / "in.mcap", "mcap", recording(60))
    simulate_log(src, None, "xarm7", in_place=True)
    simulate_log(src, None, "xarm7", in_place=True)
    records = mcap_records(src)
    assert sum(r[0] == "/twincd/sim_effort" for r in records) == 60
    assert not list(tmp_path.glob(".*.tmp"))


def quirky_recording(t_nominal: np.ndarray, rng: np.random.Generator, t0: int) -> list[Message]:
    """Joints shuffled, two gripper joints, ±15 % jitter, stamps before log times, a 2nd topic."""
    period = np.diff(t_nominal).mean()
    t = t_nominal + rng.uniform(-0.15, 0.15, len(t_nominal)) * period
    q, qd, _ = trajectory(t, seed=7)
    names = [*XARM, "left_finger", "right_finger"]
    msgs = []
    for i, ti in enumerate(t):
        stamp = t0 + round(ti * 1e9)
        lag = int(rng.uniform(0.2e6, 3e6))
        order = rng.permutation(9)
        pos = [*q[i], 0.02, 0.02]
        vel = [*qd[i], 0.0, 0.0]
        msgs.append(
            Message(
                "/joint_states",
                "sensor_msgs/msg/JointState",
                stamp + lag,
                joint_state(
                    stamp,
                    [names[k] for k in order],
                    [pos[k] for k in order],
                    [vel[k] for k in order],
                ),
            )
        )
        if i % 10 == 0:  # a gripper driver publishing on its own topic
            msgs.append(
                Message(
                    "/gripper/joint_states",
                    "sensor_msgs/msg/JointState",
                    stamp + lag + 1,
                    joint_state(stamp, names[7:], [0.02, 0.02]),
                )
            )
    return sorted(msgs, key=lambda m: m.log_time)


def test_real_world_quirks_match_the_clean_twin(tmp_path, caplog):
    t0 = 1_700_000_000_000_000_000
    t_nominal = np.arange(0, 15, 0.01)
    q, qd, _ = trajectory(t_nominal, seed=7)
    clean = [
        Message(
            "/joint_states",
            "sensor_msgs/msg/JointState",
            t0 + round(t * 1e9),
            joint_state(t0 + round(t * 1e9), XARM, q[i], qd[i]),
        )
        for i, t in enumerate(t_nominal)
    ]
    quirky = quirky_recording(t_nominal, np.random.default_rng(8), t0)
    ref_out = simulate_log(write(tmp_path / "clean.mcap", "mcap", clean), None, "xarm7").output
    with caplog.at_level("WARNING", logger="twincd"):
        out = simulate_log(write(tmp_path / "quirky.mcap", "mcap", quirky), None, "xarm7").output
    # the gripper's joints are named as ignored, nothing else is complained about
    assert [r.getMessage().split(": ", 1)[1] for r in caplog.records] == [
        "ignoring 2 log joint(s) not in the robot model: left_finger, right_finger"
    ]
    ref, got = read_log(ref_out), read_log(out).select(XARM)
    lp = LowPass()
    ref_f = lp.apply(ref.t_s, ref.sim_effort)
    got_f = lp.apply(got.t_s, got.sim_effort)
    t_ref = (ref.stamp_ns - t0) * 1e-9
    t_got = (got.stamp_ns - t0) * 1e-9
    interp = np.column_stack([np.interp(t_ref, t_got, got_f[:, j]) for j in range(7)])
    inner = slice(50, -50)  # filter start-up at both ends
    err = np.abs(interp[inner] - ref_f[inner]).max(axis=0)
    span = np.ptp(ref_f, axis=0)
    assert np.all(err < 0.02 * span), err / span


@pytest.mark.parametrize("robot", ["panda"])
def test_locked_joints_still_simulate(tmp_path, robot, caplog):
    names = [f"panda_joint{i}" for i in range(1, 8)]
    src = write(tmp_path / "panda.mcap", "mcap", joint_recording(n=40, names=names))
    with caplog.at_level("WARNING", logger="twincd"):
        result = simulate_log(src, None, robot)
    assert result.locked == ("panda_finger_joint1", "panda_finger_joint2")
    assert caplog.text.count("locking") <= 1  # once per model, cached afterwards


def test_humble_bag_without_message_definitions(tmp_path):
    msgs = recording(40)
    src = write_humble_sqlite3(tmp_path / "humble", msgs)
    ref = read_log(write(tmp_path / "ref.mcap", "mcap", msgs))
    out = simulate_log(src, None, "xarm7").output
    got = read_log(out)
    np.testing.assert_array_equal(got.position, ref.position)
    assert got.sim_effort is not None and np.isfinite(got.sim_effort).all()


def test_output_decodes_with_mcap_ros2(tmp_path):
    from mcap_ros2.decoder import DecoderFactory

    src = write(tmp_path / "in.bag", "ros1", recording(30))
    out = simulate_log(src, None, "xarm7").output
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages(topics=["/twincd/sim_effort", "/joint_states"]))
    assert len(decoded) == 60
    sim = [m for _, c, _, m in decoded if c.topic == "/twincd/sim_effort"]
    assert list(sim[0].name) == list(XARM) and len(sim[0].effort) == 7
