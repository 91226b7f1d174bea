"""What real drivers put on ``/joint_states``: more joints than the arm's (before, after or among
them), another publisher's messages on the same topic, an arm split over publishers, a joint
named twice, a Franka Panda's nine joints. Joints are matched by name on every path."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import DEFAULT_BUMPS, TWIN_JOINTS, build_twin_log
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.builders import TS, XARM, Bool, Message, joint_state, trajectory, write
from support.clitools import assert_one_line_error, run

from twincd.calibration import Calibration
from twincd.detection import detect_log
from twincd.prepare.setup import read_log

# an extra joint before, after and among the arm's (j1..j3)
SUPERSETS = {
    "before": ("aux_axis", *TWIN_JOINTS),
    "after": (*TWIN_JOINTS, "drive_joint"),
    "among": ("j1", "aux_axis", "j2", "j3"),
}
PANDA_ARM = tuple(f"panda_joint{i}" for i in range(1, 8))
PANDA = (*PANDA_ARM, "panda_finger_joint1", "panda_finger_joint2")


def twin_logs(root: Path, state_joints: Sequence[str] | None = None) -> dict[str, Path]:
    """train (clean), val (clean) and test (labelled bumps) twin logs under ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    return {
        split: build_twin_log(
            root / f"{split}.mcap", seed=seed, bumps=bumps, state_joints=state_joints
        )
        for split, seed, bumps in (("train", 0, ()), ("val", 100, ()), ("test", 200, DEFAULT_BUMPS))
    }


def chain(logs: dict[str, Path], out: Path, *robot: str) -> dict[str, Any]:
    """fit → threshold → detect → evaluate on ``logs``; what each produced."""
    cal = out / "cal.json"
    fit = run("fit", logs["train"], "-o", cal, *robot)
    assert fit.exit_code == 0, fit.stderr
    assert run("threshold", logs["val"], "-c", cal).exit_code == 0
    found = run("detect", logs["test"], "-c", cal, "--json")
    assert found.exit_code == 1, found.stderr  # the test log's bumps are found
    evaluated = run("evaluate", logs["test"], "-c", cal, "--json")
    assert evaluated.exit_code == 0, evaluated.stderr
    calibration = json.loads(cal.read_text())
    detected = json.loads(found.stdout)["logs"][0]
    methods = json.loads(evaluated.stdout)["methods"]
    return {
        "fit_stderr": fit.stderr,
        "model": calibration["model"],
        "threshold": calibration["threshold"]["value"],
        "joints": calibration["robot"]["joint_names"],
        "detected": {k: detected[k] for k in ("samples", "collision_samples", "events")},
        "evaluated": [{k: m[k] for k in ("f1_best", "auc", "f1_at_threshold")} for m in methods],
    }


