"""A recording is read as it is (contract: Inputs): simulation time that starts at 0, a second
publisher on the arm's joints, ros2_control's ``/dynamic_joint_states``. Logs are the shipped
xArm 7 sample logs written again by rosbags' writer and by twincd's, edited on the way."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.builders import rewrite
from support.clitools import assert_one_line_error, run

SAMPLES = Path(__file__).resolve().parent.parent / "sample_logs"
CALIBRATION = SAMPLES / "calibration.json"
CLEAN = SAMPLES / "val" / "val_000.mcap"
NS = 1_000_000_000


def detect(log: Path, *args: Any) -> dict[str, Any]:
    result = run("detect", log, "-c", CALIBRATION, "--json", *args)
    assert result.exit_code in (0, 1), result.output
    doc: dict[str, Any] = json.loads(result.stdout)
    return doc


def restamped(src: Path, dst: Path, stamp: Any, writer: str = "rosbags") -> Path:
    """``src`` with each JointState's header stamp replaced by ``stamp(i, old_ns)``."""
    seen = [0]

    def edit(msg: Any) -> None:
        ns = stamp(seen[0], msg.header.stamp.sec * NS + msg.header.stamp.nanosec)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), NS)
        seen[0] += 1

    return rewrite(src, dst, edit, writer=writer)


# ---------------------------------------------------------------- simulation time from 0


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_simulation_time_from_zero_is_read_as_time(tmp_path: Path, writer: str) -> None:
    """Gazebo before its first /clock: header stamps from exactly 0. The 24 s log was refused
    ("fewer than two distinct stamps"): its first stamp, 0, was taken for no stamp."""
    first: list[int] = []

    def from_zero(i: int, ns: int) -> int:
        first.append(ns)
        return ns - first[0]

    log = restamped(CLEAN, tmp_path / "sim.mcap", from_zero, writer)
    got, want = detect(log), detect(CLEAN)
    assert got["logs"][0] == {**want["logs"][0], "path": str(log)}
    assert not [w for w in got["warnings"] if "stamp" in w or "clock" in w]


def test_only_stamps_that_all_equal_each_other_are_too_few(tmp_path: Path) -> None:
    log = restamped(CLEAN, tmp_path / "same.mcap", lambda i, ns: 12 * NS)
    result = run("detect", log, "-c", CALIBRATION)
    assert_one_line_error(result, "fewer than two distinct stamps")
    # every stamp 0: no stamp at all, so the log time is used, and said
    zero = detect(restamped(CLEAN, tmp_path / "zero.mcap", lambda i, ns: 0))
    assert zero["logs"][0]["samples"] == detect(CLEAN)["logs"][0]["samples"]
    assert [w for w in zero["warnings"] if "carry no header stamp" in w and "log time" in w]


# ---------------------------------------------------------------- publishers told apart


def beside(
    tmp_path: Path, name: str, writer: str, names: Any, every: int, offset_ns: int, values: Any
) -> Path:
    """The clean log with a second JointState publisher on its topic: one message per
    ``every`` of the arm's, ``offset_ns`` after it, joints ``names``, ``values(msg)`` →
    (position, velocity, effort)."""
    from support.builders import Message, joint_state, messages_of, write_by

    msgs = messages_of(CLEAN)
    arm = [m for m in msgs if m.topic == "/joint_states"]
    extra = []
    for m in arm[::every]:
        stamp = m.msg.header.stamp.sec * NS + m.msg.header.stamp.nanosec + offset_ns
        pos, vel, eff = values(m.msg)
        extra.append(
            Message(
                m.topic, m.msgtype, m.log_time + offset_ns, joint_state(stamp, names, pos, vel, eff)
            )
        )
    every_msg = sorted(msgs + extra, key=lambda m: m.log_time)
    return write_by(writer, tmp_path / f"{name}.mcap", every_msg)


def zeros(msg: Any) -> tuple[Any, Any, Any]:
    k = len(msg.name)
    return np.zeros(k), np.zeros(k), np.zeros(k)


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
@pytest.mark.parametrize(("every", "offset_ms"), [(10, 3), (1, 4), (9, 8)])
def test_a_second_publisher_of_zeros_is_left_out_and_named(
    tmp_path: Path, writer: str, every: int, offset_ms: int
) -> None:
    """A stray publisher of exact zeros on the arm's joints (10 Hz or the arm's own rate)
    beside the live one gave one event over the whole clean log."""
    log = beside(tmp_path, "zeros", writer, [f"joint{i}" for i in range(1, 8)], every,
                 offset_ms * 1_000_000, zeros)  # fmt: skip
    got, want = detect(log), detect(CLEAN)
    assert got["logs"][0] == {**want["logs"][0], "path": str(log)}
    count = len(range(0, want["logs"][0]["samples"], every))
    (line,) = [w for w in got["warnings"] if "second publisher" in w]
    assert f"ignoring {count} message(s) on /joint_states" in line
    found = json.loads(run("inspect", log, "--json").stdout)["logs"][0]
    assert found["other_publisher"] == count and found["usable"]
    assert "second publisher" in run("inspect", log).stdout


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_a_gripper_node_on_other_joints_is_never_dropped(tmp_path: Path, writer: str) -> None:
    log = beside(tmp_path, "gripper", writer, ["gripper_joint"], 10, 3_000_000, zeros)
    got, want = detect(log), detect(CLEAN)
    assert got["logs"][0] == {**want["logs"][0], "path": str(log)}
    assert not [w for w in got["warnings"] if "second publisher" in w]


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_drives_off_are_left_out_and_said(tmp_path: Path, writer: str) -> None:
    """A driver whose motors are off publishes zero efforts in place of its samples (a real
    Doosan does, for 23 s at rest, while its twin asks 60 N·m of joint 2): nothing measured
    there, so not judged (before: one 23 s event, and fitted, a joint's noise tripled). The
    samples are left out, their span said by detect and inspect; the rest is judged as before,
    the stretch a gap (no event at its ends); streamed live alike; simulate still writes the
    twin's effort of every sample (it compares none)."""
    seen = [0]

    def off(msg: Any) -> None:
        if 1000 <= seen[0] < 1300:
            msg.effort = np.zeros_like(msg.effort)
        seen[0] += 1

    log = rewrite(CLEAN, tmp_path / "off.mcap", off, writer=writer)
    got, want = detect(log), detect(CLEAN)
    assert got["logs"][0]["samples"] == want["logs"][0]["samples"] - 300
    assert got["logs"][0]["events"] == []
    (line,) = [w for w in got["warnings"] if "efforts are all exactly 0" in w]
    assert "300 sample(s)" in line and "10.000–12.990 s" in line and "drives were off" in line
    assert not [w for w in got["warnings"] if "second publisher" in w]
    found = json.loads(run("inspect", log, "--json").stdout)["logs"][0]
    assert found["drives_off"] == {"samples": 300, "spans": 1, "spans_s": [[10.0, 12.99]]}
    assert "drives off: 300 sample(s)" in run("inspect", log).stdout
    # live, in blocks of any size: the same samples judged, nothing flagged
    from types import SimpleNamespace

    from support.streaming import pushed

    from twincd import Calibration, OnlineDetector, Setup

    cal = Calibration.load(SAMPLES / "calibration.causal.json")
    read = Setup.from_calibration(cal).prepare(CLEAN).states
    effort = read.effort.copy()
    effort[1000:1300] = 0.0
    states = SimpleNamespace(
        stamp_ns=read.stamp_ns, position=read.position, velocity=read.velocity, effort=effort
    )
    n = len(read.stamp_ns)
    live = OnlineDetector(cal)
    outs = pushed(live, states, [slice(a, a + 137) for a in range(0, n, 137)])
    events = [e for out in outs for e in out.events] + live.close()
    assert events == [] and live.counts.judged == n - 300 and live.skipped == 300
    simulated = run("simulate", log, "-o", tmp_path / "twin.mcap")
    assert simulated.exit_code == 0, simulated.output
    assert "exactly 0" not in simulated.stderr