@pytest.fixture(scope="module")
def plain(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("plain")
    logs = twin_logs(root)
    return {"logs": logs, "cal": root / "cal.json", **chain(logs, root)}


def _events(result: dict[str, Any]) -> list[dict[str, Any]]:
    return [{k: e[k] for k in ("start_ns", "end_ns", "peak_score", "joint")} for e in result]


@pytest.mark.parametrize("where", SUPERSETS)
def test_an_extra_joint_anywhere_changes_nothing(plain, tmp_path, where):
    state = SUPERSETS[where]
    extra = next(n for n in state if n not in TWIN_JOINTS)
    got = chain(twin_logs(tmp_path, state), tmp_path)
    for key in ("model", "threshold", "joints", "detected", "evaluated"):
        assert got[key] == plain[key], key
    assert got["joints"] == list(TWIN_JOINTS)
    assert f"ignoring 1 log joint(s) not in the log's twin effort: {extra}" in got["fit_stderr"]
    # the untouched calibration on the superset log: the same flags
    found = run("detect", tmp_path / "test.mcap", "-c", plain["cal"], "--json")
    assert found.exit_code == 1
    assert f"ignoring 1 log joint(s) not in the calibration: {extra}" in found.stderr
    assert json.loads(found.stdout)["logs"][0]["events"] == plain["detected"]["events"]


# ---------------------------------------------------------------- a robot model (xArm 7)


def xarm_messages(names: Sequence[str], n: int = 600, seed: int = 3) -> list[Message]:
    """xArm 7 joint states (position, velocity, effort) with extra joints where ``names`` says."""
    t0, period = 1_700_000_000_000_000_000, 10_000_000
    q, qd, _ = trajectory(np.arange(n) * period * 1e-9, 7, seed)
    effort = 5 * np.sin(q) + 0.3
    msgs = []
    for i in range(n):
        cols = [XARM.index(k) if k in XARM else -1 for k in names]

        def row(a: np.ndarray, i: int = i, cols: list[int] = cols) -> list[float]:
            return [float(a[i, c]) if c >= 0 else 0.05 for c in cols]

        stamp = t0 + i * period
        msgs.append(state_message(stamp, names, row(q), row(qd), row(effort)))
    return msgs


def state_message(stamp: int, names: Sequence[str], *arrays: object) -> Message:
    """One /joint_states message (position, velocity, effort) at ``stamp``."""
    return Message(
        "/joint_states", "sensor_msgs/msg/JointState", stamp, joint_state(stamp, names, *arrays)
    )


@pytest.mark.parametrize(
    "names",
    [("rail", *XARM), (*XARM, "drive_joint"), (*XARM[:3], "drive_joint", *XARM[3:])],
    ids=["before", "after", "among"],
)
def test_robot_model_path_ignores_extra_joints(tmp_path, names):
    plain = write(tmp_path / "plain.mcap", "mcap", xarm_messages(XARM))
    wide = write(tmp_path / "wide.mcap", "rosbag2-mcap", xarm_messages(names))
    out = {}
    for name, path in (("plain", plain), ("wide", wide)):
        result = run("simulate", path, "-o", tmp_path / f"{name}.twin.mcap")
        assert result.exit_code == 0, result.stderr
        out[name] = read_log(tmp_path / f"{name}.twin.mcap").select(XARM)
        fit = run("fit", path, "--robot", "xarm7", "-o", tmp_path / f"{name}.json")
        assert fit.exit_code == 0, fit.stderr
    assert "ignoring 1 log joint(s) not in the robot model" in result.stderr
    np.testing.assert_array_equal(out["wide"].sim_effort, out["plain"].sim_effort)
    np.testing.assert_array_equal(out["wide"].stamp_ns, out["plain"].stamp_ns)
    cal = {k: json.loads((tmp_path / f"{k}.json").read_text()) for k in ("plain", "wide")}
    assert cal["wide"]["model"] == cal["plain"]["model"]
    assert cal["wide"]["robot"]["joint_names"] == list(XARM)


# ---------------------------------------------------------------- several publishers, one topic


def messages_of(path: Path) -> list[Message]:
    """Every message of a log (read with rosbags), in log-time order."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path], default_typestore=TS) as reader:
        return [
            Message(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]


def with_gripper(msgs: list[Message], names: Sequence[str]) -> list[Message]:
    """A gripper node's JointState after each arm message, on the same topic."""
    out: list[Message] = []
    for m in msgs:
        out.append(m)
        if m.topic == "/joint_states":
            stamp = m.log_time + 3_000_000
            k = len(names)
            out.append(
                Message(
                    m.topic, m.msgtype, stamp, joint_state(stamp, names, [0.04] * k, (), [1.0] * k)
                )
            )
    return out


@pytest.mark.parametrize(
    "gripper", [("gripper_finger_joint1", "gripper_finger_joint2"), ("drive_joint",)]
)
def test_a_gripper_publisher_on_the_topic_is_ignored_and_counted(plain, tmp_path, gripper):
    msgs = messages_of(plain["logs"]["test"])
    arm = write(tmp_path / "arm", "rosbag2-mcap", msgs)
    both = write(tmp_path / "both", "rosbag2-mcap", with_gripper(msgs, gripper))
    count = sum(m.topic == "/joint_states" for m in msgs)
    found = {}
    for name, path in (("arm", arm), ("both", both)):
        result = run("detect", path, "-c", plain["cal"], "--json")
        assert result.exit_code == 1, result.stderr
        found[name] = json.loads(result.stdout)["logs"][0]
        found[name].pop("path")
    assert found["both"] == found["arm"]
    assert found["arm"]["events"] == plain["detected"]["events"]
    assert f"ignoring {count} message(s) on /joint_states that carry none of its joints" in (
        result.stderr
    )
    # without a calibration (fit): the log's own twin effort names the arm's joints
    fit = run("fit", both, "-o", tmp_path / "cal.json")
    assert fit.exit_code == 0, fit.stderr
    fitted = json.loads((tmp_path / "cal.json").read_text())
    assert fitted["robot"]["joint_names"] == list(TWIN_JOINTS)


def test_an_arm_split_over_two_publishers_is_refused_in_one_line(tmp_path):
    msgs = []
    for m in xarm_messages(XARM, n=100):
        js = m.msg
        for part in (slice(0, 4), slice(4, 7)):
            msgs.append(
                Message(
                    m.topic,
                    m.msgtype,
                    m.log_time,
                    joint_state(
                        m.log_time,
                        js.name[part],
                        js.position[part],
                        js.velocity[part],
                        js.effort[part],
                    ),
                )
            )
    path = write(tmp_path / "split.mcap", "mcap", msgs)
    assert_one_line_error(
        run("simulate", path, "-o", tmp_path / "out.mcap"),
        "split over several messages per sample (joint1, joint2, joint3, joint4 | joint5, "
        "joint6, joint7)",
    )
    assert not (tmp_path / "out.mcap").exists()


def test_a_joint_named_twice_keeps_its_first_value_with_a_warning(plain, tmp_path):
    msgs = messages_of(plain["logs"]["test"])
    for m in msgs:
        if m.topic == "/joint_states":  # j2 again at the end, with nonsense values
            js = m.msg
            m.msg = joint_state(
                m.log_time,
                [*js.name, "j2"],
                [*js.position, 9.0],
                [*js.velocity, 9.0],
                [*js.effort, 99.0],
            )
    path = write(tmp_path / "twice.mcap", "mcap", msgs)
    result = run("detect", path, "-c", plain["cal"], "--json")
    assert result.exit_code == 1, result.stderr
    assert json.loads(result.stdout)["logs"][0]["events"] == plain["detected"]["events"]
    count = sum(m.topic == "/joint_states" for m in msgs)
    assert f"{count} message(s) name joint(s) j2 twice; keeping the first value" in result.stderr


# ---------------------------------------------------------------- a Franka Panda's nine joints


def panda_log(path: Path, seed: int, bump: bool) -> Path:
    """A Panda-shaped log: the arm's seven joints, then the two fingers (franka_ros), with
    effort = the Panda's inverse dynamics (+ a labelled push when ``bump``)."""
    from twincd.prepare.robots import robot_for
    from twincd.twin.dynamics import inverse_dynamics

    n, period, t0 = 1200, 10_000_000, 1_700_000_000_000_000_000
    t = np.arange(n) * period * 1e-9
    dq, dqd, dqdd = trajectory(t, 7, seed)
    home = np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8])
    q, qd, qdd = home + 0.3 * dq, 0.3 * dqd, 0.3 * dqdd
    effort = inverse_dynamics(robot_for("panda", PANDA_ARM), q, qd, qdd)
    flag = (t > 6) & (t < 7) if bump else np.zeros(n, bool)
    effort[flag, 1] += 8.0
    fingers = np.full((n, 2), 0.035)
    msgs = [Message("/collision_flag", "std_msgs/msg/Bool", t0 - 1, Bool(data=False))]
    for i in range(n):
        stamp = t0 + i * period
        msgs.append(
            state_message(
                stamp,
                PANDA,
                np.r_[q[i], fingers[i]],
                np.r_[qd[i], 0.0, 0.0],
                np.r_[effort[i], 0.0, 0.0],
            )
        )
        if i and flag[i] != flag[i - 1]:
            msgs.append(
                Message("/collision_flag", "std_msgs/msg/Bool", stamp, Bool(data=bool(flag[i])))
            )
    return write(path, "ros1" if path.suffix == ".bag" else "mcap", msgs)