def test_a_log_whose_efforts_are_all_zero_is_named(tmp_path: Path) -> None:
    """Every effort exactly 0 (the drives off throughout, or a driver that fills the field with
    zeros): a clear error, not a log too short."""

    def off(msg: Any) -> None:
        msg.effort = np.zeros_like(msg.effort)

    log = rewrite(CLEAN, tmp_path / "zeros.mcap", off)
    refused = run("detect", log, "-c", CALIBRATION)
    assert_one_line_error(refused, "every sample's efforts are exactly 0 on every joint")


# ---------------------------------------------------------------- ros2_control's DynamicJointState

DYNAMIC = "control_msgs/msg/DynamicJointState"


def split_to_dynamic(
    tmp_path: Path,
    name: str,
    interfaces: tuple[str, ...],
    keep_joint_states: bool = True,
    form: str = "mcap",
) -> Path:
    """The clean log as ros2_control records it: /joint_states without effort (or none at
    all), and /dynamic_joint_states with ``interfaces`` per joint, at the same stamps; written
    by rosbags' writer with control_msgs registered from its .msg text."""
    from support.builders import TS, Message, messages_of, write

    value_type = TS.types["control_msgs/msg/InterfaceValue"]
    out = []
    for m in messages_of(CLEAN):
        if m.msgtype != "sensor_msgs/msg/JointState":
            out.append(m)
            continue
        arrays = {"position": m.msg.position, "velocity": m.msg.velocity, "effort": m.msg.effort}
        values = [
            value_type(interface_names=list(interfaces),
                       values=np.array([arrays[i][j] for i in interfaces]))
            for j in range(len(m.msg.name))
        ]  # fmt: skip
        dyn = TS.types[DYNAMIC](header=m.msg.header, joint_names=list(m.msg.name),
                                interface_values=values)  # fmt: skip
        out.append(Message("/dynamic_joint_states", DYNAMIC, m.log_time, dyn))
        if keep_joint_states:
            m.msg.effort = np.zeros(0)
            out.append(m)
    return write(tmp_path / (f"{name}.mcap" if form == "mcap" else name), form, out)


@pytest.mark.parametrize("form", ["mcap", "rosbag2-sqlite3"])
@pytest.mark.parametrize("keep_joint_states", [True, False])
def test_dynamic_joint_states_stand_in_when_no_joint_state_carries_effort(
    tmp_path: Path, keep_joint_states: bool, form: str
) -> None:
    log = split_to_dynamic(tmp_path, "ros2_control", ("position", "velocity", "effort"),
                           keep_joint_states, form)  # fmt: skip
    got, want = detect(log), detect(CLEAN)
    assert got["logs"][0] == {**want["logs"][0], "path": str(log)}
    if keep_joint_states:
        (line,) = [w for w in got["warnings"] if "/dynamic_joint_states" in w]
        assert "/joint_states carries no effort" in line and DYNAMIC in line
    found = json.loads(run("inspect", log, "--json").stdout)["logs"][0]
    assert found["usable"] and found["joint_topic"] == "/dynamic_joint_states"


def test_dynamic_joint_states_without_effort_are_named_in_the_error(tmp_path: Path) -> None:
    log = split_to_dynamic(tmp_path, "no_effort", ("position", "velocity"))
    result = run("detect", log, "-c", CALIBRATION)
    assert_one_line_error(result, "no measured effort")
    assert "/dynamic_joint_states" in result.stderr and "no effort interface" in result.stderr


# ---------------------------------------------------------------- what cannot be read


def denied(monkeypatch: pytest.MonkeyPatch, target: Path) -> None:
    """The operating system refuses ``target`` (a folder's listing, a file's opening) as it
    does for a user without the right (these tests run as root, who may read everything)."""
    import builtins

    def refuse(path: object) -> None:
        if Path(str(path)).resolve() == target.resolve():
            raise PermissionError(13, "Permission denied", str(path))

    listing = Path.iterdir
    opening = builtins.open

    def iterdir(self: Path) -> Any:
        refuse(self)
        return listing(self)

    def open_(file: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(file, str | Path):
            refuse(file)
        return opening(file, *args, **kwargs)

    monkeypatch.setattr(Path, "iterdir", iterdir)
    monkeypatch.setattr(builtins, "open", open_)


@pytest.mark.parametrize("what", ["folder", "file"])
def test_an_unreadable_log_is_exit_2_with_its_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, what: str
) -> None:
    folder = tmp_path / "train"
    folder.mkdir()
    log = Path(shutil.copy(CLEAN, folder / "a.mcap"))
    target = folder if what == "folder" else log
    denied(monkeypatch, target)
    for command in (("fit", folder, "-o", tmp_path / "c.json"), ("inspect", folder)):
        result = run(*command)
        assert_one_line_error(result, "Permission denied")
        assert str(target) in result.stderr


def test_an_unreadable_log_is_refused_for_real(tmp_path: Path) -> None:
    """Without a stand-in: a folder without read permission, where this user may not read it."""
    folder = tmp_path / "train"
    folder.mkdir()
    shutil.copy(CLEAN, folder / "a.mcap")
    folder.chmod(0)
    try:
        if os.access(folder, os.R_OK):
            pytest.skip("this user (root) may read a folder without read permission")
        assert_one_line_error(run("fit", folder, "-o", tmp_path / "c.json"), "Permission denied")
    finally:
        folder.chmod(0o755)


# ---------------------------------------------------------------- coverage said


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_a_hole_in_the_recording_is_said_everywhere(
    tmp_path: Path, writer: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 10 s hole mid-log (the recorder stalled) is not judged: detect says so in its line,
    in --json (``unjudged_spans``, ``unjudged_s``), in JUnit (the case's system-out) and in the
    job summary; a log without a hole says nothing of the kind."""
    seen = [0]

    def hole(msg: Any) -> bool:
        seen[0] += 1
        return not 1000 < seen[0] <= 2000  # 10.00–19.99 s at 100 Hz

    log = rewrite(CLEAN, tmp_path / "hole.mcap", hole, writer=writer)
    got = detect(log)["logs"][0]
    ((start, end),) = got["unjudged_spans"]
    assert start == pytest.approx(9.99, abs=1e-6) and end == pytest.approx(20.0, abs=1e-6)
    assert got["unjudged_s"] == pytest.approx(10.01, abs=1e-6)
    whole = detect(CLEAN)["logs"][0]
    assert whole["unjudged_spans"] == [] and whole["unjudged_s"] == 0
    said = "10 s not judged: 1 gap(s), 9.99–20.00 s"
    assert said in run("detect", log, "-c", CALIBRATION).stdout
    assert "not judged" not in run("detect", CLEAN, "-c", CALIBRATION).stdout
    junit, summary = tmp_path / "junit.xml", tmp_path / "summary.md"
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(summary))
    result = run("detect", log, "-c", CALIBRATION, "--junit", junit)
    assert result.exit_code in (0, 1), result.output
    assert f"<system-out>{said}</system-out>" in junit.read_text()
    assert said in summary.read_text()


@pytest.mark.parametrize("writer", ["rosbags", "twincd"])
def test_a_push_inside_a_hole_is_counted_apart_by_evaluate(tmp_path: Path, writer: str) -> None:
    """A labelled push whose label messages all fall in a hole of the joint states marks no
    sample: evaluate counts it apart ("not judged", ``events_not_judged``) and says so, never
    silently dropping it from the pushes."""
    seen = [0]

    def hole(msg: Any) -> bool:
        seen[0] += 1
        return not 1400 < seen[0] <= 1600  # 14.00–15.99 s: the press at ≈ 14.9–15.2 s

    test = SAMPLES / "test" / "test_000.mcap"
    log = rewrite(test, tmp_path / "hole.mcap", hole, writer=writer)

    def evaluated(path: Path) -> tuple[dict[str, Any], list[str]]:
        result = run("evaluate", path, "-c", CALIBRATION, "--json")
        assert result.exit_code == 0, result.output
        doc = json.loads(result.stdout)
        return doc["methods"][0], doc["warnings"]

    whole, _ = evaluated(test)
    holed, warnings = evaluated(log)
    assert whole["events_not_judged"] == 0
    assert holed["events_not_judged"] == 1
    assert holed["events_total"] == whole["events_total"] - 1
    assert any("1 labelled push(es) fell where no sample was judged" in w for w in warnings)