def test_a_panda_with_its_fingers_through_every_command(tmp_path):
    train = panda_log(tmp_path / "train.bag", 1, bump=False)
    val = panda_log(tmp_path / "val.mcap", 2, bump=False)
    test = panda_log(tmp_path / "test.mcap", 3, bump=True)
    sim = run("simulate", train, "--robot", "panda", "-o", tmp_path / "train.twin.mcap")
    assert sim.exit_code == 0, sim.stderr
    assert "not in the robot model: panda_finger_joint1, panda_finger_joint2" in sim.stderr
    twin = read_log(tmp_path / "train.twin.mcap")
    assert twin.sim_effort is not None and np.isfinite(twin.select(PANDA_ARM).sim_effort).all()
    cal = tmp_path / "cal.json"
    assert run("fit", train, "--robot", "panda", "-o", cal, "--model", "affine").exit_code == 0
    assert json.loads(cal.read_text())["robot"]["joint_names"] == list(PANDA_ARM)
    assert run("threshold", val, "-c", cal).exit_code == 0
    found = run("detect", test, "-c", cal, "--json")
    assert found.exit_code == 1, found.stderr
    assert json.loads(found.stdout)["logs"][0]["events"]
    evaluated = run("evaluate", test, "-c", cal, "--json", "-m", "proposed,naive-mob")
    assert evaluated.exit_code == 0, evaluated.stderr
    methods = {m["name"]: m for m in json.loads(evaluated.stdout)["methods"]}
    assert methods["proposed"]["auc"] > 0.9 and "naive-mob" in methods


# ---------------------------------------------------------------- a property


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    order=st.permutations(TWIN_JOINTS),
    extras=st.lists(
        st.sampled_from(["aux_axis", "drive_joint", "gripper_joint"]), unique=True, max_size=2
    ),
    at=st.integers(0, 3),
)
def test_joint_order_and_extra_joints_never_change_scores(plain, order, extras, at):
    calibration = Calibration.load(plain["cal"])
    reference = detect_log(calibration.prepare(plain["logs"]["test"]), calibration).scores
    names = [*order[:at], *extras, *order[at:]]
    with tempfile.TemporaryDirectory() as tmp:
        path = build_twin_log(
            Path(tmp) / "t.mcap", seed=200, bumps=DEFAULT_BUMPS, state_joints=names
        )
        scores = detect_log(calibration.prepare(path), calibration).scores
    np.testing.assert_array_equal(scores, reference)
